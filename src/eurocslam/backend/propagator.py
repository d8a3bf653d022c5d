"""The state between keyframes, predicted from the latest keyframe's: IMU preintegration since
that keyframe, or a constant velocity where there is none (visual-only, or across an IMU
dropout). The preintegration is also what the next keyframe's IMU factor holds. A visual-only
run's pose prediction comes from its last two output poses instead (`visual_pose`): without an
IMU no velocity is estimated between keyframes."""

from __future__ import annotations

import gtsam
import numpy as np

from eurocslam.backend.factors import ImuModel
from eurocslam.backend.preintegration import bias, integrate
from eurocslam.backend.types import NavEstimate
from eurocslam.geometry import F64, extrapolate_last
from eurocslam.timebase import ns_to_s


class Propagator:
    """Preintegrates the IMU from the latest keyframe (`restart`) up to the time asked
    (`predict`); `imu` None: visual-only, constant velocity only."""

    def __init__(self, imu: ImuModel | None, max_gap_s: float) -> None:
        self._imu = imu
        self._max_gap_s = max_gap_s
        self._pim: gtsam.PreintegratedCombinedMeasurements | None = None
        self._t_ns = 0
        self._ok = True

    def restart(self, st: NavEstimate) -> None:
        """Preintegrate anew from the keyframe state `st` (its biases)."""
        if self._imu is None:
            return
        self._pim = gtsam.PreintegratedCombinedMeasurements(self._imu.params, bias(st.bg, st.ba))
        self._t_ns = st.t_ns
        self._ok = True

    def _extend(self, t_ns: int) -> None:
        assert self._pim is not None and self._imu is not None
        if t_ns <= self._t_ns:
            return
        info = integrate(self._pim, self._imu.data, self._t_ns, t_ns)
        if not info.ok(self._max_gap_s):
            self._ok = False
        self._t_ns = t_ns

    @property
    def imu_ok(self) -> bool:
        """No IMU dropout since the latest keyframe (always True visual-only)."""
        return self._ok

    @property
    def imu_links(self) -> bool:
        """The next keyframe is linked to the latest by an IMU factor (`preintegrated`)."""
        return self._imu is not None and self._ok

    @property
    def preintegrated(self) -> gtsam.PreintegratedCombinedMeasurements:
        assert self._pim is not None
        return self._pim

    def predict(self, st: NavEstimate, t_ns: int) -> NavEstimate:
        """The state at `t_ns` from the latest keyframe's `st`."""
        dt = ns_to_s(t_ns - st.t_ns)
        if self._imu is not None:
            self._extend(t_ns)
        if self.imu_links:
            nav = gtsam.NavState(
                gtsam.Rot3(st.T_world_body[:3, :3]),
                gtsam.Point3(*st.T_world_body[:3, 3]),  # type: ignore[no-untyped-call]
                st.v_world,
            )
            pred = self.preintegrated.predict(nav, bias(st.bg, st.ba))
            T = pred.pose().matrix()
            v = np.asarray(pred.velocity())
        else:
            T = st.T_world_body.copy()
            T[:3, 3] = T[:3, 3] + st.v_world * dt
            v = st.v_world
        return NavEstimate(t_ns, T, v, st.bg, st.ba)


def visual_pose(recent: list[tuple[int, F64]], t_ns: int, T_keyframe: F64) -> F64:
    """Visual-only: the pose at `t_ns` at constant body-frame twist from the segment's last two
    output poses (`recent`, (t_ns, T_world_body)); before there are any, the latest keyframe's
    `T_keyframe`."""
    T = extrapolate_last(recent, t_ns)
    return T_keyframe if T is None else T
