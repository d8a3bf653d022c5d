"""IMU for synthetic sequences: simulated from the trajectory, or real rows from a file.

Simulated (body = IMU frame, z-up world, g = (0, 0, -9.81)):

    gyro  = w_body + b_g + n_g
    accel = R_world_body^T (a_world - g) + b_a + n_a

with discrete white noise sigma = density / sqrt(dt) and a bias random walk of sigma
random_walk * sqrt(dt) per sample, from the rig's `ImuCalib` (imu0/sensor.yaml). Initial biases are
drawn once per seed at EuRoC-like magnitudes. The ground truth written next to the IMU carries
the biases actually used.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.dataset.asl import read_numeric_csv
from eurocslam.dataset.calib import ImuCalib
from eurocslam.errors import DatasetError
from eurocslam.geometry import F64
from eurocslam.synth.kinematics import GRAVITY
from eurocslam.synth.spline import SplineTrajectory
from eurocslam.timebase import ns_to_s

# spread of the initial biases (EuRoC's own are ~0.02-0.08 rad/s and ~0.02-0.14 m/s^2)
INITIAL_GYRO_BIAS_SIGMA = 0.02
INITIAL_ACCEL_BIAS_SIGMA = 0.08


@dataclass(frozen=True)
class ImuStream:
    t_ns: np.ndarray  # int64
    gyro: F64  # (N, 3) rad/s, IMU frame
    accel: F64  # (N, 3) m/s^2
    bg: F64  # (N, 3) gyro bias in effect at each sample
    ba: F64  # (N, 3) accel bias
    real: bool = False


def ideal_imu(spline: SplineTrajectory, t_s: F64) -> tuple[F64, F64]:
    """Noise-free, bias-free gyro and accelerometer readings at spline times t_s."""
    st = spline.evaluate(t_s)
    f_world = st.a - GRAVITY
    accel = np.einsum("nji,nj->ni", st.R, f_world)  # R^T f
    return st.w_body, accel


def simulate_imu(
    spline: SplineTrajectory,
    t0_ns: int,
    t_ns: np.ndarray,
    calib: ImuCalib,
    seed: int,
    *,
    noise: bool,
    bias: bool,
) -> ImuStream:
    """Simulated IMU samples at `t_ns` (absolute, int64)."""
    if not np.allclose(calib.T_body_imu, np.eye(4), atol=1e-9):
        raise DatasetError(
            "imu0/sensor.yaml: T_BS must be the identity for synthesis (the ground-truth body "
            "frame is the IMU frame, as on EuRoC)"
        )
    t_s = ns_to_s((t_ns - t0_ns).astype(np.float64))
    gyro, accel = ideal_imu(spline, t_s)
    n = t_ns.shape[0]
    rng = np.random.default_rng([seed, 0x1A0])
    bg = np.zeros((n, 3))
    ba = np.zeros((n, 3))
    if bias:
        bg[:] = rng.normal(0.0, INITIAL_GYRO_BIAS_SIGMA, 3)
        ba[:] = rng.normal(0.0, INITIAL_ACCEL_BIAS_SIGMA, 3)
    if noise:
        dt = np.diff(t_s, prepend=t_s[0] - 1.0 / calib.rate_hz)
        sq = np.sqrt(dt)[:, None]
        walk_g = np.cumsum(rng.normal(0.0, 1.0, (n, 3)) * sq * calib.gyro_random_walk, axis=0)
        walk_a = np.cumsum(rng.normal(0.0, 1.0, (n, 3)) * sq * calib.accel_random_walk, axis=0)
        bg += walk_g - walk_g[0]
        ba += walk_a - walk_a[0]
        sd = 1.0 / np.sqrt(1.0 / calib.rate_hz)
        gyro = gyro + rng.normal(0.0, calib.gyro_noise_density * sd, (n, 3))
        accel = accel + rng.normal(0.0, calib.accel_noise_density * sd, (n, 3))
    return ImuStream(t_ns, gyro + bg, accel + ba, bg, ba)


def read_real_imu(path: Path, t_from_ns: int, t_to_ns: int) -> tuple[np.ndarray, F64, F64]:
    """Real IMU rows (ASL imu0/data.csv) with t_from <= t <= t_to: (t_ns, gyro, accel)."""
    path = Path(path)
    if path.is_dir():
        for cand in (
            path / "mav0" / "imu0" / "data.csv",
            path / "imu0" / "data.csv",
            path / "data.csv",
        ):
            if cand.is_file():
                path = cand
                break
    tab = read_numeric_csv(path, 7)
    if tab.t_ns.size < 2:
        raise DatasetError(f"{path}: no IMU rows")
    if np.any(np.diff(tab.t_ns) <= 0):
        k = int(np.flatnonzero(np.diff(tab.t_ns) <= 0)[0]) + 1
        raise DatasetError(f"{path}:{tab.line_numbers[k]}: IMU timestamps must increase")
    m = (tab.t_ns >= t_from_ns) & (tab.t_ns <= t_to_ns)
    if int(m.sum()) < 2:
        raise DatasetError(
            f"{path}: no IMU rows inside the trajectory's time span "
            f"[{t_from_ns}, {t_to_ns}] ns (the IMU covers [{tab.t_ns[0]}, {tab.t_ns[-1]}] ns)"
        )
    v = tab.values[m]
    return tab.t_ns[m], np.ascontiguousarray(v[:, 0:3]), np.ascontiguousarray(v[:, 3:6])


def real_imu_stream(
    t_ns: np.ndarray,
    gyro: F64,
    accel: F64,
    bias_source: tuple[np.ndarray, F64, F64] | None,
) -> ImuStream:
    """Real IMU rows, with the biases of the given ground truth (interpolated) or zeros."""
    n = t_ns.shape[0]
    bg = np.zeros((n, 3))
    ba = np.zeros((n, 3))
    if bias_source is not None:
        ts, sbg, sba = bias_source
        x = (ts - ts[0]).astype(np.float64)
        xq = (t_ns - ts[0]).astype(np.float64)
        for k in range(3):
            bg[:, k] = np.interp(xq, x, sbg[:, k])
            ba[:, k] = np.interp(xq, x, sba[:, k])
    return ImuStream(t_ns, gyro, accel, bg, ba, real=True)


def simulate_accelerometer(
    spline: SplineTrajectory,
    t0_ns: int,
    t_ns: np.ndarray,
    stream: ImuStream,
    calib: ImuCalib,
    rate_hz: float,
    seed: int,
    *,
    noise: bool,
) -> F64:
    """An accelerometer sampled apart from the gyroscope (a RealSense's own clock and rate):
    the exact specific force at `t_ns`, the accelerometer bias of `stream` (interpolated; one
    bias process drives both streams) and white noise of density / sqrt(1 / rate_hz)."""
    t_s = (t_ns - t0_ns).astype(np.float64) * 1e-9
    _, accel = ideal_imu(spline, t_s)
    x = (stream.t_ns - stream.t_ns[0]).astype(np.float64)
    xq = (t_ns - stream.t_ns[0]).astype(np.float64)
    ba = np.column_stack([np.interp(xq, x, stream.ba[:, k]) for k in range(3)])
    out: F64 = accel + ba
    if noise:
        rng = np.random.default_rng([seed, 0xACC])
        out = out + rng.normal(0.0, calib.accel_noise_density * np.sqrt(rate_hz), out.shape)
    return out
