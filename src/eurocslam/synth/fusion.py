"""A replica trajectory from a real IMU and its ground truth, consistent with both.

A real-IMU replica ships the real IMU rows, so its images must follow the motion that IMU
measured. A spline through the ground truth alone does not: on V1_01 (20 Hz ground truth) the
real gyro integrated over 0.05 s differs from it by a median 0.06 deg (a simulated IMU: 0.003)
because the ground truth cannot resolve the fast motion, over 1-20 s by a bounded 0.15-0.35 deg
(the ground truth's orientation error: the accelerometer, with a constant bias, sides with the
gyro's tilt), and its world frame is 0.2 deg off the accelerometer's gravity.

Here the IMU gives the motion at high frequency and the ground truth at low frequency, as a
complementary filter written as two banded least-squares smoothers on the IMU's own time grid:

* rotation: the bias-corrected gyro integrated (midpoint rule) to R_gyro(t), corrected by a
  world-frame rotation vector y(t), R = exp(y) R_gyro. y follows the ground truth's orientation
  (cost sum |y(t_i) - log(R_gt,i R_gyro(t_i)^T)|^2) and changes slowly (a random walk: cost
  sum h_k (dy/dt)^2 tau_rot^2 / dt_gt), so the gyro holds below the crossover time tau_rot.
* position: p follows the ground truth positions and has the acceleration R (f - b_a) + g that
  the accelerometer gives (cost sum h_k |p'' - a_k|^2 tau_pos^4 / dt_gt).
* gravity: the accelerometer's own, a constant world acceleration solved with the positions
  (a bordered banded system); the world is then rotated (about the origin) so it points along
  -z, as in every replica (any input tilt, a world upside down included).

Gravity's magnitude is left as the accelerometer has it (returned as `FusedPoses.gravity`, not
used): 9.8068 m/s^2 on V1_01 with the ground truth's mean accel bias taken off. The positions'
acceleration is R (f - b_a) + g with that g, so against the 9.81 m/s^2 that the simulated IMU,
`consistency.py` and the estimator (`imu.gravity`) take, the real accelerometer reads 3 mm/s^2
off along world z: a near-constant offset while the attitude stays near level, which an
estimator's accel bias absorbs, and small beside the bias wander below. Scaling the positions
to 9.81 would change the motion the Vicon measured, so it is not done.

The crossovers: `TAU_ROT_S` = 10 s (the gyro over the ground truth's orientation, which wanders
0.2-0.3 deg; the result stays 0.25 deg RMS from it on V1_01) and `TAU_POS_S` = 0.3 s (Vicon
positions are good to a millimetre: the result stays 1.5 mm RMS from them; a longer crossover
buys little, 1 s: 11 mm for 15 % less accelerometer mismatch). What remains between the real
accelerometer and the trajectory is a bias that wanders 4-5x faster than imu0/sensor.yaml's
random walk (its 0.5 s low-pass changes by 25 mm/s^2 RMS over 1 s and 43 over 5 s; a simulated
IMU: 4.6 and 11), which no motion within centimetres of the Vicon positions removes (making the
accelerometer consistent too would take the motion 0.13 m off them at a 3 s crossover, 1.8 m at
10 s): the real IMU's own error, kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_banded

from eurocslam.errors import DatasetError
from eurocslam.geometry import F64, rotation_between
from eurocslam.synth.kinematics import integrate_gyro, midpoint_rates
from eurocslam.synth.spline import so3_exp_batch, so3_log_batch
from eurocslam.timebase import NS_PER_S, ns_to_s

TAU_ROT_S = 10.0
TAU_POS_S = 0.3
MAX_GT_GAP_S = 0.5  # longest ground-truth gap the fusion bridges with the IMU alone


@dataclass(frozen=True)
class FusedPoses:
    """Poses at the IMU stamps, in a gravity-aligned world (z up).

    `world_R` rotates the input ground truth's world into this one (p_new = world_R p_in);
    `gravity` is the accelerometer's gravity magnitude; `rot_dev_deg`/`pos_dev_m` are the RMS
    distances to the (rotated) input poses."""

    t_ns: np.ndarray
    R: F64  # (N, 3, 3) R_world_body
    p: F64  # (N, 3)
    world_R: F64
    gravity: float
    rot_dev_deg: float
    pos_dev_m: float


def _locate(t_ns: np.ndarray, at_ns: np.ndarray) -> tuple[np.ndarray, F64]:
    """Interval k (t_k <= at < t_k+1) and fraction u of each time in `at_ns`."""
    k = np.clip(np.searchsorted(t_ns, at_ns, side="right") - 1, 0, t_ns.size - 2)
    u = (at_ns - t_ns[k]).astype(np.float64) / (t_ns[k + 1] - t_ns[k]).astype(np.float64)
    return k, np.clip(u, 0.0, 1.0)


def _add_band(ab: F64, nb: int, rows: np.ndarray, cols: np.ndarray, vals: F64) -> None:
    """Add vals at the (rows, cols) entries of a banded matrix in solve_banded's layout
    (upper = lower = nb); only those entries: the caller adds both (i, j) and (j, i)."""
    np.add.at(ab, (nb + rows - cols, cols), vals)


def _smooth(
    n: int,
    k: np.ndarray,
    u: F64,
    target: F64,
    coef: F64,
    offs: np.ndarray,
    rhs_rows: F64,
    weight: F64,
    *,
    free_offset: bool = False,
) -> tuple[F64, F64]:
    """argmin_x,c sum_i |(1-u_i) x_k_i + u_i x_k_i+1 - target_i|^2
    + sum_r weight_r |sum_j coef_rj x_{offs_r + j} - rhs_rows_r - c|^2,
    per column, banded; c (one per column) is 0 unless `free_offset`. Returns (x, c)."""
    nb = coef.shape[1] - 1
    ab = np.zeros((2 * nb + 1, n))
    rhs = np.zeros((n, target.shape[1]))
    # data terms (interpolation between two neighbouring samples)
    wts = (1.0 - u, u)
    for a in range(2):
        np.add.at(rhs, k + a, wts[a][:, None] * target)
        for b in range(2):
            _add_band(ab, nb, k + a, k + b, wts[a] * wts[b])
    # smoothness rows
    dw1 = np.zeros(n)  # D^T W 1
    for a in range(coef.shape[1]):
        np.add.at(rhs, offs + a, (weight * coef[:, a])[:, None] * rhs_rows)
        np.add.at(dw1, offs + a, weight * coef[:, a])
        for b in range(coef.shape[1]):
            _add_band(ab, nb, offs + a, offs + b, weight * coef[:, a] * coef[:, b])
    if not free_offset:
        return solve_banded((nb, nb), ab, rhs), np.zeros(target.shape[1])
    # bordered system [[A, -D^T W 1], [-1^T W D, sum W]] [x; c] = [rhs; -1^T W rhs_rows]
    sol = solve_banded((nb, nb), ab, np.column_stack([rhs, dw1]))
    x0, z = sol[:, :-1], sol[:, -1]  # A^-1 rhs, A^-1 D^T W 1
    r2 = -(weight[:, None] * rhs_rows).sum(axis=0)
    c = (r2 + dw1 @ x0) / (weight.sum() - dw1 @ z)
    return x0 + z[:, None] * c[None, :], c


def _check_inputs(
    t_ns: np.ndarray,
    gyro: F64,
    accel: F64,
    bg: F64,
    ba: F64,
    gt_t_ns: np.ndarray,
    gt_R: F64,
    gt_p: F64,
) -> None:
    """Shapes, strictly increasing stamps, finite values."""
    n, m = t_ns.shape[0], gt_t_ns.shape[0]
    for name, a, shape in (
        ("IMU gyro", gyro, (n, 3)),
        ("IMU accel", accel, (n, 3)),
        ("gyro bias", bg, (n, 3)),
        ("accel bias", ba, (n, 3)),
        ("ground-truth orientation", gt_R, (m, 3, 3)),
        ("ground-truth position", gt_p, (m, 3)),
    ):
        if np.shape(a) != shape:
            raise DatasetError(f"{name}: shape {np.shape(a)}, expected {shape}")
        bad = ~np.isfinite(a).reshape(shape[0], -1).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DatasetError(f"{name}: not finite at row {i} (of {shape[0]})")
    for name, t in (("IMU", t_ns), ("ground-truth", gt_t_ns)):
        step = np.diff(t)
        if np.any(step <= 0):
            i = int(np.flatnonzero(step <= 0)[0]) + 1
            raise DatasetError(f"{name} timestamps must strictly increase (row {i}: {t[i]} ns)")


def _check_coverage(t_ns: np.ndarray, gt_t_ns: np.ndarray, gt_first: int) -> None:
    """The ground-truth poses within the IMU's span (at least 2) cover it: no gap longer than
    MAX_GT_GAP_S, no IMU rows more than one (median) ground-truth interval beyond them."""
    step = np.diff(gt_t_ns)
    if np.any(step > MAX_GT_GAP_S * NS_PER_S):
        i = int(np.flatnonzero(step > MAX_GT_GAP_S * NS_PER_S)[0])
        raise DatasetError(
            f"gap of {ns_to_s(step[i]):.2f} s in the ground truth at "
            f"{ns_to_s(gt_t_ns[i] - gt_first):.2f} s after its first pose, within the IMU rows "
            f"(the fusion bridges at most {MAX_GT_GAP_S:g} s)"
        )
    interval = float(np.median(step))
    lead, trail = int(gt_t_ns[0] - t_ns[0]), int(t_ns[-1] - gt_t_ns[-1])
    if max(lead, trail) > interval:
        side, by = ("before", lead) if lead >= trail else ("after", trail)
        raise DatasetError(
            f"the IMU rows run {ns_to_s(by):.3f} s {side} the ground truth's poses (more than "
            f"one ground-truth interval, {ns_to_s(interval):.3f} s): crop them to its span"
        )


def fuse_imu_groundtruth(
    t_ns: np.ndarray,
    gyro: F64,
    accel: F64,
    bg: F64,
    ba: F64,
    gt_t_ns: np.ndarray,
    gt_R: F64,
    gt_p: F64,
    *,
    tau_rot_s: float = TAU_ROT_S,
    tau_pos_s: float = TAU_POS_S,
) -> FusedPoses:
    """Poses at the IMU stamps `t_ns` that the IMU (minus biases bg, ba, per sample) measures
    at high frequency and the ground truth (gt_t_ns, gt_R, gt_p) gives at low frequency.

    The IMU rows must lie within the ground truth's span (give or take one ground-truth
    interval: the caller crops them), with no ground-truth gap over `MAX_GT_GAP_S` between
    them. Raises DatasetError (messages name no file: the caller adds it) on inputs that break
    this, on stamps that do not strictly increase and on values that are not finite."""
    _check_inputs(t_ns, gyro, accel, bg, ba, gt_t_ns, gt_R, gt_p)
    n = t_ns.size
    inside = (gt_t_ns >= t_ns[0]) & (gt_t_ns <= t_ns[-1])
    if n < 3 or int(inside.sum()) < 2:
        raise DatasetError("the IMU rows and the ground truth barely overlap in time")
    gt_first = int(gt_t_ns[0])
    gt_t_ns, gt_R, gt_p = gt_t_ns[inside], gt_R[inside], gt_p[inside]
    _check_coverage(t_ns, gt_t_ns, gt_first)
    h = ns_to_s(np.diff(t_ns).astype(np.float64))
    dt_gt = ns_to_s(float(np.median(np.diff(gt_t_ns))))
    k, u = _locate(t_ns, gt_t_ns)

    # ---- rotation ----------------------------------------------------------------------------
    w = midpoint_rates(gyro, bg)
    Rg = integrate_gyro(t_ns, gyro, bg)
    Rg_at = Rg[k] @ so3_exp_batch(w[k] * (u * h[k])[:, None])  # at the ground-truth stamps
    # start where the ground truth starts, then the (small) world-frame corrections
    Rg = (gt_R[0] @ Rg_at[0].T) @ Rg
    Rg_at = (gt_R[0] @ Rg_at[0].T) @ Rg_at
    d = so3_log_batch(gt_R @ np.swapaxes(Rg_at, 1, 2))
    if not float(np.max(np.linalg.norm(d, axis=1))) <= np.radians(20.0):
        raise DatasetError(
            "the real gyro (minus the ground truth's bias) drifts more than 20 deg from the "
            "ground truth: wrong IMU file, or a ground truth without gyro bias columns"
        )
    wr = h * tau_rot_s**2 / dt_gt
    coef = np.stack([-1.0 / h, 1.0 / h], axis=1)
    y, _ = _smooth(n, k, u, d, coef, np.arange(n - 1), np.zeros((n - 1, 3)), wr)
    R = so3_exp_batch(y) @ Rg

    # ---- position ----------------------------------------------------------------------------
    f_world = np.einsum("nij,nj->ni", R, accel - ba)
    h1, h2 = h[:-1], h[1:]
    coef2 = np.stack([2.0 / (h1 * (h1 + h2)), -2.0 / (h1 * h2), 2.0 / (h2 * (h1 + h2))], axis=1)
    wp = 0.5 * (h1 + h2) * tau_pos_s**4 / dt_gt
    # gravity: the constant world acceleration that makes the accelerometer fit best
    p, g = _smooth(n, k, u, gt_p, coef2, np.arange(n - 2), f_world[1:-1], wp, free_offset=True)

    # ---- gravity-aligned world -----------------------------------------------------------------
    Q = rotation_between(g, np.array([0.0, 0.0, -1.0]))
    uq, _, vq = np.linalg.svd(Q)  # its closed form loses orthogonality near 180 deg
    Q = uq @ vq
    y_at = y[k] * (1.0 - u)[:, None] + y[k + 1] * u[:, None]
    rot_dev = np.linalg.norm(
        so3_log_batch(gt_R @ np.swapaxes(so3_exp_batch(y_at) @ Rg_at, 1, 2)), axis=1
    )
    p_at = p[k] * (1.0 - u)[:, None] + p[k + 1] * u[:, None]
    pos_dev = np.linalg.norm(p_at - gt_p, axis=1)
    return FusedPoses(
        t_ns=t_ns,
        R=Q @ R,
        p=p @ Q.T,
        world_R=Q,
        gravity=float(np.linalg.norm(g)),
        rot_dev_deg=float(np.degrees(np.sqrt(np.mean(rot_dev**2)))),
        pos_dev_m=float(np.sqrt(np.mean(pos_dev**2))),
    )
