"""Calibration of a bag input, in this order: a given rig, a `--calib DIR` folder, the
`sensor.yaml` files attached to an MCAP, the bag's own CameraInfo and `/tf_static` (`bag_rig`,
built by the reader after its pass over the bag), or the built-in EuRoC calibration; and the
extrinsic that moves a raw Vicon marker pose (`TransformStamped`) to the body frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eurocslam.dataset.bag.bag_rig import BagCamera, rig_from_camera_infos
from eurocslam.dataset.bag.files import mcap_sensor_yaml_texts
from eurocslam.dataset.bag.static import BagStatic
from eurocslam.dataset.bag.stats import ImageInfo
from eurocslam.dataset.bag.topics import EUROC_VICON_TOPIC
from eurocslam.dataset.calib import (
    ImuCalib,
    StereoRig,
    default_rig,
    load_rig,
    load_sensor_yaml,
    rig_from_texts,
)
from eurocslam.dataset.imu_noise import NoiseFigures, default_figures, with_imu_noise
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


def bag_calibration_name(path: Path, with_imu: bool) -> str:
    """`calib_source` of a rig built from a bag's CameraInfo (and /tf_static)."""
    return f"CameraInfo{' + /tf_static' if with_imu else ''} of {path.name}"


def imu_calibration(rate_hz: float) -> ImuCalib:
    """The IMU of a rig from a bag: the body frame itself, the measured rate; its noise figures
    come from outside the bag (`dataset/imu_noise.py`), the packaged defaults until then."""
    d = default_figures()
    assert d.complete
    return ImuCalib(
        T_body_imu=np.eye(4),
        rate_hz=rate_hz,
        gyro_noise_density=float(d.gyroscope_noise_density),  # type: ignore[arg-type]
        gyro_random_walk=float(d.gyroscope_random_walk),  # type: ignore[arg-type]
        accel_noise_density=float(d.accelerometer_noise_density),  # type: ignore[arg-type]
        accel_random_walk=float(d.accelerometer_random_walk),  # type: ignore[arg-type]
    )


def resolve_calibration(
    path: Path, rig: StereoRig | None, calib_dir: Path | None, notes: list[str]
) -> tuple[StereoRig | None, str]:
    """The rig of a bag given from outside it, and where it came from: `rig` if given, else
    `calib_dir`, else the MCAP's attached sensor.yaml files; (None, "") when none of them (the
    reader then reads the bag's CameraInfo, else takes the built-in EuRoC calibration)."""
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
    return None, ""


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


def rig_from_bag(
    path: Path,
    static: BagStatic,
    cameras: dict[str, tuple[str, ImageInfo | None, float]],
    imu: tuple[str, float] | None,
    notes: list[str],
) -> tuple[StereoRig, str]:
    """The rig from the bag's CameraInfo and /tf_static (`bag_rig`) and its `calib_source`;
    EuRoC's built in when the bag has no CameraInfo (the image size check then guards against
    a foreign camera). `cameras`: cam0/cam1 -> (image topic, first image, measured rate);
    `imu`: (the IMU topic whose frame is the body, its measured rate), None without one."""
    have = [c for c in ("cam0", "cam1") if c in static.camera_infos]
    if not have:
        return default_rig(), BUILTIN
    if len(have) == 1:
        other = "cam1" if have[0] == "cam0" else "cam0"
        raise CalibrationError(
            f"{path}: {static.camera_infos[have[0]].topic} gives {have[0]}'s calibration "
            f"but {cameras[other][0]} has no CameraInfo beside it (name it with "
            f"--topic {other}_info=TOPIC, or pass --calib DIR)"
        )
    cams = []
    for role in ("cam0", "cam1"):
        topic, image, rate = cameras[role]
        cams.append(
            BagCamera(
                role=role,
                image_topic=topic,
                frame_id=static.frame_ids.get(role, ""),
                image_size=(image.width, image.height) if image is not None else None,
                rate_hz=rate,
                info=static.camera_infos[role],
            )
        )
    imu_frame = None
    imu_calib = None
    if imu is not None:
        topic, rate = imu
        imu_frame = static.frame_ids.get("gyro", static.frame_ids.get("imu", ""))
        if not imu_frame:
            raise CalibrationError(
                f"{path}: {topic}: the IMU messages have no header.frame_id, so the cameras "
                "cannot be placed relative to the IMU (pass --calib DIR)"
            )
        imu_calib = imu_calibration(rate)
    rig = rig_from_camera_infos(cams[0], cams[1], static.tf, imu_frame, imu_calib, notes)
    return rig, bag_calibration_name(path, imu_frame is not None)


def apply_imu_noise(
    rig: StereoRig, noise: NoiseFigures | None, from_bag: bool, calib_source: str, notes: list[str]
) -> StereoRig:
    """IMU noise figures from outside the bag (`--imu-calib`, the config's `imu:`) replace
    the calibration's; a rig from the bag's CameraInfo takes the packaged defaults for the ones
    not given, with a note."""
    if rig.imu is None:
        return rig
    given = noise if noise is not None else NoiseFigures()
    if from_bag and calib_source != BUILTIN:
        if not given.complete:
            which = "none given" if given.empty else "some not given"
            notes.append(
                f"IMU noise: the bag carries no figures ({which}): using "
                f"{default_figures().source} (give yours with --imu-calib imu.yaml or the "
                "imu: section of --config)"
            )
        rig = with_imu_noise(rig, given.over(default_figures()), calib_source)
    elif not given.empty:
        rig = with_imu_noise(rig, given, given.source)
    if not given.empty:
        notes.append(f"IMU noise figures from {given.source}")
    return rig
