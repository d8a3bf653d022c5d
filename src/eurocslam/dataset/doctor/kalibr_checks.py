"""The doctor on a Kalibr calibration source (a `camchain.yaml` and its `imu.yaml`: TUM-VI's
`dso/`, Kalibr's output beside an ASL folder, `--calib FILE`): what cannot be read is an error
naming the file and key, each camera and transform is checked as the loaders check them, and the
rig's stereo geometry and IMU noise too. Returns the cameras, so the images can be checked
against their sizes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eurocslam.dataset.calib import load_sensor_yaml_text, read_yaml_text
from eurocslam.dataset.calib_kalibr import (
    camchain_issues,
    place_cameras,
    read_camchain,
    read_imu_yaml,
)
from eurocslam.dataset.calib_sources import CalibrationSource, default_imu_noise
from eurocslam.dataset.doctor.calib_checks import CalibIssue, check_imu, check_stereo_pair
from eurocslam.dataset.doctor.report import INFO, WARNING, Findings
from eurocslam.dataset.rig import CameraCalib, ImuCalib
from eurocslam.geometry import F64


def _add(found: Findings, issues: list[CalibIssue], path: Path, prefix: str = "") -> None:
    for i in issues:
        found.add(i.severity, "calibration", prefix + i.message, path, key=i.key)


def check_kalibr_source(
    found: Findings, src: CalibrationSource, rates_hz: dict[str, float]
) -> dict[str, CameraCalib]:
    """Findings of one Kalibr source; the cameras read from it (none if it cannot be read:
    the error finding says why)."""
    cams: dict[str, CameraCalib] = {}
    with found.guard("calibration", src.path):
        data = load_sensor_yaml_text(read_yaml_text(src.path), src.path)
        chain = read_camchain(data, src.path, rates_hz)
        _add(found, camchain_issues(chain), src.path)
        T_body_imu: F64 = np.eye(4)
        imu_rate = rates_hz.get("imu0")
        noise = default_imu_noise()
        if src.imu_path is not None:
            with found.guard("calibration", src.imu_path):
                idata = load_sensor_yaml_text(read_yaml_text(src.imu_path), src.imu_path)
                noise, rate, T_body_imu = read_imu_yaml(idata, src.imu_path)
                imu_rate = rate if rate is not None else imu_rate
        elif chain[0].T_cam_imu is not None:
            found.add(
                WARNING,
                "calibration",
                "no imu.yaml beside it: the IMU noise defaults "
                "(eurocslam/data/imu_noise_defaults.yaml) are used",
                src.path,
            )
        cam0, cam1, has_imu = place_cameras(chain, src.path, T_body_imu)
        cams = {"cam0": cam0, "cam1": cam1}
        _add(found, check_stereo_pair(cam0, cam1), src.path, "stereo: ")
        if not has_imu:
            found.add(
                INFO,
                "calibration",
                "no T_cam_imu (a camera-only calibration): the sequence runs visual-only",
                src.path,
            )
        elif imu_rate:
            imu = ImuCalib(
                T_body_imu=T_body_imu,
                rate_hz=float(imu_rate),
                gyro_noise_density=noise.gyroscope_noise_density,
                gyro_random_walk=noise.gyroscope_random_walk,
                accel_noise_density=noise.accelerometer_noise_density,
                accel_random_walk=noise.accelerometer_random_walk,
            )
            _add(found, check_imu(imu), src.imu_path or src.path)
    return cams
