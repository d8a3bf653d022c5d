"""Smooth synthetic trajectories with known truth, for tests and benchmarks of the evaluator.

`smooth_trajectory` draws a flight-like path (sums of sinusoids in x, y, z, yaw following the
velocity, small roll/pitch) at a given rate. `straight_road` is a car on a straight road (the
case where a fit of positions leaves the rotation about the road free). `perturb` makes an
"estimate" from either: a known similarity transform, a random-walk drift and white noise,
optionally subsampled.
"""

from __future__ import annotations

import numpy as np

from eurocslam.geometry import F64, make_T, so3_exp
from eurocslam.timebase import NS_PER_S
from eurocslam.trajectory import Trajectory

T0_NS = 1_403_636_580_838_555_648  # an EuRoC-like epoch


def _rz(a: F64) -> F64:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((a.size, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def _rx(a: F64) -> F64:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((a.size, 3, 3))
    R[:, 0, 0], R[:, 1, 1], R[:, 1, 2], R[:, 2, 1], R[:, 2, 2] = 1.0, c, -s, s, c
    return R


def _ry(a: F64) -> F64:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((a.size, 3, 3))
    R[:, 0, 0], R[:, 0, 2], R[:, 1, 1], R[:, 2, 0], R[:, 2, 2] = c, s, 1.0, -s, c
    return R


def smooth_trajectory(
    n: int, rate_hz: float = 200.0, seed: int = 0, t0_ns: int = T0_NS, name: str = "synthetic"
) -> Trajectory:
    """`n` poses at `rate_hz` of a smooth 3-D flight (metres, a few m/s)."""
    rng = np.random.default_rng(seed)
    dt_ns = round(NS_PER_S / rate_hz)
    t_ns = t0_ns + np.arange(n, dtype=np.int64) * dt_ns
    t = (t_ns - t0_ns) / NS_PER_S
    p = np.zeros((n, 3))
    for k, amp in enumerate((3.0, 3.0, 0.6)):
        for _ in range(3):
            f = rng.uniform(0.02, 0.15)
            p[:, k] += amp / 3 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
        p[:, k] += rng.uniform(-0.02, 0.02) * t  # slow net motion
    v = np.asarray(np.gradient(p, t, axis=0)) if n > 1 else np.zeros((n, 3))
    yaw = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    roll = 0.1 * np.sin(2 * np.pi * 0.3 * t + rng.uniform(0, 6))
    pitch = 0.1 * np.sin(2 * np.pi * 0.2 * t + rng.uniform(0, 6))
    R = _rz(yaw) @ _ry(pitch) @ _rx(roll)
    return Trajectory.from_poses(t_ns, make_T(R, p), name=name)


def straight_road(
    length_m: float,
    wiggle_m: float,
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0),
    n: int = 601,
    rate_hz: float = 10.0,
    t0_ns: int = T0_NS,
) -> Trajectory:
    """A car on a straight road: `n` poses at `rate_hz` over `length_m` along `direction`, with
    `wiggle_m` of lateral (and half of it vertical) wiggle (0: exactly collinear positions),
    heading along the road with a little roll and pitch."""
    t = t0_ns + np.arange(n, dtype=np.int64) * round(NS_PER_S / rate_hz)
    e0 = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    e1 = np.cross([0.0, 0.0, 1.0], e0) if abs(e0[2]) < 0.9 else np.cross([1.0, 0.0, 0.0], e0)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e0, e1)
    a = np.linspace(0.0, 1.0, n)
    p = (
        np.outer(length_m * a, e0)
        + np.outer(wiggle_m * np.sin(6 * np.pi * a), e1)
        + np.outer(0.5 * wiggle_m * np.cos(4 * np.pi * a), e2)
        + np.array([3.0, -2.0, 0.5])
    )
    heading = np.stack([e0, e1, e2], axis=1)  # body x along the road
    roll, pitch = 0.02 * np.sin(9 * a), 0.01 * np.cos(7 * a)
    R = heading @ _ry(pitch) @ _rx(roll)
    return Trajectory.from_poses(t, make_T(R, p), name="road")


def random_similarity(seed: int, scale: float = 1.0) -> F64:
    """A random 4x4 similarity (rotation, translation of a few metres, scale)."""
    rng = np.random.default_rng(seed)
    w = rng.normal(size=3)
    R = so3_exp(w / np.linalg.norm(w) * rng.uniform(0.3, 3.0))
    M = np.eye(4)
    M[:3, :3] = scale * R
    M[:3, 3] = rng.uniform(-5, 5, size=3)
    return M


def perturb(
    gt: Trajectory,
    M_est_gt: F64 | None = None,
    step: int = 1,
    noise_m: float = 0.0,
    noise_rad: float = 0.0,
    drift_m: float = 0.0,
    seed: int = 1,
    jitter_ns: int = 0,
    name: str = "estimate",
) -> Trajectory:
    """An estimate in another frame: `p_est = M (p_gt + walk + noise)`, orientations rotated by
    M's rotation and perturbed; every `step`-th pose; stamps jittered by up to `jitter_ns`."""
    rng = np.random.default_rng(seed)
    sub = gt.take(np.arange(0, len(gt), step))
    n = len(sub)
    p = sub.p.copy()
    if drift_m:
        p += np.cumsum(rng.normal(scale=drift_m, size=(n, 3)), axis=0)
    if noise_m:
        p += rng.normal(scale=noise_m, size=(n, 3))
    R = sub.rotations()
    if noise_rad:
        dR = np.stack([so3_exp(w) for w in rng.normal(scale=noise_rad, size=(n, 3))])
        R = R @ dR
    M = np.eye(4) if M_est_gt is None else np.asarray(M_est_gt, dtype=np.float64)
    s = float(np.cbrt(np.linalg.det(M[:3, :3])))
    Rm = M[:3, :3] / s
    p = s * p @ Rm.T + M[:3, 3]
    R = np.einsum("ij,njk->nik", Rm, R)
    t = sub.t_ns.copy()
    if jitter_ns:
        t = t + rng.integers(-jitter_ns, jitter_ns + 1, size=n)
        t = np.maximum.accumulate(t)
    return Trajectory.from_poses(t, make_T(R, p), name=name)
