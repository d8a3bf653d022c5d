"""Uniform cubic B-spline trajectory on R^3 x SO(3) with analytic derivatives.

Positions are a uniform cubic B-spline (C2: continuous acceleration). Rotations are a *cumulative*
cubic B-spline on SO(3) (Kim et al. 1995; Sommer et al. 2020): for segment i and u in [0, 1),

    R(u) = C_i exp(B1(u) W1) exp(B2(u) W2) exp(B3(u) W3),   Wj = log(C_{i+j-1}^T C_{i+j}),

with the cumulative basis B1..B3. Its body-frame angular velocity follows from the product rule
(`w1 = dB1 W1; wj = Aj^T w_{j-1} + dBj Wj`, Aj = exp(Bj Wj)), so the gyro a simulated IMU reports
is the exact derivative of the rotation the renderer uses and the IMU integrates back to the
trajectory. Knots are uniform: control point k sits at time `t0 + (k - 1) dt`; the spline is
defined on [t0, t0 + (M - 3) dt] for M control points.

`fit_spline` turns sampled poses (ground truth at 200 Hz with Vicon/Leica noise, or the built-in
motion) into a spline: resample to a uniform grid, optional Gaussian low-pass (so accelerations
are not differentiated noise), then control points that make the spline pass through the
smoothed poses at the knots (a banded solve for positions, a fixed-point iteration for
rotations).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.linalg import solve_banded
from scipy.ndimage import gaussian_filter1d

from eurocslam.geometry import F64, quat_wxyz_to_rot, rot_to_quat_wxyz


def so3_exp_batch(w: F64) -> F64:
    """Rotation matrices (N, 3, 3) from rotation vectors (N, 3) (Rodrigues, vectorised)."""
    w = np.asarray(w, dtype=np.float64)
    th = np.linalg.norm(w, axis=-1)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    K = np.zeros((*w.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2] = -w[..., 2], w[..., 1]
    K[..., 1, 0], K[..., 1, 2] = w[..., 2], -w[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -w[..., 1], w[..., 0]
    return cast(F64, np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K))


def so3_log_batch(R: F64) -> F64:
    """Rotation vectors (N, 3) from rotation matrices (N, 3, 3), robust near 0 and pi."""
    q = rot_to_quat_wxyz(R)  # w >= 0
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    ang = 2.0 * np.arctan2(s, q[..., 0])
    scale = np.where(s < 1e-12, 2.0, ang / np.where(s < 1e-12, 1.0, s))
    return v * scale[..., None]


def _basis(u: F64) -> tuple[F64, F64, F64]:
    """Cubic B-spline basis (N, 4) and its first and second derivatives in u."""
    u2, u3 = u * u, u * u * u
    b = np.stack([(1 - u) ** 3, 3 * u3 - 6 * u2 + 4, -3 * u3 + 3 * u2 + 3 * u + 1, u3], -1) / 6.0
    db = np.stack([-0.5 * (1 - u) ** 2, 1.5 * u2 - 2 * u, -1.5 * u2 + u + 0.5, 0.5 * u2], -1)
    ddb = np.stack([1 - u, 3 * u - 2, -3 * u + 1, u], -1)
    return b, db, ddb


@dataclass(frozen=True)
class PoseSamples:
    """Trajectory state at times t [s]: world-frame position/velocity/acceleration, R_world_body,
    body-frame angular velocity."""

    t: F64
    p: F64  # (N, 3)
    v: F64  # (N, 3)
    a: F64  # (N, 3)
    R: F64  # (N, 3, 3) R_world_body
    w_body: F64  # (N, 3) rad/s


@dataclass(frozen=True)
class SplineTrajectory:
    """Uniform cubic B-spline on R^3 x SO(3); times in seconds relative to the sequence t0."""

    t0: float
    dt: float
    ctrl_p: F64  # (M, 3)
    ctrl_R: F64  # (M, 3, 3)

    @property
    def t_end(self) -> float:
        return float(self.t0 + (self.ctrl_p.shape[0] - 3) * self.dt)

    def _segments(self, t: F64) -> tuple[np.ndarray, F64]:
        s = (np.asarray(t, dtype=np.float64) - self.t0) / self.dt
        i = np.clip(np.floor(s).astype(np.int64), 0, self.ctrl_p.shape[0] - 4)
        return i, s - i

    def positions(self, t: F64) -> F64:
        i, u = self._segments(t)
        b, _, _ = _basis(u)
        idx = i[:, None] + np.arange(4)
        return cast(F64, np.einsum("nk,nkd->nd", b, self.ctrl_p[idx]))

    def evaluate(self, t: F64) -> PoseSamples:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        i, u = self._segments(t)
        b, db, ddb = _basis(u)
        idx = i[:, None] + np.arange(4)
        P = self.ctrl_p[idx]  # (N, 4, 3)
        p = np.einsum("nk,nkd->nd", b, P)
        v = np.einsum("nk,nkd->nd", db, P) / self.dt
        a = np.einsum("nk,nkd->nd", ddb, P) / self.dt**2
        # cumulative basis for the rotation part
        cb = np.cumsum(b[:, ::-1], axis=1)[:, ::-1]  # cb[:, j] = sum_{k>=j} b_k
        cdb = np.cumsum(db[:, ::-1], axis=1)[:, ::-1]
        C = self.ctrl_R[idx]  # (N, 4, 3, 3)
        R = C[:, 0].copy()
        w = np.zeros((t.shape[0], 3))
        for j in (1, 2, 3):
            Wj = so3_log_batch(np.swapaxes(C[:, j - 1], -1, -2) @ C[:, j])
            Aj = so3_exp_batch(cb[:, j, None] * Wj)
            R = R @ Aj
            w = np.einsum("nji,nj->ni", Aj, w) + cdb[:, j, None] * Wj
        return PoseSamples(t, p, v, a, R, w / self.dt)

    def rotations(self, t: F64) -> F64:
        return self.evaluate(t).R


def _resample(t: F64, p: F64, q_wxyz: F64, grid: F64) -> tuple[F64, F64]:
    """Linear (positions) and normalised-linear (quaternions) interpolation onto `grid`."""
    q = q_wxyz.copy()
    # sign continuity so that interpolation and smoothing take the short way
    flips = np.cumsum(np.r_[0, (np.einsum("ij,ij->i", q[1:], q[:-1]) < 0).astype(np.int64)]) % 2
    q[flips == 1] *= -1
    pg = np.stack([np.interp(grid, t, p[:, k]) for k in range(3)], -1)
    qg = np.stack([np.interp(grid, t, q[:, k]) for k in range(4)], -1)
    return pg, qg / np.linalg.norm(qg, axis=1, keepdims=True)


def fit_spline(
    t: F64,
    p: F64,
    q_wxyz: F64,
    *,
    knot_dt: float,
    smooth_sigma_s: float = 0.0,
    grid_dt: float = 0.005,
    iterations: int = 60,
) -> SplineTrajectory:
    """Fit a spline to sampled poses (t [s] increasing, p (N, 3), q (N, 4) wxyz).

    The spline starts at t[0] and ends at or before t[-1] (a whole number of knots). With
    `smooth_sigma_s` > 0 the poses are low-passed by a Gaussian of that width first.
    """
    t = np.asarray(t, dtype=np.float64)
    span = float(t[-1] - t[0])
    nseg = int(np.floor(span / knot_dt + 1e-9))
    if nseg < 1:
        raise ValueError(f"trajectory span {span:.3f} s is shorter than one knot ({knot_dt} s)")
    grid = t[0] + np.arange(int(np.floor(span / grid_dt + 1e-9)) + 1) * grid_dt
    pg, qg = _resample(t, p, q_wxyz, grid)
    if smooth_sigma_s > 0:
        sig = smooth_sigma_s / grid_dt
        pg = gaussian_filter1d(pg, sig, axis=0, mode="nearest")
        qg = gaussian_filter1d(qg, sig, axis=0, mode="nearest")
        qg /= np.linalg.norm(qg, axis=1, keepdims=True)
    knots = t[0] + np.arange(nseg + 1) * knot_dt  # interior knots 1..M-2
    tp, tq = _resample(grid, pg, qg, knots)
    R_target = quat_wxyz_to_rot(tq)
    M = nseg + 3
    # positions: interior rows interpolate (1 4 1)/6, end rows have zero second difference
    ab = np.zeros((5, M))  # banded (2, 2): ab[2 + i - j, j] = A[i, j]
    ab[2, 1 : M - 1] = 4.0 / 6.0
    ab[1, 2:M] = 1.0 / 6.0  # A[i, i+1]
    ab[3, 0 : M - 2] = 1.0 / 6.0  # A[i, i-1]
    # row 0: C0 - 2 C1 + C2 = 0 ; row M-1: C_{M-3} - 2 C_{M-2} + C_{M-1} = 0
    ab[2, 0], ab[1, 1], ab[0, 2] = 1.0, -2.0, 1.0
    ab[2, M - 1], ab[3, M - 2], ab[4, M - 3] = 1.0, -2.0, 1.0
    rhs = np.zeros((M, 3))
    rhs[1 : M - 1] = tp
    ctrl_p = solve_banded((2, 2), ab, rhs)
    # rotations: fixed-point iteration C_k <- C_k exp(log(R(tau_k)^T T_k))
    C = np.empty((M, 3, 3))
    C[1 : M - 1] = R_target
    traj = SplineTrajectory(float(t[0]), knot_dt, ctrl_p, C)
    for _ in range(iterations):
        C[0] = C[1] @ C[2].T @ C[1]
        C[M - 1] = C[M - 2] @ C[M - 3].T @ C[M - 2]
        R_now = traj.rotations(knots)
        corr = so3_log_batch(np.swapaxes(R_now, -1, -2) @ R_target)
        C[1 : M - 1] = C[1 : M - 1] @ so3_exp_batch(corr)
        if float(np.max(np.abs(corr))) < 1e-12:
            break
    C[0] = C[1] @ C[2].T @ C[1]
    C[M - 1] = C[M - 2] @ C[M - 3].T @ C[M - 2]
    # re-orthonormalise (accumulated products)
    u, _, vt = np.linalg.svd(C)
    C = u @ vt
    return SplineTrajectory(float(t[0]), knot_dt, ctrl_p, C)
