"""Losing track and finding it again: how long since the last trusted pose, whether a new pose
is plausible, and what a frame without a tracked pose gets.

A frame the tracker cannot place is bridged by the prediction while it is worth something
(`health.max_lost_s` with the IMU, `max_lost_s_no_imu` without or across an IMU dropout; an IMU
dropout has no prediction to give). Beyond, with place recognition, frames get no pose while
relocalization is tried for up to `places.relocalize_max_s`; then, or without place
recognition, the segment ends (a reset) and the next one starts from the last trusted pose.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from eurocslam.backend.health import Health, Verdict
from eurocslam.config import PlacesConfig
from eurocslam.geometry import F64
from eurocslam.timebase import ns_to_s


class LostAction(Enum):
    BRIDGE = "bridge"  # the prediction is the frame's pose
    WAIT = "wait"  # no pose; relocalization goes on
    RESET = "reset"  # the segment ends


@dataclass(frozen=True)
class LostDecision:
    action: LostAction
    reason: str = ""  # RESET: why
    T_hint: F64 | None = None  # RESET: where the next segment starts
    guess: bool = True  # RESET: the frame gets `T_hint` as its pose (False: it gets none)


class Recovery:
    """The last trusted pose and the decisions that depend on it. `places`: place recognition's
    configuration (None: no place recognition)."""

    def __init__(self, health: Health, places: PlacesConfig | None) -> None:
        self.health = health
        self.places = places
        self._t: int | None = None  # the last trusted (tracked or smoothed) frame ...
        self._T: F64 | None = None  # ... and its pose

    def trusted(self, t_ns: int, T_world_body: F64) -> None:
        self._t, self._T = t_ns, T_world_body

    def lost_s(self, t_ns: int) -> float:
        """Seconds since the last trusted pose (0 before the first)."""
        return ns_to_s(t_ns - (self._t or t_ns))

    def verdict(self, t_ns: int, imu_ok: bool) -> Verdict:
        """Whether a prediction is still worth something this long after the last trusted
        pose (`imu_ok`: no IMU dropout since the latest keyframe)."""
        return self.health.lost(self.lost_s(t_ns), imu_ok)

    def min_inliers(self, blind: bool) -> int:
        """Inliers a tracked pose needs beyond the tracker's own `frontend.min_tracked`: blind
        (lost beyond what the prediction is worth), the tracker's recovery without a prior must
        convince at least as much as a place match (`health.recover_min_inliers`,
        `places.min_inliers`); else nothing more."""
        if not blind:
            return 0
        need = self.health.cfg.recover_min_inliers
        return max(need, self.places.min_inliers) if self.places is not None else need

    def plausible(self, t_ns: int, T_pred: F64, T_new: F64) -> Verdict:
        """`Health.motion` of a tracked or smoothed pose at `t_ns`."""
        T_last = self._T if self._T is not None else T_pred
        dt = ns_to_s(t_ns - (self._t if self._t is not None else t_ns))
        return self.health.motion(T_pred, T_last, dt, T_new)

    def decide(
        self, t_ns: int, T_pred: F64, imu_ok: bool, inertial: bool, T_last_output: F64 | None
    ) -> LostDecision:
        """What an untracked frame gets: the prediction (stereo-inertial: only an IMU
        prediction), no pose while relocalization goes on, or a reset (its hint: the prediction,
        or the last output pose where the prediction is not finite)."""
        verdict = self.verdict(t_ns, imu_ok)
        finite = bool(np.all(np.isfinite(T_pred)))
        bridged = not inertial or imu_ok
        if verdict.ok and finite and (bridged or self.places is None):
            return LostDecision(LostAction.BRIDGE)
        lost_s = self.lost_s(t_ns)
        if self.places is not None and finite and lost_s < self.places.relocalize_max_s:
            return LostDecision(LostAction.WAIT)
        reason = verdict.reason if not verdict.ok else "non-finite prediction"
        if self.places is not None and not verdict.ok:
            reason += f"; no place recognised for {lost_s:.1f} s"
        if finite and not bridged:
            # across an IMU dropout the prediction is no pose for this frame, only a place for
            # the next segment to start
            return LostDecision(LostAction.RESET, reason, T_pred, guess=False)
        return LostDecision(LostAction.RESET, reason, T_pred if finite else T_last_output)
