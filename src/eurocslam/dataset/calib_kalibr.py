"""Calibration from Kalibr's files: `camchain.yaml` (cameras) and `imu.yaml` (IMU noise).

`camchain.yaml` (Kalibr's camchain or camchain-imucam output; TUM-VI ships one as
`dso/camchain.yaml`) holds per camera `cam0`, `cam1`:

- `camera_model` (`pinhole`), `distortion_model` (`radtan`, `equidistant`, `none`),
  `intrinsics` [fu, fv, pu, pv], `distortion_coeffs`, `resolution` [width, height];
- `T_cam_imu`: 4x4, maps IMU points into the camera (camchain-imucam only);
- `T_cn_cnm1` (cam1 and later): 4x4, maps the previous camera's points into this one.

With `T_cam_imu` the body frame is the IMU (`T_body_cam = T_cam_imu^-1`); a camera without it is
placed by `T_cn_cnm1`. A camchain without any `T_cam_imu` (a camera-only calibration) gives a
stereo-only rig whose body is cam0: the IMU's place is unknown. A camera that has both is
placed by `T_cam_imu` (the doctor says when the two disagree).

`imu.yaml` (Kalibr's IMU description; TUM-VI's `dso/imu_config.yaml` is one): the noise densities
and random walks (`accelerometer_noise_density`, `accelerometer_random_walk`,
`gyroscope_noise_density`, `gyroscope_random_walk`), `update_rate`, either at the top level or
under `imu0` (Kalibr's result files), optionally `T_i_b` (body -> IMU; the identity when absent).

Camera rates are not in a camchain: the caller passes them (measured from the data), as it
passes the IMU noise to use when there is no imu.yaml (`ImuNoise`, with a note). Every error names
the file and the key (`cam1.intrinsics`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.calib import (
    check_coefficient_count,
    distortion_model_of,
    float_list,
    load_sensor_yaml_text,
    read_yaml_text,
    require_key,
)
from eurocslam.dataset.calib_yaml import camera_yaml_text, imu_yaml_text
from eurocslam.dataset.doctor.calib_checks import (
    CalibIssue,
    check_camera,
    check_imu,
    check_stereo,
    check_transform,
)
from eurocslam.dataset.rig import CameraCalib, ImuCalib, StereoRig
from eurocslam.errors import CalibrationError
from eurocslam.geometry import F64, inv_T

CAMERAS = ("cam0", "cam1")
NOISE_KEYS = (
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
)


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise: densities and random walks (imu.yaml's four keys)."""

    gyroscope_noise_density: float
    gyroscope_random_walk: float
    accelerometer_noise_density: float
    accelerometer_random_walk: float


@dataclass(frozen=True)
class KalibrCamera:
    """One camera of a camchain, as read (before the rig is assembled)."""

    name: str
    calib: CameraCalib  # T_body_cam still the identity: placed by `kalibr_rig`
    T_cam_imu: F64 | None
    T_cn_cnm1: F64 | None


def _matrix(value: Any, key: str, path: Path | str) -> F64:
    """A 4x4 matrix written as four rows (Kalibr) or 16 numbers."""
    rows = value if isinstance(value, list) else None
    if rows is not None and len(rows) == 4 and all(isinstance(r, list) for r in rows):
        vals = [v for r in rows for v in float_list(r, 4, key, path)]
    else:
        vals = float_list(value, 16, key, path)
    return np.array(vals, dtype=np.float64).reshape(4, 4)


def _prefixed(issues: list[CalibIssue], prefix: str) -> list[CalibIssue]:
    return [CalibIssue(i.severity, prefix + i.key, i.message) for i in issues]


def _raise(issues: list[CalibIssue], path: Path | str) -> None:
    for i in issues:
        if i.severity == "error":
            raise CalibrationError(f"{path}: key '{i.key}': {i.message}")


