"""The backend's measurement models: stereo factors in the rectified cam0 frame, and the IMU
(its data and noise model, to preintegrate any span again)."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from eurocslam.backend.preintegration import make_params
from eurocslam.camera import RectifiedStereo, triangulate_rect
from eurocslam.config import BackendConfig, ImuConfig
from eurocslam.dataset.calib import ImuCalib
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64


def pose(T: F64) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, dtype=np.float64))


def huber(base: gtsam.noiseModel.Base, k: float) -> gtsam.noiseModel.Base:
    """`base` made robust: Huber, quadratic within `k` sigmas, linear beyond."""
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k), base)


class StereoModel:
    """`GenericStereoFactor3D(X(k), L(j))` of (uL, uR, v) rectified measurements, with
    `body_P_sensor = T_body_rect0` and a Huber-robust isotropic noise of `stereo_sigma_px` times
    the keypoint's pyramid scale."""

    def __init__(self, stereo: RectifiedStereo, cfg: BackendConfig) -> None:
        self.geometry = stereo
        self.K = gtsam.Cal3_S2Stereo(
            stereo.fx, stereo.fy, 0.0, stereo.cx, stereo.cy, stereo.baseline
        )
        self.body_P_rect0 = pose(stereo.T_body_rect0)
        self._cfg = cfg
        self._noises: dict[float, gtsam.noiseModel.Base] = {}

    def noise(self, scale: float) -> gtsam.noiseModel.Base:
        m = self._noises.get(scale)
        if m is None:
            b = self._cfg
            base = gtsam.noiseModel.Isotropic.Sigma(3, b.stereo_sigma_px * max(scale, 1e-3))
            m = huber(base, b.huber_k)
            self._noises[scale] = m
        return m

    def point_covariance(self, uL: float, uR: float, v: float, scale: float) -> F64:
        """The covariance (3, 3) in rect0 of the point triangulated from one stereo measurement
        (uL, uR, v) with this model's pixel sigma (`stereo_sigma_px` x `scale`, each of uL, uR,
        v): J J^T sigma^2 with J the triangulation's Jacobian. Its depth sigma is
        z^2 sigma sqrt(2) / (fx b), its lateral ones z sigma / f."""
        g = self.geometry
        d = uL - uR
        z = g.fx * g.baseline / d
        x = (uL - g.cx) * z / g.fx
        y = (v - g.cy) * z / g.fy
        J = np.array(  # d(x, y, z) / d(uL, uR, v)
            [
                [z / g.fx - x / d, x / d, 0.0],
                [-y / d, y / d, z / g.fy],
                [-z / d, z / d, 0.0],
            ]
        )
        sigma = self._cfg.stereo_sigma_px * max(scale, 1e-3)
        return np.asarray(J @ J.T * sigma * sigma, dtype=np.float64)

    def point_information(self, uv: F64, scale: F64) -> F64:
        """The information (N, 3, 3) in rect0 of stereo measurements `uv` (N, 3: uL, uR, v)
        about the points they triangulate to: H^T H / sigma^2 with H = d(uL, uR, v) / d(x, y,
        z), the inverse of `point_covariance` (several views of one point add up)."""
        g = self.geometry
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 3)
        x, y, z = triangulate_rect(uv[:, 0], uv[:, 1], uv[:, 2], g).T
        H = np.zeros((len(uv), 3, 3))
        H[:, 0, 0] = H[:, 1, 0] = g.fx / z
        H[:, 0, 2] = -g.fx * x / z**2
        H[:, 1, 2] = -g.fx * (x - g.baseline) / z**2
        H[:, 2, 1] = g.fy / z
        H[:, 2, 2] = -g.fy * y / z**2
        sigma = self._cfg.stereo_sigma_px * np.maximum(np.asarray(scale, dtype=np.float64), 1e-3)
        return np.asarray(
            np.einsum("nki,nkj->nij", H, H) / (sigma**2)[:, None, None], dtype=np.float64
        )

    def factor(
        self, k: int, landmark_key: int, uL: float, uR: float, v: float, scale: float
    ) -> gtsam.GenericStereoFactor3D:
        return gtsam.GenericStereoFactor3D(
            gtsam.StereoPoint2(uL, uR, v),
            self.noise(scale),
            X(k),
            L(landmark_key),
            self.K,
            self.body_P_rect0,
        )


class ImuModel:
    """The IMU samples and their noise model (preintegration parameters, optionally with the
    accelerometer's covariances scaled)."""

    def __init__(self, imu: ImuData, calib: ImuCalib, cfg: ImuConfig) -> None:
        self.data = imu
        self.calib = calib
        self.cfg = cfg
        self.params = make_params(calib, cfg)

    def params_scaled(self, accel_scale: float) -> gtsam.PreintegrationCombinedParams:
        return make_params(self.calib, self.cfg, accel_scale)
