"""Kinematics shared by the generator's motion, IMU and fusion: gravity in the z-up world, and the
gyro integrated with the midpoint rule."""

from __future__ import annotations

import numpy as np

from eurocslam.geometry import F64
from eurocslam.synth.spline import so3_exp_batch
from eurocslam.timebase import ns_to_s

GRAVITY = np.array([0.0, 0.0, -9.81])


def midpoint_rates(gyro: F64, bg: F64) -> F64:
    """The bias-corrected angular rate over each IMU interval (midpoint rule), (N-1, 3); bg is
    per sample (N, 3) or constant (3,)."""
    bg = np.broadcast_to(bg, gyro.shape)
    return 0.5 * (gyro[1:] + gyro[:-1]) - 0.5 * (bg[1:] + bg[:-1])


def integrate_gyro(t_ns: np.ndarray, gyro: F64, bg: F64) -> F64:
    """The gyro (minus bias bg, (N, 3) or (3,)) integrated with the midpoint rule from the
    identity at t_ns[0]: R(t_k) (N, 3, 3), body at t_k into body at t_0, re-orthonormalised."""
    h = ns_to_s(np.diff(t_ns).astype(np.float64))
    steps = so3_exp_batch(midpoint_rates(gyro, bg) * h[:, None])
    P = np.empty((t_ns.size, 3, 3))
    P[0] = np.eye(3)
    for i in range(h.size):
        P[i + 1] = P[i] @ steps[i]
    u, _, vt = np.linalg.svd(P)
    R: F64 = u @ vt
    return R
