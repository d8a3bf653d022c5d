"""One IMU stream from an accelerometer and a gyroscope published separately (realsense-ros
without `unite_imu_method`: `/camera/accel/sample` at 63 or 250 Hz, `/camera/gyro/sample` at 200
or 400 Hz, neither a multiple of the other).

`unite_imu` puts the accelerometer onto the gyroscope's stamps by linear interpolation between
the two accelerometer samples around each gyro stamp, as realsense-ros's
`unite_imu_method: linear_interpolation` does: the united stream keeps the gyro's rate and its
samples exactly. Gyro samples before the first or after the last accelerometer sample have no
bracketing pair and are dropped (counted); an accelerometer gap does not stop the interpolation,
the doctor reports gaps per stream. With `R_gyro_accel` the accelerometer's vectors are first
rotated into the gyro's frame (the body frame of the united stream).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eurocslam.dataset.types import I64, ImuData
from eurocslam.geometry import F64


@dataclass(frozen=True)
class UnitedImu:
    """The united stream and what uniting did."""

    imu: ImuData
    dropped_before: int  # gyro samples before the first accelerometer sample
    dropped_after: int  # ... and after the last one

    @property
    def dropped(self) -> int:
        return self.dropped_before + self.dropped_after


def unite_imu(
    accel_t_ns: I64,
    accel: F64,
    gyro_t_ns: I64,
    gyro: F64,
    R_gyro_accel: F64 | None = None,
) -> UnitedImu:
    """Accelerometer interpolated linearly onto the gyro stamps. Both streams sorted by time
    with unique stamps (the bag reader sorts and de-duplicates them first)."""
    ta = np.asarray(accel_t_ns, dtype=np.int64)
    tg = np.asarray(gyro_t_ns, dtype=np.int64)
    a = np.asarray(accel, dtype=np.float64).reshape(-1, 3)
    g = np.asarray(gyro, dtype=np.float64).reshape(-1, 3)
    if R_gyro_accel is not None:
        a = a @ np.asarray(R_gyro_accel, dtype=np.float64).T
    if ta.size == 0 or tg.size == 0:
        return UnitedImu(ImuData(tg[:0], g[:0], a[:0]), int(tg.size), 0)
    lo = int(np.searchsorted(tg, ta[0], side="left"))
    hi = int(np.searchsorted(tg, ta[-1], side="right"))
    t_out = tg[lo:hi]
    g_out = g[lo:hi]
    if t_out.size == 0:
        return UnitedImu(ImuData(t_out, g_out, a[:0]), lo, int(tg.size) - hi)
    if ta.size == 1:  # one accelerometer sample: every kept gyro stamp equals it
        a_out = np.repeat(a[:1], t_out.size, axis=0)
    else:
        # the accelerometer interval [ta[j], ta[j + 1]] holding each gyro stamp
        j = np.clip(np.searchsorted(ta, t_out, side="right") - 1, 0, ta.size - 2)
        # weights from integer nanosecond differences (exact before the one division)
        w = (t_out - ta[j]).astype(np.float64) / (ta[j + 1] - ta[j]).astype(np.float64)
        # (1 - w) a_j + w a_j+1: exactly a sample's value on a shared stamp (w = 0 or 1)
        a_out = (1.0 - w)[:, None] * a[j] + w[:, None] * a[j + 1]
    return UnitedImu(
        ImuData(t_out.copy(), np.ascontiguousarray(g_out), np.ascontiguousarray(a_out)),
        lo,
        int(tg.size) - hi,
    )
