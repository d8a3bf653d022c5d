"""Writing a calibration as EuRoC-style `sensor.yaml` files (for sources that carry their
calibration in another form, e.g. KITTI's calib.txt, a Kalibr camchain: MCAP attachments, ASL
copies)."""

from __future__ import annotations

import numpy as np

from eurocslam.dataset.calib import CameraCalib, ImuCalib


def _yaml_float(v: float) -> str:
    """A float as YAML that reads back to the same double (repr; integers keep a '.0')."""
    return repr(float(v))


def camera_yaml_text(cam: CameraCalib, comment: str = "") -> str:
    """An EuRoC-style `sensor.yaml` for `cam` that `camera_from_yaml` reads back to the same
    values (every float written with `repr`, so it round-trips exactly)."""
    T = ", ".join(_yaml_float(v) for v in np.asarray(cam.T_body_cam, dtype=np.float64).ravel())
    intr = ", ".join(_yaml_float(v) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    dist = ", ".join(_yaml_float(v) for v in (cam.distortion or (0.0, 0.0, 0.0, 0.0)))
    lines = [
        "%YAML:1.0",
        "sensor_type: camera",
        f"comment: {comment or cam.name}",
        "T_BS:",
        "  cols: 4",
        "  rows: 4",
        f"  data: [{T}]",
        f"rate_hz: {_yaml_float(cam.rate_hz)}",
        f"resolution: [{cam.width}, {cam.height}]",
        "camera_model: pinhole",
        f"intrinsics: [{intr}]",
        f"distortion_model: {cam.distortion_model}",
        f"distortion_coefficients: [{dist}]",
    ]
    return "\n".join(lines) + "\n"


def imu_yaml_text(imu: ImuCalib, comment: str = "") -> str:
    """An EuRoC-style imu0 `sensor.yaml` for `imu` that `imu_from_yaml` reads back exactly."""
    T = ", ".join(_yaml_float(v) for v in np.asarray(imu.T_body_imu, dtype=np.float64).ravel())
    lines = [
        "%YAML:1.0",
        "sensor_type: imu",
        f"comment: {comment or 'imu0'}",
        "T_BS:",
        "  cols: 4",
        "  rows: 4",
        f"  data: [{T}]",
        f"rate_hz: {_yaml_float(imu.rate_hz)}",
        f"gyroscope_noise_density: {_yaml_float(imu.gyro_noise_density)}",
        f"gyroscope_random_walk: {_yaml_float(imu.gyro_random_walk)}",
        f"accelerometer_noise_density: {_yaml_float(imu.accel_noise_density)}",
        f"accelerometer_random_walk: {_yaml_float(imu.accel_random_walk)}",
    ]
    return "\n".join(lines) + "\n"
