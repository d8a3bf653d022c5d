"""Motion for synthetic sequences: the built-in drone-like flight, or a given ground truth.

Both end up as a `SplineTrajectory` (see `spline.py`) in a z-up, gravity-aligned world, with
times in seconds relative to the sequence start `t0_ns`.

Built-in flight (deterministic per seed): the drone sits on the floor, takes off to a hover
height, then flies smooth loops (sums of sines per axis) with yaw changes, scaled so the peak
speed and yaw rate hit the requested values. Its attitude is that of a multirotor: the thrust
axis follows the specific force (a - g), the heading follows a smooth yaw profile. The body
frame is the EuRoC IMU frame: body x up (thrust), body z forward (where the cameras look).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from eurocslam.dataset.asl import read_numeric_csv
from eurocslam.errors import DatasetError
from eurocslam.geometry import F64, quat_wxyz_to_rot, rot_to_quat_wxyz
from eurocslam.synth.fusion import fuse_imu_groundtruth
from eurocslam.synth.kinematics import GRAVITY
from eurocslam.synth.spline import SplineTrajectory, fit_spline
from eurocslam.timebase import ns_to_s

BUILTIN_T0_NS = 1_400_000_000_000_000_000  # a realistic epoch (2014-05-13), like EuRoC's


@dataclass(frozen=True)
class Motion:
    """A spline trajectory plus where it came from.

    `t0_ns` is the absolute time of spline time 0. `bias_source` (optional) gives IMU biases
    from the input ground truth, as (t_ns, bg (N, 3), ba (N, 3)). `fit_rms_m`/`fit_rms_deg` are
    the residuals of the spline against the input poses (0 for the built-in motion).
    `world_R` rotates the input's world into the spline's (a real-IMU replica's world is turned
    so the real accelerometer's gravity points along -z; otherwise the identity).
    """

    spline: SplineTrajectory
    t0_ns: int
    t_start_s: float  # first usable time (spline time)
    t_end_s: float  # last usable time
    description: str
    bias_source: tuple[np.ndarray, F64, F64] | None = None
    fit_rms_m: float = 0.0
    fit_rms_deg: float = 0.0
    world_R: F64 | None = None


def _smoothstep(x: F64) -> F64:
    """C2 ramp 0 -> 1 on [0, 1] (quintic)."""
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x * x)


def builtin_motion(
    duration_s: float, seed: int, *, max_speed: float = 1.5, max_yaw_rate: float = 1.0
) -> Motion:
    """The built-in drone flight of `duration_s` seconds (>= 0.2)."""
    if not duration_s >= 0.2:
        raise DatasetError(f"duration {duration_s:g} s: the built-in motion needs at least 0.2 s")
    rng = np.random.default_rng([seed, 0x5EED])
    dt = 0.005
    t: F64 = np.asarray(np.arange(round((duration_s + 1.0) / dt) + 1) * dt, dtype=np.float64)
    rest = float(np.clip(0.08 * duration_s, 0.3, 2.0))
    hover = float(rng.uniform(1.1, 1.6))
    if duration_s >= 8.0:
        # on the floor, then a take-off slow enough to keep |a| <= 3 m/s^2 (peak of the quintic
        # ramp: 5.77 dh / T^2)
        z_rest = 0.15  # body centre above the floor when standing
        climb = max(
            float(np.clip(0.12 * duration_s, 0.6, 3.0)),
            float(np.sqrt(5.77 * (hover - z_rest) / 3.0)),
        )
    else:
        # short sequences (unit tests) start hovering still, so they are all flight
        z_rest, climb = hover, 0.6
    lift = _smoothstep((t - rest) / climb)
    # loops: blend in after the climb starts, so the flight never stands still in the air
    t_loop = rest + 0.5 * climb
    ramp = _smoothstep((t - t_loop) / (3.0 if duration_s >= 8.0 else 1.5))
    disp = np.zeros((t.size, 3))
    for k, amp in enumerate((1.0, 1.0, 0.25)):
        f = rng.uniform(0.05, 0.14, size=2) * 2 * np.pi
        ph = rng.uniform(0, 2 * np.pi, size=2)
        a = amp * rng.uniform(0.6, 1.0, size=2)
        s = sum(a[j] * (np.sin(f[j] * (t - t_loop) + ph[j]) - np.sin(ph[j])) for j in range(2))
        disp[:, k] = s
    disp *= ramp[:, None]
    # scale horizontal loop size so the peak speed matches max_speed
    vel = np.gradient(disp, dt, axis=0)
    peak = float(np.max(np.linalg.norm(vel, axis=1)))
    disp *= max_speed / max(peak, 1e-9)
    p = disp.copy()
    p[:, 2] += z_rest + (hover - z_rest) * lift
    # yaw: smooth random profile, peak rate = max_yaw_rate
    yaw = np.zeros(t.size)
    for _ in range(3):
        fy = rng.uniform(0.05, 0.25) * 2 * np.pi
        phy = rng.uniform(0, 2 * np.pi)
        yaw += rng.uniform(0.5, 1.0) * (np.sin(fy * (t - t_loop) + phy) - np.sin(phy))
    yaw += rng.choice([-1.0, 1.0]) * 0.3 * (t - t_loop)  # a slow overall turn
    yaw = yaw * ramp
    yaw *= max_yaw_rate / max(float(np.max(np.abs(np.gradient(yaw, dt)))), 1e-9)
    yaw += rng.uniform(-np.pi, np.pi)
    # attitude: thrust axis (body x) along the specific force, body z towards the heading
    acc = np.gradient(np.gradient(p, dt, axis=0), dt, axis=0)
    acc[t < rest] = 0.0
    x_b = acc - GRAVITY
    x_b /= np.linalg.norm(x_b, axis=1, keepdims=True)
    head = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], -1)
    z_b = head - np.einsum("ij,ij->i", head, x_b)[:, None] * x_b
    z_b /= np.linalg.norm(z_b, axis=1, keepdims=True)
    y_b = np.cross(z_b, x_b)
    R = np.stack([x_b, y_b, z_b], axis=-1)  # columns: body axes in world
    spline = fit_spline(t, p, rot_to_quat_wxyz(R), knot_dt=0.05)
    return Motion(
        spline=spline,
        t0_ns=BUILTIN_T0_NS,
        t_start_s=0.0,
        t_end_s=float(duration_s),
        description=f"built-in flight, {duration_s:g} s, seed {seed}",
    )


@dataclass(frozen=True)
class GroundTruthInput:
    """Poses read from a trajectory file, plus bias columns when the file had them."""

    path: Path
    t_ns: np.ndarray
    p: F64
    q_wxyz: F64
    bg: F64 | None
    ba: F64 | None


def read_groundtruth_file(path: Path) -> GroundTruthInput:
    """Read a TUM or EuRoC CSV trajectory; a 17-column ASL ground truth also gives biases."""
    from eurocslam.trajectory_io import read_trajectory

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: trajectory file not found")
    traj = read_trajectory(path)
    if traj.has_segments:
        raise DatasetError(f"{path}: has several segments; give a single continuous trajectory")
    if len(traj) < 4:
        raise DatasetError(f"{path}: only {len(traj)} poses; need at least 4")
    bg = ba = None
    first = next(
        (ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")), ""
    )
    if first.count(",") == 16:
        tab = read_numeric_csv(path, 17)
        if tab.t_ns.shape == traj.t_ns.shape and np.array_equal(tab.t_ns, traj.t_ns):
            bg, ba = tab.values[:, 10:13].copy(), tab.values[:, 13:16].copy()
    return GroundTruthInput(path, traj.t_ns, traj.p, traj.q_wxyz, bg, ba)


def reexpress(gt: GroundTruthInput, T_oldbody_newbody: F64) -> GroundTruthInput:
    """The same motion as the pose of another body frame rigidly attached to the first
    (`T_world_newbody = T_world_oldbody T_oldbody_newbody`); bias columns turned into it."""
    R = quat_wxyz_to_rot(gt.q_wxyz)
    r_on, t_on = T_oldbody_newbody[:3, :3], T_oldbody_newbody[:3, 3]
    p = gt.p + R @ t_on
    q = rot_to_quat_wxyz(R @ r_on)
    bg = gt.bg @ r_on if gt.bg is not None else None  # (r_on^T b per row)
    ba = gt.ba @ r_on if gt.ba is not None else None
    return replace(gt, p=p, q_wxyz=q, bg=bg, ba=ba)


def motion_from_groundtruth(
    gt: GroundTruthInput,
    *,
    start_s: float | None = None,
    end_s: float | None = None,
    knot_dt: float = 0.1,
    smooth_sigma_s: float = 0.03,
    imu: tuple[np.ndarray, F64, F64] | None = None,
) -> Motion:
    """Spline through a real ground truth, cropped to [start_s, end_s] seconds after its first
    pose. The fit uses up to 1 s of poses beyond the crop so its ends are not distorted.

    With `imu` (t_ns, gyro, accel: the real IMU rows that will ship with the replica) the motion
    is the IMU's at high frequency and the ground truth's at low frequency (`fusion.py`), in a
    world turned so the accelerometer's gravity is along -z, with a knot per IMU sample;
    `knot_dt` and `smooth_sigma_s` are then unused."""
    t_ns = gt.t_ns
    t_first = int(t_ns[0])
    rel = ns_to_s((t_ns - t_first).astype(np.float64))
    total = float(rel[-1])
    a = 0.0 if start_s is None else float(start_s)
    b = total if end_s is None else min(float(end_s), total)
    if a < 0 or a >= b:
        raise DatasetError(
            f"{gt.path}: crop [{a:g}, {b:g}] s is empty (the file spans 0 to {total:.2f} s)"
        )
    if b - a < 2 * knot_dt + 0.05:
        raise DatasetError(f"{gt.path}: crop [{a:g}, {b:g}] s is too short (need > 0.25 s)")
    gaps = np.diff(rel)
    inside = (rel[1:] > a) & (rel[:-1] < b)
    if np.any(gaps[inside] > 0.5):
        k = int(np.flatnonzero(inside & (gaps > 0.5))[0])
        raise DatasetError(
            f"{gt.path}: gap of {gaps[k]:.2f} s in the poses at {rel[k]:.2f} s after the start; "
            "crop around it with --start/--end"
        )
    sel = (rel >= a - 1.0) & (rel <= b + 1.0)
    # spline time 0 = the first pose at or after the crop start, on the file's own clock
    i0 = int(np.searchsorted(rel, a - 1e-9))
    t0_ns = int(t_ns[i0])
    ts = ns_to_s((t_ns[sel] - t0_ns).astype(np.float64))
    world_R = None
    p_in, q_in = gt.p[sel], gt.q_wxyz[sel]
    if imu is None:
        spline = fit_spline(ts, p_in, q_in, knot_dt=knot_dt, smooth_sigma_s=smooth_sigma_s)
    else:
        spline, world_R, const_bias = _imu_spline(gt, sel, t0_ns, imu)
        p_in = p_in @ world_R.T
        q_in = rot_to_quat_wxyz(world_R @ quat_wxyz_to_rot(q_in))
    t_end = min(b - ns_to_s(t0_ns - t_first), spline.t_end)
    # residuals against the input inside the crop
    m = (ts >= 0) & (ts <= t_end)
    st = spline.evaluate(ts[m])
    dp = np.linalg.norm(st.p - p_in[m], axis=1)
    Rin = quat_wxyz_to_rot(q_in[m])
    cosang = (np.einsum("nij,nij->n", st.R, Rin) - 1.0) / 2.0
    ang = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    bias = None
    if imu is not None:
        bias = const_bias
    elif gt.bg is not None and gt.ba is not None:
        bias = (t_ns, gt.bg, gt.ba)
    return Motion(
        spline=spline,
        t0_ns=t0_ns,
        t_start_s=max(0.0, spline.t0),
        t_end_s=float(t_end),
        description=f"replica of {gt.path.name} [{a:g} s, {b:g} s]",
        bias_source=bias,
        fit_rms_m=float(np.sqrt(np.mean(dp**2))),
        fit_rms_deg=float(np.sqrt(np.mean(ang**2))),
        world_R=world_R,
    )


def _imu_spline(
    gt: GroundTruthInput, sel: np.ndarray, t0_ns: int, imu: tuple[np.ndarray, F64, F64]
) -> tuple[SplineTrajectory, F64, tuple[np.ndarray, F64, F64]]:
    """Spline (a knot per IMU sample) over the selected poses' time span through the IMU/ground
    truth fusion; the rotation of the input world into the spline's; and the (constant) biases
    the fusion took off the IMU, as a bias source. The fusion runs over the whole overlap of
    the IMU and the ground truth, so every crop of a sequence has the same motion and world.

    The biases are the means of the ground truth's bias columns. V1_01's (an IMU/Vicon fit)
    swing by 20-100 mm/s^2 within 5 s, but that fit used its own orientation, whose tilt the
    accelerometer and gyro both disagree with; a constant bias imports none of it, and what the
    real accelerometer does beyond it stays in the replica as the IMU's own error."""
    t_imu, gyro, accel = imu
    m = (t_imu >= gt.t_ns[0]) & (t_imu <= gt.t_ns[-1])
    lo, hi = int(gt.t_ns[sel][0]), int(gt.t_ns[sel][-1])
    if int(np.count_nonzero(m & (t_imu >= lo) & (t_imu <= hi))) < 10:
        raise DatasetError(
            f"{gt.path}: the IMU rows do not cover the ground truth's poses "
            f"[{lo}, {hi}] ns of the crop"
        )
    t_imu, gyro, accel = t_imu[m], gyro[m], accel[m]
    R_in = quat_wxyz_to_rot(gt.q_wxyz)
    if gt.bg is not None and gt.ba is not None:
        bg, ba = gt.bg.mean(axis=0), gt.ba.mean(axis=0)
    else:
        # no bias columns: a constant gyro bias against the ground truth's rotation rate
        ts = ns_to_s((gt.t_ns - gt.t_ns[0]).astype(np.float64))
        ref = fit_spline(ts, gt.p, gt.q_wxyz, knot_dt=0.1, smooth_sigma_s=0.03)
        w = ref.evaluate(ns_to_s((t_imu - gt.t_ns[0]).astype(np.float64))).w_body
        bg, ba = np.mean(gyro - w, axis=0), np.zeros(3)
    bg_n = np.broadcast_to(bg, gyro.shape)
    ba_n = np.broadcast_to(ba, accel.shape)
    try:
        fused = fuse_imu_groundtruth(t_imu, gyro, accel, bg_n, ba_n, gt.t_ns, R_in, gt.p)
    except DatasetError as e:
        raise DatasetError(f"{gt.path} with the given IMU rows: {e}") from None
    keep = (t_imu >= lo) & (t_imu <= hi)
    t = ns_to_s((t_imu[keep] - t0_ns).astype(np.float64))
    q = rot_to_quat_wxyz(fused.R[keep])
    period = float(np.median(np.diff(t)))
    spline = fit_spline(t, fused.p[keep], q, knot_dt=period, grid_dt=period)
    bias = (np.array([t_imu[0], t_imu[-1]]), np.stack([bg, bg]), np.stack([ba, ba]))
    return spline, fused.world_R, bias
