"""The SLAM pipeline's state machine: frames in, one `FrameOutput` per frame out.

Stages, each behind a typed record: extraction (`FeatureStream` -> `FrameFeatures`, in worker
processes) -> tracking (`StereoTracker` -> `FrontendResult`; corrections go back as one
`MapCorrection`) -> estimator (`KeyframeEstimator` -> `KeyframeUpdate`, `SegmentSolution`) ->
observers (`on_frame(frame, FrameOutput)`); place recognition (`PlaceStage`) sees every
keyframe and every lost frame.

States (`PipelineState`): **INIT** (no estimate yet: `startup.py`), **TRACKING** (the
prediction seeds the tracker, keyframes go into the smoother and past place recognition, the
tracker takes one correction per keyframe; with `frontend.track_every` N > 1 a frame between
tracked ones gets the IMU's motion), **LOST** (bridged, waiting for relocalization, or reset:
`recovery.py`). docs/architecture.md describes each.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np
from threadpoolctl import threadpool_limits

from eurocslam.backend.estimator import KeyframeEstimator
from eurocslam.backend.health import Health
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate, NavEstimate
from eurocslam.config import RunConfig, resolve_mode
from eurocslam.dataset.types import SequenceSource, has_imu
from eurocslam.errors import ConfigError
from eurocslam.frontend.extraction import Extractor, FrameFeatures, FrameProblem
from eurocslam.frontend.projection import pyramid_scales
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.frontend.stream import FeatureStream
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.frontend.types import FrontendResult, MapCorrection, TrackingState, TrackPath
from eurocslam.geometry import F64, inv_T
from eurocslam.maps.store import SavedMap
from eurocslam.pipeline.active import ActiveSegment
from eurocslam.pipeline.frames import WorldFrames
from eurocslam.pipeline.outputs import RunOutputs, RunResult
from eurocslam.pipeline.places import PlaceStage
from eurocslam.pipeline.records import (
    FrameObserver,
    FrameOutput,
    KeyframePath,
    PipelineState,
)
from eurocslam.pipeline.recovery import LostAction, Recovery
from eurocslam.pipeline.segments import Segment
from eurocslam.pipeline.session_map import MAP_SEGMENT, PriorMap, build_map, localized_after_s
from eurocslam.pipeline.startup import Startup
from eurocslam.pipeline.summary import RunSummary
from eurocslam.timebase import ns_to_s


class SlamPipeline:
    """Stereo-inertial or visual-only SLAM over a `SequenceSource` (`cfg.mode`; `auto` is
    resolved against the source's IMU)."""

    def __init__(
        self,
        source: SequenceSource,
        cfg: RunConfig | None = None,
        *,
        observers: Iterable[FrameObserver] = (),
        prior_map: PriorMap | None = None,
    ) -> None:
        """`prior_map`: an earlier session's map to localize in and map on (session_map.py);
        a map this run cannot use is a one-line `MapError`."""
        self.source = source
        self.cfg = resolve_mode(cfg or RunConfig(), has_imu(source), source.name)
        self.observers = list(observers)
        self.imu = source.imu
        self.summary = RunSummary(sequence=source.name, mode=self.cfg.mode)
        fc = self.cfg.frontend
        rectifier = StereoRectifier.for_config(source.rig, fc)  # the rectified rig, built once
        self.stereo = rectifier.geometry
        self.features = FeatureStream(Extractor(rectifier, fc))
        self.health = Health(self.cfg.health, self.cfg.inertial)
        self.recovery = Recovery(self.health, self.cfg.places if self.cfg.places.enabled else None)
        self.tracker = StereoTracker(rectifier, fc.for_mode(self.cfg.inertial))
        self.frames = WorldFrames()  # the world frame of each segment
        self.places = (
            PlaceStage.create(
                self.cfg.places,
                self.stereo,
                pyramid_scales(fc),
                self.stereo.fx * np.radians(fc.track_radius_deg),
                self.frames,
                self._map_points,
            )
            if self.cfg.places.enabled
            else None
        )
        self.outputs = RunOutputs(self.frames)
        self.state = PipelineState.INIT
        self.segments: list[Segment] = []
        self.prior_map = prior_map
        if prior_map is not None:
            self._file_prior_map(prior_map)
        self._new_segment()
        self._last_pose: F64 | None = None

    # ---- segments -------------------------------------------------------------------------------
    @property
    def segment(self) -> Segment:
        return self.segments[-1]

    def _new_segment(self, T_hint: F64 | None = None) -> None:
        """A new segment, started by a new `Startup` from `T_hint` (None: the origin)."""
        self.segments.append(Segment(len(self.segments)))
        self.frames.new_segment()
        self.live = ActiveSegment(
            self.segments[-1],
            Startup(self.cfg, self.imu, self.source.rig, T_hint),
            KeyframeEstimator(self.source.rig.imu, self.stereo, self.imu, self.cfg),
        )

    def _file_prior_map(self, prior: PriorMap) -> None:
        """The earlier map as segment 0 (no frames): its keyframes in the place database, its
        landmarks as that segment's map; the session starts as the next segment."""
        if self.places is None or not self.cfg.places.merge:
            raise ConfigError(
                "--map needs place recognition and merging (places.enabled, places.merge: true)"
            )
        prior.check(self.source.rig, self.places.vocabulary_id)
        self.segments.append(prior.segment())
        self.frames.new_segment()
        self.places.file_saved(prior.map.keyframes, MAP_SEGMENT)
        self.summary.prior_map = prior.summary()

    def saved_map(self) -> SavedMap | None:
        """The run's map for later sessions (after `run`); None without place recognition."""
        if self.places is None:
            return None
        return build_map(
            self.places,
            len(self.segments),
            lambda seg, ids: self.frames.to_frame(seg, self._map_points(seg, ids)),
            self.prior_map,
            self.source.name,
            self.source.rig,
            self.cfg.mode,
        )

    def _finish_segment(self) -> None:
        """Final batch over the segment's graph; the segment keeps the solution (and place
        recognition the keyframes' final poses)."""
        seg = self.segment
        if self.live.nav is None or not seg.records:
            return
        t0 = time.perf_counter()
        seg.solution = self.live.est.finish(seg.frame_refs())
        if seg.solution.imu_check is not None:
            self.summary.imu_checks.append(seg.solution.imu_check)
        self.summary.add_time("final_batch", (time.perf_counter() - t0) * 1e3)
        self.summary.keyframes += len(seg.solution.keyframes)
        if self.places is not None:
            for k, T in seg.solution.keyframes.items():
                self.places.update_pose(seg.index, k, T)

    def _reset(self, t_ns: int, reason: str, T_hint: F64 | None) -> None:
        self.summary.resets.append((t_ns, reason))
        self._finish_segment()
        self.tracker = self.tracker.restarted()
        self._new_segment(T_hint)
        self.state = PipelineState.INIT

    # ---- main loop ------------------------------------------------------------------------------
    def run(
        self,
        t_start_ns: int | None = None,
        t_end_ns: int | None = None,
        on_progress: Callable[[FrameOutput], None] | None = None,
    ) -> RunResult:
        # BLAS on this thread alone: its products are small (landmarks x 3, one pose's Jacobian)
        # and a second BLAS thread competes with the extraction workers for the cores, spinning
        # while it waits
        with threadpool_limits(limits=1, user_api="blas"):
            return self._run(t_start_ns, t_end_ns, on_progress)

    def _run(
        self,
        t_start_ns: int | None,
        t_end_ns: int | None,
        on_progress: Callable[[FrameOutput], None] | None,
    ) -> RunResult:
        self.summary.start_clock()
        frames = self.source.frames(
            include_incomplete=True, t_start_ns=t_start_ns, t_end_ns=t_end_ns
        )
        t_first = t_last = None
        for frame, ff in self.features(frames):
            if t_first is None:
                t_first = frame.t_ns
            t_last = frame.t_ns
            out = self.step(ff)
            t0 = time.perf_counter()
            for ob in self.observers:
                ob.on_frame(frame, out)
            self.summary.add_time("output", (time.perf_counter() - t0) * 1e3)
            if on_progress is not None:
                on_progress(out)
        self._finish_segment()
        span_s = None
        if t_first is not None and t_last is not None:
            span_s = ns_to_s(t_last - t_first) + 1.0 / max(self.source.rig.cam0.rate_hz, 1e-9)
        self.summary.stop_clock(self.features.cost, span_s)
        return self.result()

    def step(self, ff: FrameFeatures) -> FrameOutput:
        """Process one frame (features already extracted)."""
        self.summary.count_frame(ff.timings_ms)
        if ff.problem == FrameProblem.SKIPPED and self.state != PipelineState.LOST:
            out = self._between(ff.t_ns)  # lost, it is a frame without images
        elif self.state == PipelineState.INIT:
            out = self._step_init(ff)
        else:
            out = self._step_tracking(ff)
        self.summary.count_output(out)
        if out.T_world_body is not None:
            self._last_pose = out.T_world_body
        return out

    def _between(self, t: int) -> FrameOutput:
        """A frame left out by `frontend.track_every`: the IMU's motion since the last tracked
        frame is its pose (across an IMU dropout, the estimator's constant velocity); in a
        dynamic start's VO window, the motion between its last two tracked frames."""
        if self.state == PipelineState.INIT:
            T_vo = self.live.startup.between(t)
            if T_vo is not None:
                self.live.record(t, T_vo, -1)
            self.summary.count_path(TrackPath.VO_BETWEEN)
            return self._emit(t, PipelineState.INIT, T_vo, None, left_out=True)
        T = self.live.between(t)
        self.live.record(t, T)
        self.summary.count_path(TrackPath.IMU_BETWEEN)
        return self._emit(t, PipelineState.TRACKING, T, None, self.live.nav, left_out=True)

    # ---- INIT -----------------------------------------------------------------------------------
    def _step_init(self, ff: FrameFeatures) -> FrameOutput:
        t = ff.t_ns
        st = self.live.startup.step(ff, self.tracker, self.live.est, self.segment)
        if st.failure:
            self._reset(t, st.failure, self.live.startup.hint)
            return self._emit(t, PipelineState.INIT, None, st.fr)
        if st.started is None:
            return self._emit(t, PipelineState.INIT, st.T_world_body, st.fr)
        assert st.mode is not None and st.fr is not None
        self.summary.init_modes.append(st.mode.value)
        nav = st.started.nav
        # the tracker's map, still in the VO window's frame after a dynamic start, moves into
        # the world with the first keyframe
        correction = MapCorrection(nav.T_world_body, T_new_old=st.T_world_vo)
        return self._keyframe(nav.t_ns, st.started, st.fr, correction)

    # ---- TRACKING / LOST ------------------------------------------------------------------------
    def _step_tracking(self, ff: FrameFeatures) -> FrameOutput:
        nav = self.live.nav
        assert nav is not None
        t = ff.t_ns
        recent = [] if self.cfg.inertial else self.outputs.last_online(self.segment.index, 2)
        pred = self.live.predict(t, self.cfg.inertial, recent)
        # blind for longer than the prediction is worth: no prior, no new map at it
        imu_ok = self.live.est.imu_ok_since_keyframe()
        blind = self.state == PipelineState.LOST and not self.recovery.verdict(t, imu_ok).ok
        since_kf = ns_to_s(t - nav.t_ns)
        bc = self.cfg.backend
        kf_ok = since_kf >= bc.min_keyframe_interval_s
        prior = pred.T_world_body if self.cfg.inertial and not blind else None
        if blind and self.places is not None and ff.problem is None:
            # a place recognised by appearance first: its match is selected by the words the
            # frame shares with one keyframe and verified against that keyframe's points; the
            # tracker's own search of its whole local map is the fallback (on a rendered
            # blackout it accepted a pose 1.5 m off with 41 inliers)
            out = self._relocalize(ff, pred)
            if out is not None:
                return out
        # the tracker keeps nothing of a frame below the bar
        need = self.recovery.min_inliers(blind)
        fr = self.tracker.track(ff, prior, kf_ok, may_restart=not blind, min_inliers=need)
        T = fr.T_world_body  # tracked (with `need` inliers), or None
        if T is not None and not blind and not self.recovery.plausible(t, pred.T_world_body, T).ok:
            T = None
            self.tracker.apply(MapCorrection(pred.T_world_body))
        if T is not None:
            need_kf = (
                fr.is_keyframe
                or fr.state == TrackingState.INIT
                or self.state == PipelineState.LOST
                or since_kf >= bc.max_keyframe_interval_s
            )
            if need_kf:
                return self._add_keyframe(t, fr, pred, T if blind else None)
            self.live.record(t, T)
            self.state = PipelineState.TRACKING
            self.recovery.trusted(t, T)
            self.live.tracked_offset = T @ inv_T(pred.T_world_body)
            return self._emit(t, PipelineState.TRACKING, T, fr, nav)
        if self.places is not None and ff.problem is None and not blind:
            out = self._relocalize(ff, pred)
            if out is not None:
                return out
        # LOST (`recovery.py`)
        T = pred.T_world_body
        imu_ok = self.live.est.imu_ok_since_keyframe()
        lost = self.recovery.decide(t, T, imu_ok, self.cfg.inertial, self._last_pose)
        if lost.action == LostAction.BRIDGE:
            self.state = PipelineState.LOST
            self.live.record(t, T)
            return self._emit(t, PipelineState.LOST, T, fr, nav)
        if lost.action == LostAction.WAIT:
            self.state = PipelineState.LOST  # no pose; relocalization goes on
            return self._emit(t, PipelineState.LOST, None, fr, nav)
        return self._fail(t, lost.reason, lost.T_hint, fr, guess=lost.guess)

    def _relocalize(self, ff: FrameFeatures, pred: NavEstimate) -> FrameOutput | None:
        """A lost frame found in the map by appearance: a new local map there, a keyframe tied
        to the map by its pose."""
        assert self.places is not None
        found = self.places.relocalize(self.places.frame_view(ff), self.segment.index)
        self.outputs.add_events(found.events)
        T = found.T_seg_query
        if T is None:
            return None
        fr = self.tracker.restart_map(ff, T)
        if fr.T_world_body is None:
            return None
        return self._add_keyframe(ff.t_ns, fr, pred, fr.T_world_body)

    def _add_keyframe(
        self, t: int, fr: FrontendResult, pred: NavEstimate, pose_prior: F64 | None = None
    ) -> FrameOutput:
        """`pose_prior`: the frame was found in the map after a loss (relocalization); it ties
        the keyframe to the map, and no prediction judges it."""
        assert fr.T_world_body is not None
        t0 = time.perf_counter()
        try:
            upd = self.live.est.add_keyframe(
                t, fr.landmark_ids, fr.stereo_uv, fr.T_world_body, fr.stereo_sigma, pose_prior
            )
        except EstimatorFailure as e:
            return self._fail(t, str(e), pred.T_world_body, fr)
        self.summary.add_time("backend", (time.perf_counter() - t0) * 1e3)
        self.live.kf_index = upd.index
        T = upd.nav.T_world_body
        verdict = self.health.state(upd.nav)
        if verdict.ok and pose_prior is None:
            verdict = self.recovery.plausible(t, pred.T_world_body, T)
        if not verdict.ok:
            return self._fail(t, verdict.reason, pred.T_world_body, fr)
        b = self.cfg.backend
        # the landmarks the smoother does not hold move rigidly with the keyframe's correction,
        # so the tracker's map stays in one frame (mixing corrected and uncorrected points would
        # bias its pose estimates between keyframes); those it holds take its positions
        correction = MapCorrection(
            T,
            T @ inv_T(fr.T_world_body) if b.correct_whole_map else None,
            upd.landmark_ids if b.correct_landmarks else None,
            upd.landmark_xyz if b.correct_landmarks else None,
        )
        return self._keyframe(t, upd, fr, correction)

    def _keyframe(
        self, t: int, upd: KeyframeUpdate, fr: FrontendResult, correction: MapCorrection
    ) -> FrameOutput:
        """A keyframe in the smoother: place recognition sees it (and may move the estimate),
        the tracker takes the keyframe's correction (one record), the segment records it."""
        upd, correction = self._place_keyframe(t, upd, fr, correction)
        self.tracker.apply(correction)
        seg = self.segment
        T = upd.nav.T_world_body
        seg.kf_T_chain[upd.index] = T
        self.live.record(t, T, upd.index)
        self.state = PipelineState.TRACKING
        self.recovery.trusted(t, T)
        self.live.tracked_offset = None  # the predictions start from this keyframe's state
        return self._keyframe_out(t, upd, fr)

    def _place_keyframe(
        self, t: int, upd: KeyframeUpdate, fr: FrontendResult, correction: MapCorrection
    ) -> tuple[KeyframeUpdate, MapCorrection]:
        """Merge (a segment after a reset) or loop closure at this keyframe
        (`ActiveSegment.close_loop`), then file it; a loop closed moves the keyframe's
        correction too."""
        if self.places is None:
            return upd, correction
        p, seg, inertial = self.places, self.segment.index, self.cfg.inertial
        for k, T in upd.window:
            p.update_pose(seg, k, T)
        view = p.keyframe_view(t, fr)
        merged = p.merge(view, seg, upd.nav.T_world_body)
        self.outputs.add_events(merged.events)
        if merged.merge is not None:
            self.frames.merge(seg, *merged.merge)
        else:
            loop = p.loop(
                view, seg, upd.nav.T_world_body, self.live.est.pose_covariance, upd.index, inertial
            )
            self.outputs.add_events(loop.events)
            closed = None if loop.loop is None else self.live.close_loop(loop.loop, upd, inertial)
            if closed is not None:  # the estimate moved; the tracker's map moves with it
                upd, D = closed
                correction = correction.then_move(D, upd.nav.T_world_body)
        # the estimator's uncertainty, sampled for the loop gate (`PlaceStage.loop`)
        cov = None
        if self.live.covariance_due(t, self.cfg.places.loop_covariance_every_s):
            cov = self.live.est.pose_covariance()
        p.file(view, seg, upd.index, upd.nav.T_world_body, cov)
        return upd, correction

    def _map_points(self, segment: int, ids: np.ndarray) -> F64:
        """The map's positions (N, 3) of landmarks by id in a segment's world (NaN: unknown):
        the smoother's latest estimates in the running segment, the final batch's in an
        ended one."""
        if segment == self.segment.index and self.segment.solution is None:
            return self.live.est.landmark_positions(ids)
        return self.segments[segment].landmark_positions(ids)

    def _fail(
        self,
        t: int,
        reason: str,
        T_hint: F64 | None,
        fr: FrontendResult | None,
        guess: bool = True,
    ) -> FrameOutput:
        """Reset: end the segment; the next one starts at `T_hint`, and this frame gets it as
        its pose (the last trusted estimate) unless it is only a `guess=False`."""
        seg_index = self.segment.index
        ok_hint = T_hint is not None and np.all(np.isfinite(T_hint))
        T_start = T_hint if ok_hint else None
        T_out = T_start if guess else None
        if T_out is not None:
            self.live.record(t, T_out, max(self.live.kf_index, 0))
        self._reset(t, reason, T_start)
        return self._emit(t, PipelineState.LOST, T_out, fr, segment=seg_index, reset_reason=reason)

    # ---- outputs --------------------------------------------------------------------------------
    def _keyframe_out(self, t: int, upd: KeyframeUpdate, fr: FrontendResult) -> FrameOutput:
        """A keyframe's output: the smoother's state, path and landmarks after the update."""
        path = self.live.keyframe(t, upd)
        return self._emit(
            t, PipelineState.TRACKING, upd.nav.T_world_body, fr, upd.nav, path, upd.landmark_xyz
        )

    def _emit(
        self,
        t: int,
        state: PipelineState,
        T: F64 | None,
        fr: FrontendResult | None,
        nav: NavEstimate | None = None,
        path: KeyframePath | None = None,
        landmarks: F64 | None = None,
        *,
        segment: int | None = None,
        reset_reason: str = "",
        left_out: bool = False,
    ) -> FrameOutput:
        """One frame's output (`segment`: a segment that has just ended, else the running one)."""
        ended = segment is not None
        return self.outputs.frame(
            t,
            state,
            T,
            self.segment.index if segment is None else segment,
            fr,
            nav,
            path,
            landmarks,
            reset_reason=reset_reason,
            left_out=left_out,
            n_keyframes=0 if ended else self.live.kf_index + 1,
            n_resets=len(self.summary.resets),
            n_active_landmarks=0 if ended else self.live.n_active,
        )

    def result(self) -> RunResult:
        s = self.summary
        s.segments = sum(1 for seg in self.segments if seg.records)
        if self.places is not None:
            for seg, T_frame_seg in self.places.refined_frames().items():
                self.frames.place(seg, T_frame_seg)
        res = self.outputs.result(self.segments, s)
        s.landmarks = len(res.landmarks)
        if self.places is not None:
            s.places = list(self.outputs.events)
            s.place_db = self.places.stats()
        if self.prior_map is not None:
            starts = [seg.records[0].t_ns for seg in self.segments if seg.records]
            s.prior_map["localized_after_s"] = localized_after_s(
                starts, self.outputs.events, self.frames
            )
        return res
