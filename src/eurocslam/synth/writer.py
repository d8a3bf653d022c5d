"""Write a synthetic sequence as an EuRoC ASL folder (what `open_sequence` and `doctor` read),
or as a TUM-VI folder as distributed (`rig` "tumvi").

EuRoC layout::

    OUT/mav0/cam0/{data.csv, data/<t_ns>.png, sensor.yaml}
    OUT/mav0/cam1/{...}
    OUT/mav0/imu0/{data.csv, sensor.yaml}
    OUT/mav0/state_groundtruth_estimate0/{data.csv, sensor.yaml}   17 columns
    OUT/mav0/body.yaml
    OUT/synth.json                                                 spec + summary

TUM-VI layout (no sensor.yaml: the calibration is in dso/)::

    OUT/dso/{camchain.yaml, imu_config.yaml}
    OUT/mav0/cam0/{data.csv, data/<t_ns>.png}, OUT/mav0/cam1/{...}
    OUT/mav0/imu0/data.csv
    OUT/mav0/mocap0/data.csv                                       8 columns: t, p, q wxyz
    OUT/synth.json

The folder is assembled under `OUT.partial` and renamed at the end, so an interrupted run never
leaves something that looks like a finished sequence.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.calib import StereoRig
from eurocslam.errors import OutputError
from eurocslam.geometry import F64

CAM_HEADER = "#timestamp [ns],filename"
IMU_HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
)
GT_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
    "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
    "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
    "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
)
GT_SENSOR_YAML = """%YAML:1.0
# General sensor definitions.
sensor_type: visual-inertial
comment: eurocslam synthetic ground truth (the exact trajectory the images and IMU were made from).

# Sensor extrinsics wrt. the body-frame. This is the transformation of the
# tracking prima to the body frame.
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0,
         0.0, 1.0, 0.0, 0.0,
         0.0, 0.0, 1.0, 0.0,
         0.0, 0.0, 0.0, 1.0]
"""
BODY_YAML = "%YAML:1.0\ncomment: eurocslam synthetic sequence (EuRoC VI-sensor calibration)\n"
MOCAP_HEADER = (
    "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []"
)
# the folders of each layout, under the staging root
FOLDERS = {
    "euroc": ("mav0/cam0/data", "mav0/cam1/data", "mav0/imu0", "mav0/state_groundtruth_estimate0"),
    "tumvi": ("mav0/cam0/data", "mav0/cam1/data", "mav0/imu0", "mav0/mocap0", "dso"),
}


def _rows(t_ns: np.ndarray, values: F64, fmt: str) -> str:
    """CSV rows 't,v1,...' with exact integer timestamps."""
    body = [
        str(int(t)) + "," + ",".join(fmt % x for x in row)
        for t, row in zip(t_ns, values, strict=False)
    ]
    return "\n".join(body) + "\n"


def prepare_folder(out: Path, overwrite: bool, layout: str = "euroc") -> Path:
    """Create the staging folder `OUT.partial/mav0/...` (`layout`: "euroc" or "tumvi");
    returns the staging root."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: is a file; the output of synth is a folder")
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise OutputError(
                f"{out}: already exists and is not empty (pass --force to replace it)"
            )
        if not (out / "synth.json").is_file():
            raise OutputError(
                f"{out}: exists and is not a synthetic sequence written by eurocslam (no "
                "synth.json); refusing to replace it"
            )
    stage = out.with_name(out.name + ".partial")
    if stage.is_dir() and {p.name for p in stage.iterdir()} <= {"mav0", "synth.json", "dso"}:
        shutil.rmtree(stage)  # left by an interrupted synth
    elif stage.exists():
        raise OutputError(
            f"{stage}: exists and is not an unfinished synthetic sequence; synth stages its "
            "output there: move it away"
        )
    try:
        for sub in FOLDERS[layout]:
            (stage / sub).mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{stage}: cannot create: {e}") from None
    return stage


