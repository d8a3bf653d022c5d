"""Health of the estimate: decide when the pipeline must reset and start a new segment.

Checked after every keyframe update and every bridged frame. A failed check never lets the
pipeline continue silently: it ends the current trajectory segment, re-initialises, and the
reason is counted in the run summary.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eurocslam.backend.types import NavEstimate
from eurocslam.config import HealthConfig


@dataclass(frozen=True)
class Verdict:
    ok: bool
    reason: str = ""


OK = Verdict(True)


class Health:
    """The checks of one run's mode: visual-only skips the velocity and bias bounds (nothing
    measures them) and bridges blind frames for less long."""

    def __init__(self, cfg: HealthConfig, inertial: bool) -> None:
        self.cfg = cfg
        self.inertial = inertial

    def state(self, st: NavEstimate) -> Verdict:
        """NaN, velocity and bias bounds of a smoothed state."""
        cfg = self.cfg
        arrays = (st.T_world_body, st.v_world, st.bg, st.ba)
        if not all(np.all(np.isfinite(a)) for a in arrays):
            return Verdict(False, "non-finite state")
        R = st.T_world_body[:3, :3]
        if abs(np.linalg.det(R) - 1.0) > 1e-3:
            return Verdict(False, "rotation not orthonormal")
        if not self.inertial:
            return OK
        speed = float(np.linalg.norm(st.v_world))
        if speed > cfg.max_speed:
            return Verdict(False, f"velocity {speed:.1f} m/s out of bounds")
        bg = float(np.max(np.abs(st.bg)))
        if bg > cfg.max_gyro_bias:
            return Verdict(False, f"gyro bias {bg:.3f} rad/s out of bounds")
        ba = float(np.max(np.abs(st.ba)))
        if ba > cfg.max_accel_bias:
            return Verdict(False, f"accel bias {ba:.2f} m/s^2 out of bounds")
        return OK

    def motion(
        self, T_pred: np.ndarray, T_last: np.ndarray, dt_s: float, T_new: np.ndarray
    ) -> Verdict:
        """Is `T_new` a plausible pose? Stereo-inertial: within `max_prediction_error_m` of the
        IMU's prediction `T_pred`. Visual-only (no prediction to trust: the car may have moved a
        metre since the last frame): within `max_speed` x `dt_s` of the last tracked pose
        `T_last`."""
        if self.inertial:
            err = float(np.linalg.norm(T_new[:3, 3] - T_pred[:3, 3]))
            if not np.isfinite(err) or err > self.cfg.max_prediction_error_m:
                return Verdict(False, f"pose jumped {err:.2f} m from the IMU's prediction")
            return OK
        step = float(np.linalg.norm(T_new[:3, 3] - T_last[:3, 3]))
        speed = step / max(dt_s, 1e-3)
        if not np.isfinite(step) or speed > self.cfg.max_speed:
            return Verdict(False, f"pose jumped {step:.2f} m in {dt_s:.2f} s ({speed:.0f} m/s)")
        return OK

    def lost(self, lost_s: float, imu_ok: bool) -> Verdict:
        """How long the pipeline may bridge frames without vision (`imu_ok`: the IMU has no
        dropout since the last keyframe)."""
        cfg = self.cfg
        if self.inertial and imu_ok:
            if lost_s > cfg.max_lost_s:
                return Verdict(False, f"no visual tracking for {lost_s:.1f} s")
            return OK
        if lost_s > cfg.max_lost_s_no_imu:
            what = "IMU dropout" if self.inertial else "visual-only"
            return Verdict(False, f"no visual tracking for {lost_s:.2f} s ({what})")
        return OK
