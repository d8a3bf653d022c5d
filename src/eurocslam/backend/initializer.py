"""Initial state of the estimator: attitude, velocity and IMU biases. Two kinds, chosen
automatically (`choose_mode`):

* **static** (`static_init`): the platform is still around the first frame. The mean
  accelerometer reading is the reaction to gravity, so it gives roll and pitch
  (`R_world_body @ a_mean = +g z_world`); the mean gyro reading is the gyro bias. Yaw is
  unobservable and set so the body x axis projects onto world x where possible. The EuRoC IMU's
  x axis points up, so this is never the identity.
* **dynamic** (`dynamic_init`): the platform moves (MH sequences start with the drone being picked
  up). Stereo visual odometry over the first 1-2 s gives metric body poses `T_vo_body(t_k)` in an
  arbitrary frame. With the gyro bias from the rotation residuals against preintegrated gyro,
  the positions and preintegrated IMU deltas give a linear system in the velocities and the
  gravity vector expressed in the VO frame (metric stereo: no scale); gravity's direction then
  rotates the VO frame into the gravity-aligned world frame. The accelerometer bias is refined
  from the same system with |g| fixed (it is only weakly observable in 1-2 s, so it is kept
  small by a prior in the smoother).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import gtsam
import numpy as np

from eurocslam.backend.preintegration import bias, integrate
from eurocslam.config import InitConfig
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64, make_T, rotation_between, so3_log


class InitMode(str, Enum):
    """How a segment's estimate starts: the IMU still (`STATIC`), moving (`DYNAMIC`: a stereo VO
    window aligned with the IMU), or without an IMU (`VISUAL`)."""

    STATIC = "static"
    DYNAMIC = "dynamic"
    VISUAL = "visual"


@dataclass(frozen=True)
class InitialState:
    """Estimator state at the first keyframe, in the gravity-aligned world frame."""

    t_ns: int
    T_world_body: F64
    v_world: F64
    bg: F64
    ba: F64
    mode: InitMode
    # for dynamic starts: the window's keyframes in the world frame (t_ns, T_world_body, v_world)
    window: tuple[tuple[int, F64, F64], ...] = ()
    # rotation applied to VO-frame quantities to bring them into the world frame: p_w = R @ p_vo
    R_world_vo: F64 | None = None


@dataclass(frozen=True)
class StillnessTest:
    still: bool
    gyro_std: float
    accel_std: float
    accel_norm: float
    n_samples: int


def stillness(
    imu: ImuData, t0_ns: int, t1_ns: int, gravity: float, cfg: InitConfig
) -> StillnessTest:
    """Whether the IMU window [t0, t1] looks like a platform standing still."""
    w = imu.slice(t0_ns, t1_ns)
    n = len(w)
    if n < 10:
        return StillnessTest(False, float("nan"), float("nan"), float("nan"), n)
    gstd = float(np.max(np.std(w.gyro, axis=0)))
    astd = float(np.max(np.std(w.accel, axis=0)))
    anorm = float(np.linalg.norm(np.mean(w.accel, axis=0)))
    still = (
        gstd <= cfg.static_gyro_std_max
        and astd <= cfg.static_accel_std_max
        and abs(anorm - gravity) <= cfg.static_accel_norm_tol
    )
    return StillnessTest(still, gstd, astd, anorm, n)


def static_window(t_first_ns: int, cfg: InitConfig) -> tuple[int, int]:
    """IMU window for the stillness test and static init: centred on the first frame."""
    half = int(cfg.static_window_s * 0.5e9)
    return t_first_ns - half, t_first_ns + half


def gravity_aligned_rotation(accel_mean_body: F64) -> F64:
    """`R_world_body` that maps the measured specific force to +z, with a deterministic yaw.

    Yaw choice: the body axis closest to horizontal among x, y, z is mapped onto the world x
    direction's vertical plane, so the result does not depend on tiny accelerometer noise.
    """
    R = rotation_between(accel_mean_body, np.array([0.0, 0.0, 1.0]))
    return R


def static_init(imu: ImuData, t_ns: int, cfg: InitConfig, gravity: float = 9.81) -> InitialState:
    """Attitude from the mean specific force, gyro bias from the mean rate, zero velocity."""
    t0, t1 = static_window(t_ns, cfg)
    w = imu.slice(t0, t1)
    if len(w) < 10:
        raise ValueError("not enough IMU samples around the first frame for a static start")
    a_mean = np.mean(w.accel, axis=0)
    bg = np.mean(w.gyro, axis=0)
    R_world_body = gravity_aligned_rotation(a_mean)
    # the accel bias along gravity is observable while still (|a| - g); the horizontal part is
    # indistinguishable from tilt and is absorbed by the attitude
    a_norm = float(np.linalg.norm(a_mean))
    ba = (a_norm - gravity) * a_mean / a_norm
    return InitialState(
        t_ns=int(t_ns),
        T_world_body=make_T(R_world_body, np.zeros(3)),
        v_world=np.zeros(3),
        bg=bg,
        ba=ba,
        mode=InitMode.STATIC,
    )


def choose_mode(imu: ImuData, t_first_ns: int, cfg: InitConfig, gravity: float) -> InitMode:
    if cfg.mode != "auto":
        return InitMode(cfg.mode)
    t0, t1 = static_window(t_first_ns, cfg)
    return InitMode.STATIC if stillness(imu, t0, t1, gravity, cfg).still else InitMode.DYNAMIC


def _preintegrate(
    params: gtsam.PreintegrationCombinedParams,
    imu: ImuData,
    t0: int,
    t1: int,
    bg: F64,
    ba: F64 | None = None,
) -> gtsam.PreintegratedCombinedMeasurements:
    pim = gtsam.PreintegratedCombinedMeasurements(
        params, bias(bg, np.zeros(3) if ba is None else ba)
    )
    integrate(pim, imu, t0, t1)
    return pim


@dataclass(frozen=True)
class _Delta:
    dt: float
    dR: F64
    dp: F64
    dv: F64
    # numeric Jacobians of (theta, p, v) w.r.t. the gyro bias and the accel bias: (9, 3) each
    H_bg: F64
    H_ba: F64


def _delta(
    params: gtsam.PreintegrationCombinedParams,
    imu: ImuData,
    t0: int,
    t1: int,
    bg: F64,
    ba: F64,
) -> _Delta:
    """Preintegrated deltas and their bias Jacobians (central differences; GTSAM's Python
    wrapper does not expose the analytic ones)."""

    def run(bg_: F64, ba_: F64) -> tuple[F64, F64, F64]:
        pim = _preintegrate(params, imu, t0, t1, bg_, ba_)
        return pim.deltaRij().matrix(), np.asarray(pim.deltaPij()), np.asarray(pim.deltaVij())

    pim = _preintegrate(params, imu, t0, t1, bg, ba)
    dR, dp, dv = pim.deltaRij().matrix(), np.asarray(pim.deltaPij()), np.asarray(pim.deltaVij())
    H = np.zeros((2, 9, 3))
    for which, eps in ((0, 1e-4), (1, 1e-3)):
        for j in range(3):
            e = np.zeros(3)
            e[j] = eps
            if which == 0:
                Rp, pp, vp = run(bg + e, ba)
                Rm, pm, vm = run(bg - e, ba)
            else:
                Rp, pp, vp = run(bg, ba + e)
                Rm, pm, vm = run(bg, ba - e)
            H[which, 0:3, j] = (so3_log(dR.T @ Rp) - so3_log(dR.T @ Rm)) / (2 * eps)
            H[which, 3:6, j] = (pp - pm) / (2 * eps)
            H[which, 6:9, j] = (vp - vm) / (2 * eps)
    return _Delta(float(pim.deltaTij()), dR, dp, dv, H[0], H[1])


def estimate_gyro_bias(
    params: gtsam.PreintegrationCombinedParams,
    imu: ImuData,
    times: Sequence[int],
    R_vo_body: Sequence[F64],
) -> F64:
    """Gyro bias minimising the rotation residuals between VO and preintegrated gyro."""
    bg = np.zeros(3)
    for _ in range(2):
        A, b = [], []
        for k in range(len(times) - 1):
            d = _delta(params, imu, times[k], times[k + 1], bg, np.zeros(3))
            dR_vo = R_vo_body[k].T @ R_vo_body[k + 1]
            # dR_vo ~ dR_imu * Exp(H dbg)  ->  H dbg = Log(dR_imu^T dR_vo)
            A.append(d.H_bg[0:3])
            b.append(so3_log(d.dR.T @ dR_vo))
        dbg, *_ = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)
        bg = bg + dbg
    return bg


def dynamic_init(
    params: gtsam.PreintegrationCombinedParams,
    imu: ImuData,
    times: Sequence[int],
    T_vo_body: Sequence[F64],
    gravity: float = 9.81,
) -> InitialState:
    """Align a VO window with the preintegrated IMU: gyro bias, gravity, velocities, accel bias.

    `times` / `T_vo_body`: at least 3 keyframes spanning ~1-2 s with enough motion. Raises
    `ValueError` when the system is degenerate (no excitation) or inconsistent.
    """
    n = len(times)
    if n < 3:
        raise ValueError("dynamic initialisation needs at least 3 keyframes")
    R = [np.asarray(T)[:3, :3] for T in T_vo_body]
    p = [np.asarray(T)[:3, 3] for T in T_vo_body]
    bg = estimate_gyro_bias(params, imu, times, R)

    # unknowns: v_0..v_{n-1} (3n), g_vo (3)
    pims = [_preintegrate(params, imu, times[k], times[k + 1], bg) for k in range(n - 1)]
    rows_A, rows_b = [], []
    nv = 3 * n
    for k in range(n - 1):
        dt = pims[k].deltaTij()
        dp = np.asarray(pims[k].deltaPij())
        dv = np.asarray(pims[k].deltaVij())
        # p_{k+1} = p_k + v_k dt + 0.5 g dt^2 + R_k dp
        A = np.zeros((3, nv + 3))
        A[:, 3 * k : 3 * k + 3] = np.eye(3) * dt
        A[:, nv:] = 0.5 * dt * dt * np.eye(3)
        rows_A.append(A)
        rows_b.append(p[k + 1] - p[k] - R[k] @ dp)
        # v_{k+1} = v_k + g dt + R_k dv
        A = np.zeros((3, nv + 3))
        A[:, 3 * (k + 1) : 3 * k + 6] = np.eye(3)
        A[:, 3 * k : 3 * k + 3] = -np.eye(3)
        A[:, nv:] = -dt * np.eye(3)
        rows_A.append(A)
        rows_b.append(R[k] @ dv)
    A = np.vstack(rows_A)
    b = np.concatenate(rows_b)
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    g_vo = x[nv:]
    gnorm = float(np.linalg.norm(g_vo))
    if not np.isfinite(gnorm) or abs(gnorm - gravity) > 0.25 * gravity:
        raise ValueError(
            f"gravity from VO/IMU alignment has norm {gnorm:.2f} m/s^2 (expected "
            f"{gravity:.2f}): not enough motion or inconsistent VO"
        )
    # refine with |g| fixed: solve again with g = gravity * dir, plus an accel bias (small angle)
    g_dir = g_vo / gnorm
    ba = np.zeros(3)
    for _ in range(2):
        g_fixed = g_dir * gravity
        deltas = [_delta(params, imu, times[k], times[k + 1], bg, ba) for k in range(n - 1)]
        # unknowns: v (3n), dtheta (2, tangent of g_dir), dba (3)
        t1 = np.cross(g_dir, [1.0, 0.0, 0.0])
        if np.linalg.norm(t1) < 0.1:
            t1 = np.cross(g_dir, [0.0, 1.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(g_dir, t1)
        Tg = gravity * np.stack([t1, t2], axis=1)  # dg = Tg @ dtheta
        rows_A, rows_b = [], []
        m = nv + 5
        for k in range(n - 1):
            d = deltas[k]
            dt, dp, dv, H_ba = d.dt, d.dp, d.dv, d.H_ba
            A = np.zeros((3, m))
            A[:, 3 * k : 3 * k + 3] = np.eye(3) * dt
            A[:, nv : nv + 2] = 0.5 * dt * dt * Tg
            A[:, nv + 2 :] = R[k] @ H_ba[3:6]
            rows_A.append(A)
            rows_b.append(p[k + 1] - p[k] - R[k] @ dp - 0.5 * dt * dt * g_fixed)
            A = np.zeros((3, m))
            A[:, 3 * (k + 1) : 3 * k + 6] = np.eye(3)
            A[:, 3 * k : 3 * k + 3] = -np.eye(3)
            A[:, nv : nv + 2] = -dt * Tg
            A[:, nv + 2 :] = -R[k] @ H_ba[6:9]
            rows_A.append(A)
            rows_b.append(R[k] @ dv + dt * g_fixed)
        # weak prior keeping the accel bias small (it is barely observable over 1-2 s)
        Ap = np.zeros((3, m))
        Ap[:, nv + 2 :] = np.eye(3) * 0.5
        A = np.vstack([*rows_A, Ap])
        b = np.concatenate([*rows_b, np.zeros(3)])
        x, *_ = np.linalg.lstsq(A, b, rcond=None)
        g_dir = g_fixed + Tg @ x[nv : nv + 2]
        g_dir /= np.linalg.norm(g_dir)
        ba = ba + x[nv + 2 :]
    v = x[:nv].reshape(n, 3)
    if np.linalg.norm(ba) > 1.0:
        ba = np.zeros(3)  # not observable enough: leave it to the smoother
    # world frame: gravity along -z
    R_world_vo = rotation_between(np.asarray(g_dir, dtype=np.float64), np.array([0.0, 0.0, -1.0]))
    window = []
    for k in range(n):
        T_w = make_T(R_world_vo @ R[k], R_world_vo @ p[k])
        window.append((int(times[k]), T_w, R_world_vo @ v[k]))
    return InitialState(
        t_ns=int(times[0]),
        T_world_body=window[0][1],
        v_world=window[0][2],
        bg=bg,
        ba=ba,
        mode=InitMode.DYNAMIC,
        window=tuple(window),
        R_world_vo=R_world_vo,
    )