def image_path(stage: Path, cam: str, t_ns: int) -> Path:
    return stage / "mav0" / cam / "data" / f"{int(t_ns)}.png"


def write_tables(
    stage: Path,
    rig: StereoRig,
    cam_t_ns: np.ndarray,
    imu_t_ns: np.ndarray,
    gyro: F64,
    accel: F64,
    imu_rows: np.ndarray,
    gt_p: F64,
    gt_q_wxyz: F64,
    gt_v: F64,
    bg: F64,
    ba: F64,
    summary: dict[str, Any],
) -> None:
    mav0 = stage / "mav0"
    texts = dict(rig.yaml_texts)
    cam_rows = "".join(f"{int(t)},{int(t)}.png\n" for t in cam_t_ns)
    try:
        for cam in ("cam0", "cam1"):
            (mav0 / cam / "data.csv").write_text(CAM_HEADER + "\n" + cam_rows)
            (mav0 / cam / "sensor.yaml").write_text(texts[cam])
        # `imu_rows`: the samples the IMU delivered (a blackout drops some; the truth goes on)
        (mav0 / "imu0" / "data.csv").write_text(
            IMU_HEADER
            + "\n"
            + _rows(imu_t_ns[imu_rows], np.hstack([gyro, accel])[imu_rows], "%.17g")
        )
        (mav0 / "imu0" / "sensor.yaml").write_text(texts["imu0"])
        gt = np.hstack([gt_p, gt_q_wxyz, gt_v, bg, ba])
        (mav0 / "state_groundtruth_estimate0" / "data.csv").write_text(
            GT_HEADER + "\n" + _rows(imu_t_ns, gt, "%.12g")
        )
        (mav0 / "state_groundtruth_estimate0" / "sensor.yaml").write_text(GT_SENSOR_YAML)
        (mav0 / "body.yaml").write_text(BODY_YAML)
        (stage / "synth.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    except OSError as e:
        raise OutputError(f"{stage}: cannot write: {e}") from None


def write_tumvi_tables(
    stage: Path,
    kalibr_texts: dict[str, str],
    cam_t_ns: np.ndarray,
    imu_t_ns: np.ndarray,
    gyro: F64,
    accel: F64,
    imu_rows: np.ndarray,
    gt_p: F64,
    gt_q_wxyz: F64,
    summary: dict[str, Any],
) -> None:
    """The tables of a TUM-VI folder: `kalibr_texts` holds dso/camchain.yaml and
    dso/imu_config.yaml; the ground truth is the IMU's pose (mocap0, every IMU sample)."""
    mav0 = stage / "mav0"
    cam_rows = "".join(f"{int(t)},{int(t)}.png\n" for t in cam_t_ns)
    try:
        for name, text in kalibr_texts.items():
            (stage / "dso" / name).write_text(text)
        for cam in ("cam0", "cam1"):
            (mav0 / cam / "data.csv").write_text(CAM_HEADER + "\n" + cam_rows)
        (mav0 / "imu0" / "data.csv").write_text(
            IMU_HEADER
            + "\n"
            + _rows(imu_t_ns[imu_rows], np.hstack([gyro, accel])[imu_rows], "%.17g")
        )
        (mav0 / "mocap0" / "data.csv").write_text(
            MOCAP_HEADER + "\n" + _rows(imu_t_ns, np.hstack([gt_p, gt_q_wxyz]), "%.12g")
        )
        (stage / "synth.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    except OSError as e:
        raise OutputError(f"{stage}: cannot write: {e}") from None


def finish(stage: Path, out: Path) -> Path:
    """Move the finished staging folder into place (replacing `out` if asked earlier)."""
    out = Path(out)
    try:
        if out.exists():
            shutil.rmtree(out) if out.is_dir() else out.unlink()
        stage.rename(out)
    except OSError as e:
        raise OutputError(f"{out}: cannot move the finished sequence into place: {e}") from None
    return out