def read_camchain(
    data: dict[str, Any], path: Path | str, rates_hz: dict[str, float]
) -> list[KalibrCamera]:
    """cam0 and cam1 of a parsed camchain (no plausibility checks: `camchain_issues`)."""
    out = []
    for name in CAMERAS:
        cam = require_key(data, name, path)
        if not isinstance(cam, dict):
            raise CalibrationError(f"{path}: key '{name}' must be a mapping of the camera's keys")

        def key(k: str, _name: str = name) -> str:
            return f"{_name}.{k}"

        model = str(cam.get("camera_model", "pinhole"))
        if model != "pinhole":
            raise CalibrationError(
                f"{path}: key '{key('camera_model')}': '{model}' not supported (only pinhole; "
                "omni and double sphere cameras are not)"
            )
        dmodel = distortion_model_of(
            cam.get("distortion_model", "none"), path, key("distortion_model")
        )
        intr = float_list(require_key(cam, "intrinsics", path), 4, key("intrinsics"), path)
        res = float_list(require_key(cam, "resolution", path), 2, key("resolution"), path)
        if any(r != int(r) for r in res):
            raise CalibrationError(f"{path}: key '{key('resolution')}' must be whole pixels")
        dist = float_list(cam.get("distortion_coeffs", []), None, key("distortion_coeffs"), path)
        if dmodel == "none" and not dist:
            dist = [0.0, 0.0, 0.0, 0.0]
        check_coefficient_count(dmodel, dist, key("distortion_coeffs"), path)
        rate = rates_hz.get(name) or cam.get("rate_hz")
        if not rate:
            raise CalibrationError(
                f"{path}: key '{key('rate_hz')}': missing, and no {name}/data.csv to measure "
                "the camera's rate from (a camchain holds none)"
            )
        calib = CameraCalib(
            name=name,
            T_body_cam=np.eye(4),
            rate_hz=float_list([rate], 1, key("rate_hz"), path)[0],
            width=int(res[0]),
            height=int(res[1]),
            fx=intr[0],
            fy=intr[1],
            cx=intr[2],
            cy=intr[3],
            distortion=tuple(dist),
            distortion_model=dmodel,
        )
        T_ci = _matrix(cam["T_cam_imu"], key("T_cam_imu"), path) if "T_cam_imu" in cam else None
        T_cc = _matrix(cam["T_cn_cnm1"], key("T_cn_cnm1"), path) if "T_cn_cnm1" in cam else None
        out.append(KalibrCamera(name, calib, T_ci, T_cc))
    return out


def camchain_issues(cams: list[KalibrCamera]) -> list[CalibIssue]:
    """Plausibility of each camera and transform (keys prefixed `camN.`), and the agreement of
    cam1's two placements when it has both."""
    out: list[CalibIssue] = []
    for c in cams:
        out += _prefixed(check_camera(c.calib), f"{c.name}.")
        for T, k in ((c.T_cam_imu, "T_cam_imu"), (c.T_cn_cnm1, "T_cn_cnm1")):
            if T is not None:
                out += check_transform(T, f"{c.name}.{k}")
    c0, c1 = cams[0], cams[1]
    if c0.T_cam_imu is not None and c1.T_cam_imu is not None and c1.T_cn_cnm1 is not None:
        chained = c1.T_cn_cnm1 @ c0.T_cam_imu
        dt = float(np.linalg.norm(chained[:3, 3] - c1.T_cam_imu[:3, 3]))
        dR = chained[:3, :3] @ c1.T_cam_imu[:3, :3].T
        dang = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1.0, 1.0))))
        if dt > 1e-3 or dang > 0.1:
            out.append(
                CalibIssue(
                    "warning",
                    "cam1.T_cn_cnm1",
                    f"disagrees with cam0.T_cam_imu and cam1.T_cam_imu by {dt * 1000:.1f} mm, "
                    f"{dang:.2f} deg (T_cam_imu is used)",
                )
            )
    return out


def place_cameras(
    cams: list[KalibrCamera], path: Path | str, T_body_imu: F64
) -> tuple[CameraCalib, CameraCalib, bool]:
    """cam0 and cam1 with their `T_body_cam`, and whether the IMU's place is known."""
    from dataclasses import replace

    c0, c1 = cams
    has_imu = c0.T_cam_imu is not None
    T_body_cam0 = T_body_imu @ inv_T(c0.T_cam_imu) if c0.T_cam_imu is not None else np.eye(4)
    if has_imu and c1.T_cam_imu is not None:
        T_body_cam1 = T_body_imu @ inv_T(c1.T_cam_imu)
    elif c1.T_cn_cnm1 is not None:
        T_body_cam1 = T_body_cam0 @ inv_T(c1.T_cn_cnm1)
    else:
        need = "T_cam_imu or T_cn_cnm1" if has_imu else "T_cn_cnm1"
        raise CalibrationError(
            f"{path}: key 'cam1.{need.split(' ')[-1]}': missing: cam1 needs {need} to be placed"
        )
    return (
        replace(c0.calib, T_body_cam=T_body_cam0),
        replace(c1.calib, T_body_cam=T_body_cam1),
        has_imu,
    )


