"""The online smoother: GTSAM's `IncrementalFixedLagSmoother` (`backend.smoother: fixed_lag`) or
plain `ISAM2`, behind one interface. Its failures surface as `EstimatorFailure`."""

from __future__ import annotations

import gtsam
import numpy as np

from eurocslam.backend.types import EstimatorFailure
from eurocslam.config import BackendConfig
from eurocslam.geometry import F64


class Smoother:
    """One smoother per segment (a loop's move starts a new one)."""

    def __init__(self, b: BackendConfig) -> None:
        p = gtsam.ISAM2Params()
        p.setRelinearizeThreshold(b.relinearize_threshold)
        p.relinearizeSkip = b.relinearize_skip
        p.findUnusedFactorSlots = True
        self._lag: gtsam.IncrementalFixedLagSmoother | None = None
        self._isam: gtsam.ISAM2 | None = None
        if b.smoother == "fixed_lag":
            self._lag = gtsam.IncrementalFixedLagSmoother(b.lag_s, p)
        else:
            self._isam = gtsam.ISAM2(p)

    def update(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, stamps: dict[int, float]
    ) -> gtsam.Values:
        """Add the factors and values (each new key with its time `stamps`, seconds: the lag's
        clock); the new estimate."""
        try:
            if self._lag is not None:
                ts = gtsam.FixedLagSmootherKeyTimestampMap()
                for key, t in stamps.items():
                    ts.insert((key, t))  # type: ignore[no-untyped-call]
                self._lag.update(graph, values, ts)
                return self._lag.calculateEstimate()
            assert self._isam is not None
            self._isam.update(graph, values)
            return self._isam.calculateEstimate()
        except RuntimeError as e:
            raise EstimatorFailure(f"smoother update failed: {e}") from None

    def marginal_covariance(self, key: int) -> F64 | None:
        """The marginal covariance of `key` in its tangent space; None where GTSAM cannot give
        it."""
        try:
            if self._lag is not None:
                return np.asarray(self._lag.marginalCovariance(key), dtype=np.float64)
            assert self._isam is not None
            return np.asarray(self._isam.marginalCovariance(key), dtype=np.float64)
        except RuntimeError:
            return None
