"""Calibration of a bag input (bags carry none): a given rig, a `--calib DIR` folder, the
`sensor.yaml` files attached to an MCAP, or the built-in EuRoC calibration; and the extrinsic that
moves a raw Vicon marker pose (`TransformStamped`) to the body frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eurocslam.dataset.bag.files import mcap_sensor_yaml_texts
from eurocslam.dataset.bag.topics import EUROC_VICON_TOPIC
from eurocslam.dataset.calib import (
    StereoRig,
    default_rig,
    load_rig,
    load_sensor_yaml,
    rig_from_texts,
)
from eurocslam.errors import CalibrationError, DatasetError
from eurocslam.geometry import F64, make_T

BUILTIN = "built-in EuRoC calibration"

# EuRoC vicon0/sensor.yaml T_BS (Vicon marker -> body/IMU), identical in every V1/V2 sequence.
EUROC_T_BODY_VICON = np.array(
    [
        [0.33638, -0.01749, 0.94156, 0.06901],
        [-0.02078, -0.99972, -0.01114, -0.02781],
        [0.94150, -0.01582, -0.33665, -0.12395],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def orthonormalize(T: F64) -> F64:
    """Project the (4-decimal) rotation of a published T_BS onto SO(3)."""
    u, _, vt = np.linalg.svd(T[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:
        r = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    return make_T(r, T[:3, 3])


def resolve_calibration(
    path: Path, rig: StereoRig | None, calib_dir: Path | None, notes: list[str]
) -> tuple[StereoRig, str]:
    """The rig of a bag and where it came from (`BUILTIN` for the built-in EuRoC calibration):
    `rig` if given, else `calib_dir`, else the MCAP's attached sensor.yaml files."""
    if rig is not None:
        return rig, "given calibration"
    if calib_dir is not None:
        if not calib_dir.is_dir():
            raise CalibrationError(f"{calib_dir}: calibration folder not found")
        return load_rig(calib_dir), f"{calib_dir}"
    try:
        texts = mcap_sensor_yaml_texts(path)
    except DatasetError as e:  # e.g. an MCAP without a summary; the messages may be fine
        notes.append(f"attachments not read ({e})")
        texts = {}
    if texts:
        if not all(s in texts for s in ("cam0", "cam1")):
            raise CalibrationError(
                f"{path}: MCAP attachments hold sensor.yaml for {sorted(texts)} but not "
                "both cam0 and cam1; pass --calib DIR"
            )
        return rig_from_texts(texts, f"{path} (attachment)"), f"{path.name} attachments"
    return default_rig(), BUILTIN


def gt_sensor_extrinsic(calib_dir: Path | None, topic: str, notes: list[str]) -> F64:
    """`T_body_sensor` of a `TransformStamped` ground-truth topic: `vicon0/sensor.yaml`'s `T_BS`
    from `calib_dir`, EuRoC's for EuRoC's Vicon topic, else the identity (with a note)."""
    if calib_dir is not None and (calib_dir / "vicon0" / "sensor.yaml").is_file():
        ypath = calib_dir / "vicon0" / "sensor.yaml"
        data = load_sensor_yaml(ypath)
        t = data.get("T_BS")
        try:
            T = np.asarray(t["data"], dtype=np.float64).reshape(4, 4)  # type: ignore[index]
        except (TypeError, KeyError, ValueError):
            raise CalibrationError(f"{ypath}: key 'T_BS' must hold 16 numbers") from None
        notes.append(f"{topic}: Vicon marker pose moved to the body frame with {ypath}")
        return orthonormalize(T)
    if topic == EUROC_VICON_TOPIC:
        notes.append(
            f"{topic}: raw Vicon marker pose moved to the body (IMU) frame with EuRoC's "
            "vicon0 T_BS (pass --calib DIR with vicon0/sensor.yaml to use another)"
        )
        return orthonormalize(EUROC_T_BODY_VICON)
    notes.append(f"{topic}: TransformStamped taken as the body pose (no vicon0 T_BS)")
    return np.eye(4)
