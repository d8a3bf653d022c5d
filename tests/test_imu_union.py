"""Accelerometer and gyroscope as separate streams at rates that are no multiple of each other
(a RealSense: accel 63/250 Hz, gyro 200/400 Hz), united onto the gyro's stamps by linear
interpolation: the united stream must reproduce a known motion, and preintegrating it must
reproduce the motion's velocity and position change."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from eurocslam.backend.preintegration import integrate, make_params
from eurocslam.dataset.bag.imu_union import unite_imu
from eurocslam.dataset.calib import default_rig
from eurocslam.dataset.types import ImuData
from eurocslam.synth.imu import ideal_imu
from eurocslam.synth.trajectory import builtin_motion

T0 = 1_700_000_000_000_000_000


def _stamps(rate_hz: float, span_s: float, offset_ns: int = 0) -> np.ndarray:
    n = int(span_s * rate_hz) + 1
    return T0 + offset_ns + np.round(np.arange(n) * 1e9 / rate_hz).astype(np.int64)


def test_linear_signals_are_reproduced_exactly() -> None:
    ta = _stamps(63.0, 1.0)
    tg = _stamps(200.0, 1.0, offset_ns=1_234_567)
    slope = np.array([0.5, -2.0, 3.0])
    a = 9.81 + (ta - T0)[:, None] * 1e-9 * slope
    g = np.tile([0.1, 0.2, 0.3], (tg.size, 1))
    u = unite_imu(ta, a, tg, g)
    inside = (tg >= ta[0]) & (tg <= ta[-1])
    assert len(u.imu) == inside.sum() and u.dropped_before == 0
    assert u.dropped_after == tg.size - inside.sum() > 0  # gyro after the last accel sample
    np.testing.assert_array_equal(u.imu.t_ns, tg[inside])
    np.testing.assert_array_equal(u.imu.gyro, g[inside])  # the gyro untouched
    expected = 9.81 + (u.imu.t_ns - T0)[:, None] * 1e-9 * slope
    np.testing.assert_allclose(u.imu.accel, expected, atol=1e-12)


def test_samples_on_shared_stamps_are_kept_as_they_are() -> None:
    t = _stamps(200.0, 0.5)
    rng = np.random.default_rng(0)
    a, g = rng.normal(size=(t.size, 3)), rng.normal(size=(t.size, 3))
    u = unite_imu(t, a, t, g)
    np.testing.assert_array_equal(u.imu.accel, a)
    np.testing.assert_array_equal(u.imu.gyro, g)
    assert u.dropped == 0


@pytest.mark.parametrize(("accel_hz", "gyro_hz"), [(250.0, 400.0), (63.0, 200.0)])
def test_united_stream_reproduces_a_known_motion(accel_hz: float, gyro_hz: float) -> None:
    """The built-in drone flight (up to ~3 m/s^2): the interpolated accelerometer stays within
    the linear-interpolation error bound of the exact one at the gyro's stamps, and a
    preintegration over 1 s of it lands where the exact readings do."""
    motion = builtin_motion(4.0, seed=3)
    span = 3.0
    ta = _stamps(accel_hz, span)
    tg = _stamps(gyro_hz, span, offset_ns=700_000)  # the two clocks are not aligned

    def at(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return ideal_imu(motion.spline, (t_ns - T0).astype(np.float64) * 1e-9 + 0.5)

    _, a_meas = at(ta)
    g_true, a_true = at(tg)
    u = unite_imu(ta, a_meas, tg, g_true)
    keep = (tg >= ta[0]) & (tg <= ta[-1])
    np.testing.assert_array_equal(u.imu.t_ns, tg[keep])
    err = np.abs(u.imu.accel - a_true[keep]).max()
    # linear interpolation error <= max|a''| h^2 / 8, a'' measured on a fine grid
    tf = _stamps(2000.0, span)
    _, a_fine = at(tf)
    a2 = np.abs(np.diff(a_fine, 2, axis=0)).max() / (1 / 2000.0) ** 2
    bound = a2 * (1.0 / accel_hz) ** 2 / 8
    assert err <= 1.05 * bound + 1e-9, (err, bound)
    assert err < (0.02 if accel_hz > 100 else 0.2)  # m/s^2
    # preintegrated over 1 s: velocity and position change against the exact readings
    imu = default_rig().imu
    assert imu is not None
    t0, t1 = int(tg[keep][10]), int(tg[keep][10]) + 1_000_000_000
    deltas = []
    for accel in (u.imu.accel, a_true[keep]):
        pim = gtsam.PreintegratedCombinedMeasurements(make_params(imu))
        integrate(pim, ImuData(u.imu.t_ns, u.imu.gyro, accel), t0, t1)
        deltas.append((pim.deltaVij(), pim.deltaPij()))
    dv = np.linalg.norm(deltas[0][0] - deltas[1][0])
    dp = np.linalg.norm(deltas[0][1] - deltas[1][1])
    assert dv < (2e-3 if accel_hz > 100 else 2e-2) and dp < (1e-3 if accel_hz > 100 else 1e-2)


def test_no_overlap_keeps_nothing() -> None:
    ta = _stamps(100.0, 0.1)
    tg = _stamps(200.0, 0.1, offset_ns=1_000_000_000)
    u = unite_imu(ta, np.zeros((ta.size, 3)), tg, np.zeros((tg.size, 3)))
    assert len(u.imu) == 0 and u.dropped_after == tg.size
