"""The backend's measurement models: stereo factors in the rectified cam0 frame, and the IMU
(its data and noise model, to preintegrate any span again)."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from eurocslam.backend.preintegration import make_params
from eurocslam.camera import RectifiedStereo
from eurocslam.config import BackendConfig, ImuConfig
from eurocslam.dataset.calib import ImuCalib
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64


def pose(T: F64) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, dtype=np.float64))


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
            m = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(b.huber_k), base
            )
            self._noises[scale] = m
        return m

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
