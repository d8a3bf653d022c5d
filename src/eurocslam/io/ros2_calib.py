"""The sensor calibration as ROS 2 messages: sensor_msgs/CameraInfo of both cameras (K, D and the
stereo R/P of the rectification SLAM uses) and the IMU noise as sensor_msgs/Imu covariances.

The R and P come from `eurocslam.camera.rectify_stereo`, the function the frontend rectifies its
images with; pass the run's `rectify_alpha` so that the CameraInfo in run.mcap describes the
rectification the run used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eurocslam.camera import rectify_stereo
from eurocslam.dataset.calib import CameraCalib, ImuCalib, StereoRig
from eurocslam.geometry import F64
from eurocslam.io.cdr import CdrWriter


@dataclass(frozen=True)
class CameraInfoData:
    """The static part of a sensor_msgs/CameraInfo (everything but the header)."""

    width: int
    height: int
    distortion_model: str
    D: F64
    K: F64  # 3x3
    R: F64  # 3x3 rectification rotation
    P: F64  # 3x4 projection of the rectified camera


def stereo_camera_infos(
    rig: StereoRig, alpha: float = 0.0, fov_deg: float | None = None, size: str = "image"
) -> tuple[CameraInfoData, CameraInfoData]:
    """CameraInfo for cam0 and cam1: K, the camera model's distortion (`plumb_bob` with 5
    coefficients for a pinhole camera, `equidistant` with k1..k4 for a fisheye) and R/P of
    `rectify_stereo(rig, alpha, fov_deg, size)` (zero disparity at infinity; with size "focal"
    the rectified images are larger than the raw ones: P is theirs). cam1's
    P[0, 3] = -fx' * baseline, as in ROS."""
    rect = rectify_stereo(rig, alpha, fov_deg, size)
    return _info(rig.cam0, rect.R_rect0_cam0, rect.P0), _info(rig.cam1, rect.R_rect1_cam1, rect.P1)


def _info(c: CameraCalib, R: F64, P: F64) -> CameraInfoData:
    return CameraInfoData(
        c.width,
        c.height,
        c.model.ros_name,
        c.model.ros_coeffs(),
        c.K.copy(),
        np.asarray(R, dtype=np.float64),
        np.asarray(P, dtype=np.float64),
    )


def camera_info(t_ns: int, frame_id: str, info: CameraInfoData) -> bytes:
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.u32(info.height)
    out.u32(info.width)
    out.string(info.distortion_model)
    out.f64_seq(info.D)
    out.f64_fixed(info.K, 9)
    out.f64_fixed(info.R, 9)
    out.f64_fixed(info.P, 12)
    out.u32(0)  # binning_x
    out.u32(0)  # binning_y
    for _ in range(4):  # roi: x_offset, y_offset, height, width (all 0 = full image)
        out.u32(0)
    out.bool(False)  # roi.do_rectify
    return out.getvalue()


def imu_covariances(calib: ImuCalib) -> tuple[F64, F64]:
    """Diagonal 3x3 gyro and accel covariances of one sample: density**2 / dt (= * rate_hz)."""
    return (np.eye(3) * calib.discrete_gyro_variance(), np.eye(3) * calib.discrete_accel_variance())
