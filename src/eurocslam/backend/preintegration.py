"""IMU preintegration: GTSAM parameters from `ImuCalib` and integration between two timestamps.

Noise densities from `imu0/sensor.yaml` are continuous-time; GTSAM's
`PreintegrationCombinedParams` takes continuous-time covariances, so they are passed as
`density**2 * I` (never divided or multiplied by dt here). Gravity is `g` along -z of the world
frame (`MakeSharedU`). The initial-bias covariance setter is gone from GTSAM 4.3: the estimator
puts a prior on the first bias instead.

`integrate(pim, imu, t0_ns, t1_ns)` integrates exactly the span [t0, t1], interpolating linearly
between samples (mid-point rule), so consecutive spans add up without double counting. Spans
with an IMU dropout (a gap between samples longer than `max_gap_s`) are reported, so the caller
can bridge them with vision.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from eurocslam.config import ImuConfig
from eurocslam.dataset.calib import ImuCalib
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64
from eurocslam.timebase import ns_to_s


def make_params(
    imu: ImuCalib, cfg: ImuConfig | None = None, accel_variance_scale: float = 1.0
) -> gtsam.PreintegrationCombinedParams:
    """`PreintegrationCombinedParams` (z-up gravity) from the IMU calibration; the
    accelerometer's noise and bias random walk covariances times `accel_variance_scale`."""
    cfg = cfg or ImuConfig()
    p = gtsam.PreintegrationCombinedParams.MakeSharedU(cfg.gravity)
    i3 = np.eye(3)
    a3 = i3 * accel_variance_scale
    p.setGyroscopeCovariance((imu.gyro_noise_density * cfg.gyro_noise_scale) ** 2 * i3)
    p.setAccelerometerCovariance((imu.accel_noise_density * cfg.accel_noise_scale) ** 2 * a3)
    p.setBiasOmegaCovariance((imu.gyro_random_walk * cfg.gyro_bias_walk_scale) ** 2 * i3)
    p.setBiasAccCovariance((imu.accel_random_walk * cfg.accel_bias_walk_scale) ** 2 * a3)
    p.setIntegrationCovariance(cfg.integration_sigma**2 * i3)
    T_body_imu = np.asarray(imu.T_body_imu, dtype=np.float64)
    if not np.allclose(T_body_imu, np.eye(4), atol=1e-9):
        p.setBodyPSensor(gtsam.Pose3(T_body_imu))
    return p


def bias(bg: F64, ba: F64) -> gtsam.imuBias.ConstantBias:
    return gtsam.imuBias.ConstantBias(np.asarray(ba, dtype=float), np.asarray(bg, dtype=float))


@dataclass(frozen=True)
class SpanInfo:
    """What happened while integrating one span."""

    n_samples: int
    max_gap_s: float  # largest interval without an IMU sample inside the span
    covered: bool  # IMU samples exist at or before t0 and at or after t1 (no dropout at the ends)

    def ok(self, max_gap_s: float) -> bool:
        return self.covered and self.max_gap_s <= max_gap_s


def integrate(
    pim: gtsam.PreintegratedCombinedMeasurements, imu: ImuData, t0_ns: int, t1_ns: int
) -> SpanInfo:
    """Add the IMU measurements covering [t0_ns, t1_ns] to `pim`.

    Samples are instantaneous readings; between two samples the reading is interpolated
    linearly and each (clipped) interval is integrated with its mid-point value, the exact
    mean of the interpolant. A zero-order hold (each sample held until the next) would leave a
    systematic velocity error of dt/2 times the change of acceleration over the span.
    """
    if t1_ns <= t0_ns:
        return SpanInfo(0, 0.0, True)
    t = imu.t_ns
    # last sample at or before t0, first sample at or after t1
    i0 = int(np.searchsorted(t, t0_ns, side="right")) - 1
    i1 = int(np.searchsorted(t, t1_ns, side="left"))
    covered = i0 >= 0 and i1 < t.size
    i0 = max(i0, 0)
    i1 = min(i1, t.size - 1)
    if t.size == 0 or i1 < i0 or (i1 == i0 and not covered and t[i0] > t1_ns):
        return SpanInfo(0, ns_to_s(t1_ns - t0_ns), False)
    ts = t[i0 : i1 + 1].astype(np.int64)
    gyro = imu.gyro[i0 : i1 + 1]
    acc = imu.accel[i0 : i1 + 1]
    # interval k: [ts[k], ts[k+1]] clipped to [t0, t1]; a lone/last sample holds to t1
    starts = np.maximum(ts, t0_ns)
    ends = np.empty_like(starts)
    ends[:-1] = ts[1:]
    ends[-1] = max(int(ts[-1]), t1_ns)
    ends = np.minimum(ends, t1_ns)
    dts = ns_to_s(ends - starts)
    mids = 0.5 * (starts + ends)
    seg = np.maximum(np.diff(ts).astype(np.float64), 1.0)
    w = np.zeros(ts.size)
    if ts.size > 1:
        w[:-1] = np.clip((mids[:-1] - ts[:-1]) / seg, 0.0, 1.0)
    nxt = np.minimum(np.arange(ts.size) + 1, ts.size - 1)
    g_mid = gyro + w[:, None] * (gyro[nxt] - gyro)
    a_mid = acc + w[:, None] * (acc[nxt] - acc)
    for k in np.nonzero(dts > 0.0)[0].tolist():
        pim.integrateMeasurement(a_mid[k], g_mid[k], float(dts[k]))
    # a gap is the spacing of the samples around an integrated interval, however little of it
    # falls in this span: a span inside a dropout is integrated from samples seconds apart
    spacing = ns_to_s(np.append(np.diff(ts), 0))
    gaps = spacing[dts > 0.0]
    if ts[0] > t0_ns:
        gaps = np.append(gaps, ns_to_s(ts[0] - t0_ns))
    if ts[-1] < t1_ns:
        gaps = np.append(gaps, ns_to_s(t1_ns - ts[-1]))
    return SpanInfo(int(ts.size), float(np.max(gaps)) if gaps.size else 0.0, covered)


def gap_in(imu: ImuData, t0_ns: int, t1_ns: int) -> float:
    """Largest interval [s] without IMU data inside [t0, t1] (including the ends)."""
    t = imu.t_ns
    i0 = int(np.searchsorted(t, t0_ns, side="right")) - 1
    i1 = int(np.searchsorted(t, t1_ns, side="left"))
    pts = t[max(i0, 0) : min(i1 + 1, t.size)]
    pts = np.clip(pts, t0_ns, t1_ns)
    pts = np.concatenate([[t0_ns] if i0 < 0 else [], pts, [t1_ns] if i1 >= t.size else []])
    if pts.size < 2:
        return ns_to_s(t1_ns - t0_ns)
    return ns_to_s(float(np.max(np.diff(pts))))
