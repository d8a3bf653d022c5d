"""Image-free simulation for testing and benchmarking the backend on its own.

Produces, from a smooth known motion, what the frontend and the IMU would deliver: IMU samples
(specific force and angular rate in the body frame, with optional white noise and constant
biases) and stereo observations (uL, uR, v) in the rectified cam0 frame of random 3D landmarks.
The backend can then be checked against the exact ground truth (ATE in millimetres) without
rendering or matching a single image.

The motion is analytic (sums of sines for position and attitude) on top of a base attitude whose
body x axis points up, as on the EuRoC drone; rates and accelerations come from central
differences of the analytic functions (error far below the IMU noise).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from eurocslam.camera import RectifiedStereo
from eurocslam.dataset.calib import default_rig
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64, inv_T, make_T, so3_exp, so3_log
from eurocslam.timebase import NS_PER_S

# EuRoC-like mounting: body x points up (world z), body z forward (world x), body y = z cross x
R_WORLD_BODY_BASE = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])


def euroc_like_stereo() -> RectifiedStereo:
    """Rectified EuRoC-like stereo (752x480, fx 435, baseline 0.11 m) mounted with the real
    EuRoC cam0 extrinsics, so tests exercise a non-trivial `body_P_sensor`."""
    T_body_cam0 = np.asarray(default_rig().cam0.T_body_cam, dtype=np.float64)
    return RectifiedStereo(
        fx=435.0,
        fy=435.0,
        cx=376.0,
        cy=240.0,
        baseline=0.11,
        width=752,
        height=480,
        T_body_rect0=T_body_cam0,
    )


@dataclass(frozen=True)
class Motion:
    """Analytic smooth motion: `pose(t)` -> T_world_body at float seconds."""

    pose: Callable[[float], F64]
    duration_s: float


def lissajous_motion(
    duration_s: float = 20.0, scale: float = 1.0, rot_scale: float = 1.0
) -> Motion:
    """A room-scale figure-eight with attitude oscillations (EuRoC V-room-like speeds)."""

    def pose(t: float) -> F64:
        p = scale * np.array(
            [1.5 * np.sin(0.35 * t), 1.0 * np.sin(0.7 * t + 0.3), 0.3 * np.sin(0.45 * t) + 1.0]
        )
        w = rot_scale * np.array(
            [0.15 * np.sin(0.9 * t), 0.12 * np.sin(0.6 * t + 1.0), 0.8 * np.sin(0.25 * t)]
        )
        R = so3_exp(w) @ R_WORLD_BODY_BASE
        return make_T(R, p)

    return Motion(pose, duration_s)


def still_motion(duration_s: float = 5.0) -> Motion:
    def pose(t: float) -> F64:
        return make_T(R_WORLD_BODY_BASE, np.array([0.0, 0.0, 1.0]))

    return Motion(pose, duration_s)


def imu_from_motion(
    motion: Motion,
    t0_ns: int,
    rate_hz: float = 200.0,
    *,
    gravity: float = 9.81,
    bg: F64 | None = None,
    ba: F64 | None = None,
    gyro_sigma: float = 0.0,
    accel_sigma: float = 0.0,
    seed: int = 0,
    pad_s: float = 1.0,
) -> ImuData:
    """Instantaneous IMU samples from `-pad_s` to `duration + pad_s` (as a real IMU and the
    synthetic sequences deliver them)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    ts = np.arange(-pad_s, motion.duration_s + pad_s, dt)
    g_world = np.array([0.0, 0.0, -gravity])
    h = 1e-4
    gyro = np.empty((ts.size, 3))
    acc = np.empty((ts.size, 3))
    for i, t in enumerate(ts):
        tm = t
        T0 = motion.pose(tm - h)
        T1 = motion.pose(tm)
        T2 = motion.pose(tm + h)
        R = T1[:3, :3]
        # body angular rate: Log(R(t-h)^T R(t+h)) / 2h
        gyro[i] = so3_log(T0[:3, :3].T @ T2[:3, :3]) / (2 * h)
        a_world = (T2[:3, 3] - 2 * T1[:3, 3] + T0[:3, 3]) / (h * h)
        acc[i] = R.T @ (a_world - g_world)
    if bg is not None:
        gyro += bg
    if ba is not None:
        acc += ba
    if gyro_sigma > 0:
        gyro += rng.normal(0.0, gyro_sigma, gyro.shape)
    if accel_sigma > 0:
        acc += rng.normal(0.0, accel_sigma, acc.shape)
    t_ns = t0_ns + np.round(ts * NS_PER_S).astype(np.int64)
    return ImuData(t_ns, gyro, acc)


def random_landmarks(n: int, seed: int = 0, half_extent: float = 6.0) -> F64:
    """Points on the walls, floor and ceiling of a room around the origin."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-half_extent, half_extent, (n, 3))
    face = rng.integers(0, 6, n)
    for i in range(n):
        ax = face[i] // 2
        pts[i, ax] = half_extent if face[i] % 2 else -half_extent
    pts[:, 2] = np.clip(pts[:, 2] * 0.5 + 1.5, -1.5, 4.5)
    return pts


@dataclass(frozen=True)
class StereoObs:
    ids: np.ndarray  # (N,) int64
    uv: F64  # (N, 3) uL, uR, v


def observe(
    T_world_body: F64,
    landmarks: F64,
    stereo: RectifiedStereo,
    *,
    pixel_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
    max_depth: float = 20.0,
    max_n: int = 150,
) -> StereoObs:
    """Stereo observations of the landmarks visible from `T_world_body`."""
    T_rect0_world = inv_T(T_world_body @ stereo.T_body_rect0)
    Xc = landmarks @ T_rect0_world[:3, :3].T + T_rect0_world[:3, 3]
    z = Xc[:, 2]
    ok = (z > 0.3) & (z < max_depth)
    uL = stereo.fx * Xc[:, 0] / np.where(ok, z, 1.0) + stereo.cx
    v = stereo.fy * Xc[:, 1] / np.where(ok, z, 1.0) + stereo.cy
    uR = uL - stereo.fx * stereo.baseline / np.where(ok, z, 1.0)
    ok &= (uL >= 0) & (uL < stereo.width) & (uR >= 0) & (v >= 0) & (v < stereo.height)
    ids = np.nonzero(ok)[0]
    if ids.size > max_n:
        ids = ids[:max_n]
    uv = np.stack([uL[ids], uR[ids], v[ids]], axis=1)
    if pixel_sigma > 0:
        rng = rng or np.random.default_rng(0)
        uv = uv + rng.normal(0.0, pixel_sigma, uv.shape)
    return StereoObs(ids.astype(np.int64), uv)