def read_imu_yaml(data: dict[str, Any], path: Path | str) -> tuple[ImuNoise, float | None, F64]:
    """Noise, `update_rate` (None if absent) and `T_body_imu` of a parsed imu.yaml."""
    imu = data.get("imu0", data)
    if not isinstance(imu, dict):
        raise CalibrationError(f"{path}: key 'imu0' must be a mapping of the IMU's keys")
    prefix = "imu0." if "imu0" in data else ""

    def value(k: str) -> float:
        if k not in imu:
            raise CalibrationError(f"{path}: missing key '{prefix}{k}'")
        return float_list([imu[k]], 1, prefix + k, path)[0]

    noise = ImuNoise(*(value(k) for k in NOISE_KEYS))
    rate = value("update_rate") if "update_rate" in imu else None
    T_i_b = _matrix(imu["T_i_b"], prefix + "T_i_b", path) if "T_i_b" in imu else np.eye(4)
    _raise(check_transform(T_i_b, prefix + "T_i_b"), path)
    return noise, rate, inv_T(T_i_b)


def kalibr_rig(
    camchain: Path | str,
    imu_path: Path | str | None,
    rates_hz: dict[str, float],
    default_noise: ImuNoise,
    notes: list[str],
) -> StereoRig:
    """The rig of a camchain.yaml (+ imu.yaml). `rates_hz`: camera and IMU rates measured from
    the data (`cam0`, `cam1`, `imu0`; an imu.yaml's `update_rate` wins); `default_noise` when
    there is no imu.yaml (a note says so)."""
    data = load_sensor_yaml_text(read_yaml_text(camchain), camchain)
    cams = read_camchain(data, camchain, rates_hz)
    _raise(camchain_issues(cams), camchain)
    T_body_imu = np.eye(4)
    noise, imu_rate = default_noise, rates_hz.get("imu0")
    if imu_path is not None:
        idata = load_sensor_yaml_text(read_yaml_text(imu_path), imu_path)
        noise, rate, T_body_imu = read_imu_yaml(idata, imu_path)
        imu_rate = rate if rate is not None else imu_rate
    cam0, cam1, has_imu = place_cameras(cams, camchain, T_body_imu)
    imu: ImuCalib | None = None
    if not has_imu:
        notes.append(f"{camchain}: no T_cam_imu (a camera-only calibration): visual-only")
    elif not imu_rate:
        notes.append(f"{camchain}: no IMU rows to measure the IMU's rate from: visual-only")
    else:
        if imu_path is None:
            notes.append(
                f"IMU noise: no imu.yaml beside {camchain}: the defaults of "
                "eurocslam/data/imu_noise_defaults.yaml are used"
            )
        imu = ImuCalib(
            T_body_imu=T_body_imu,
            rate_hz=float(imu_rate),
            gyro_noise_density=noise.gyroscope_noise_density,
            gyro_random_walk=noise.gyroscope_random_walk,
            accel_noise_density=noise.accelerometer_noise_density,
            accel_random_walk=noise.accelerometer_random_walk,
        )
        _raise(check_imu(imu), imu_path or camchain)
    origin = f"Kalibr {Path(camchain).name}"
    texts = {
        "cam0": camera_yaml_text(cam0, f"cam0 of {origin}"),
        "cam1": camera_yaml_text(cam1, f"cam1 of {origin}"),
    }
    if imu is not None:
        texts["imu0"] = imu_yaml_text(imu, f"imu0 of {origin}")
    rig = StereoRig(cam0, cam1, imu, tuple(sorted(texts.items())))
    _raise(check_stereo(rig), camchain)
    return rig
