"""The running segment: what the pipeline keeps about the segment it is extending.

Its frames (`Segment`), how it starts (`Startup`), its estimator, and the latest keyframe: the
smoothed state the predictions start from, the keyframe index frames hang from, the keyframes'
latest smoothed poses (the keyframe path of the outputs). A reset ends it; the next segment gets
a new one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from eurocslam.backend.estimator import KeyframeEstimator
from eurocslam.backend.pose_graph import LoopEdge
from eurocslam.backend.propagator import visual_pose
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate, NavEstimate
from eurocslam.geometry import F64
from eurocslam.pipeline.places import LoopFix
from eurocslam.pipeline.records import KeyframePath
from eurocslam.pipeline.segments import FrameRecord, Segment
from eurocslam.pipeline.startup import Startup
from eurocslam.places.loop_gate import yaw_and_translation
from eurocslam.timebase import ns_to_s


@dataclass
class ActiveSegment:
    segment: Segment
    startup: Startup
    est: KeyframeEstimator
    nav: NavEstimate | None = None  # the latest keyframe's smoothed state
    kf_index: int = -1  # the latest keyframe's index in the segment
    n_active: int = 0  # landmarks in the smoother
    tracked_offset: F64 | None = None  # last tracked pose @ inv(its prediction)
    cov_sampled_t: int = -(1 << 62)  # the last keyframe whose covariance was sampled
    kf_path: list[tuple[int, F64]] = field(default_factory=list)  # time, latest smoothed pose

    def predict(self, t_ns: int, inertial: bool, recent: list[tuple[int, F64]]) -> NavEstimate:
        """The state a frame is expected in: with the IMU, preintegrated from the latest
        keyframe's (the estimator's `predict`); visual-only, the pose at constant velocity from
        the segment's last two output poses (`recent`; the keyframe's before there are two)."""
        pred = self.est.predict(t_ns)
        if inertial:
            return pred
        assert self.nav is not None
        T_cv = visual_pose(recent, t_ns, self.nav.T_world_body)
        return NavEstimate(t_ns, T_cv, pred.v_world, pred.bg, pred.ba)

    def between(self, t_ns: int) -> F64:
        """The pose of a frame left out by `track_every`: the IMU's motion since the last
        tracked frame (across an IMU dropout, the estimator's constant velocity)."""
        T = self.est.predict(t_ns).T_world_body
        return T if self.tracked_offset is None else self.tracked_offset @ T

    def record(self, t_ns: int, T_world_body: F64, ref_kf: int | None = None) -> None:
        """A frame of the segment, hanging from the latest keyframe (or `ref_kf`)."""
        ref = self.kf_index if ref_kf is None else ref_kf
        self.segment.records.append(FrameRecord(t_ns, T_world_body, ref))

    def covariance_due(self, t_ns: int, every_s: float) -> bool:
        """Time to sample the estimator's covariance again (and note that it is sampled)."""
        if ns_to_s(t_ns - self.cov_sampled_t) < every_s:
            return False
        self.cov_sampled_t = t_ns
        return True

    def keyframe(self, t_ns: int, upd: KeyframeUpdate) -> KeyframePath:
        """A keyframe's update taken: the latest state, and the keyframe path with the smoother's
        window refreshed."""
        self.nav = upd.nav
        self.kf_index = upd.index
        self.n_active = len(upd.landmark_ids)
        self.kf_path.append((t_ns, upd.nav.T_world_body))
        for k, T in upd.window:
            if 0 <= k < len(self.kf_path):
                self.kf_path[k] = (self.kf_path[k][0], T)
        return KeyframePath(
            np.array([p[0] for p in self.kf_path], dtype=np.int64),
            np.array([p[1] for p in self.kf_path]),
        )

    def close_loop(
        self, fix: LoopFix, upd: KeyframeUpdate, inertial: bool
    ) -> tuple[KeyframeUpdate, F64] | None:
        """Move the estimate at keyframe `upd` onto the map it has come back to (`fix.D`; with
        an IMU, roll and pitch are observed: yaw and position only): the smoother starts again
        from the moved state, and the segment's final batch gets the loop edge when the
        recognised keyframe is in this segment. The moved keyframe and the move; None when the
        estimator cannot move."""
        edge = (
            LoopEdge(fix.cand_index, upd.index, fix.T_cand_query)
            if fix.cand_segment == self.segment.index
            else None
        )
        D = yaw_and_translation(fix.D, upd.nav.T_world_body[:3, 3]) if inertial else fix.D
        try:
            return self.est.reanchor(D, edge, fix.cov_after), D
        except EstimatorFailure:
            return None
