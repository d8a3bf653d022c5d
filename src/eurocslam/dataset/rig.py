"""The rig's calibration as types: cameras, the IMU and the stereo rig they form.

Built by the loaders (`dataset/calib.py` and the other calibration sources), checked by
`dataset/doctor/calib_checks.py`; everything else reads them. A camera's `T_body_cam` maps camera
points into the body (IMU) frame.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from eurocslam.camera_models import CameraModel, make_camera_model
from eurocslam.geometry import F64, inv_T


@dataclass(frozen=True)
class CameraCalib:
    """One camera: extrinsics, rate, image size, intrinsics and distortion.

    `distortion_model` names the camera model (`eurocslam.camera_models.MODELS`:
    "radial-tangential" as EuRoC's, "equidistant" for a Kannala-Brandt fisheye as TUM-VI's,
    "none" for a rectified pinhole) and `distortion` holds its coefficients (radial-tangential:
    k1, k2, p1, p2[, k3] in OpenCV's order; equidistant: k1..k4). `model` is the projection
    they make, the one interface everything that projects or unprojects uses."""

    name: str
    T_body_cam: F64
    rate_hz: float
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...]  # the model's coefficients (see the docstring)
    distortion_model: str = "radial-tangential"

    @functools.cached_property
    def model(self) -> CameraModel:
        """The camera model (projection, unprojection, valid region) of these intrinsics."""
        return make_camera_model(
            self.distortion_model, self.fx, self.fy, self.cx, self.cy, tuple(self.distortion)
        )

    @property
    def K(self) -> F64:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> F64:
        """The coefficients as OpenCV takes them (radial-tangential: `cv2.*`; equidistant:
        `cv2.fisheye.*`)."""
        return np.array(self.distortion, dtype=np.float64)

    @property
    def resolution(self) -> tuple[int, int]:
        return self.width, self.height


@dataclass(frozen=True)
class ImuCalib:
    """IMU noise model (continuous-time densities) and extrinsics, from imu0/sensor.yaml."""

    T_body_imu: F64
    rate_hz: float
    gyro_noise_density: float  # rad/s/sqrt(Hz)
    gyro_random_walk: float  # rad/s^2/sqrt(Hz)
    accel_noise_density: float  # m/s^2/sqrt(Hz)
    accel_random_walk: float  # m/s^3/sqrt(Hz)

    def discrete_gyro_variance(self, dt: float | None = None) -> float:
        """Per-sample white-noise variance: density**2 / dt."""
        return self.gyro_noise_density**2 / (dt if dt else 1.0 / self.rate_hz)

    def discrete_accel_variance(self, dt: float | None = None) -> float:
        return self.accel_noise_density**2 / (dt if dt else 1.0 / self.rate_hz)


@dataclass(frozen=True)
class StereoRig:
    """Two cameras and, on a stereo-inertial rig, the IMU (`imu` is None on a stereo-only rig)."""

    cam0: CameraCalib
    cam1: CameraCalib
    imu: ImuCalib | None
    # raw text of each sensor.yaml, keyed by sensor name (for MCAP attachments / synth output)
    yaml_texts: tuple[tuple[str, str], ...] = ()

    @property
    def T_cam1_cam0(self) -> F64:
        return inv_T(self.cam1.T_body_cam) @ self.cam0.T_body_cam

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T_cam1_cam0[:3, 3]))
