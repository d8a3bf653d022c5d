"""The SLAM pipeline's state machine: frames in, one `FrameOutput` per frame out.

Stages, each behind a typed record: extraction (`FeatureStream` -> `FrameFeatures`, in worker
processes) -> tracking (`StereoTracker` -> `FrontendResult`; corrections go back as one
`MapCorrection`) -> estimator (`KeyframeEstimator` -> `KeyframeUpdate`, `SegmentSolution`) ->
observers (`on_frame(frame, FrameOutput)`); place recognition (`PlaceStage`) sees every
keyframe and every lost frame.

States (`PipelineState`):

* **INIT**: no estimate yet (start, or after a reset): `startup.py`.
* **TRACKING**: per frame, the estimator predicts the pose from the latest keyframe state, the
  tracker tracks its local map from that prediction, keyframes go into the smoother (and the
  tracker adopts the smoothed pose and landmarks). The online pose of a frame is the smoothed
  state for keyframes and the tracker's pose otherwise. At each keyframe place recognition looks
  for a loop (and corrects the estimate when the drift is large) and, in a segment started after
  a reset, for a place of an earlier segment (then the segment joins that segment's world).
  With `frontend.track_every` N > 1 only every Nth frame is extracted and tracked; a frame
  between gets the IMU's motion since the last tracked frame as its pose.
* **LOST**: blank / missing images or failed tracking: the prediction bridges the frames while
  it is worth something (`health.max_lost_s` with the IMU, `max_lost_s_no_imu` without or
  across an IMU dropout); beyond, frames get no pose while every frame with images is matched
  against the map by appearance (relocalization) for up to `places.relocalize_max_s`. A smoother
  failure, NaN, out-of-bounds velocity/biases, or no relocalization in time reset the estimator:
  the segment ends (final batch) and a new one starts with a fresh initialisation.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np
from threadpoolctl import threadpool_limits

from eurocslam.backend.estimator import KeyframeEstimator
from eurocslam.backend.health import Health, Verdict
from eurocslam.backend.pose_graph import LoopEdge
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate, NavEstimate
from eurocslam.config import RunConfig, resolve_mode
from eurocslam.dataset.types import SequenceSource, has_imu
from eurocslam.errors import ConfigError
from eurocslam.frontend.extraction import SKIPPED, FrameFeatures
from eurocslam.frontend.stream import FeatureStream
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.frontend.types import FrontendResult, MapCorrection, TrackingState
from eurocslam.geometry import F64, inv_T
from eurocslam.maps.store import SavedMap
from eurocslam.memory import peak_rss_mb, usable_cores
from eurocslam.pipeline.places import (
    FrameBook,
    LoopFix,
    PlaceEvent,
    PlaceStage,
    yaw_and_translation,
)
from eurocslam.pipeline.records import (
    FrameObserver,
    FrameOutput,
    KeyframePath,
    PipelineState,
    RunResult,
)
from eurocslam.pipeline.segments import FrameRecord, Segment, assemble, extrapolate_last
from eurocslam.pipeline.session_map import MAP_SEGMENT, PriorMap, build_map, localized_after_s
from eurocslam.pipeline.startup import Startup
from eurocslam.pipeline.summary import IMU_BETWEEN, VO_BETWEEN, RunSummary


class SlamPipeline(Startup):
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
        self.features = FeatureStream(source.rig, self.cfg.frontend)
        self.stereo = self.features.extractor.geometry
        self.health = Health(self.cfg.health, self.cfg.inertial)
        self.tracker = StereoTracker(
            self.features.extractor.rectifier, self.cfg.frontend.for_mode(self.cfg.inertial)
        )
        self.frames = FrameBook()  # the world frame of each segment
        self.places = (
            PlaceStage.create(
                self.cfg.places,
                self.stereo,
                self.tracker.scale,
                self.stereo.fx * np.radians(self.cfg.frontend.track_radius_deg),
                self.frames,
                self._map_points,
            )
            if self.cfg.places.enabled
            else None
        )
        self._events_out = 0  # place events already handed to observers
        self.state = PipelineState.INIT
        self.segments: list[Segment] = []
        self.prior_map = prior_map
        if prior_map is not None:
            self._file_prior_map(prior_map)
        self._new_segment()
        self._last_pose: F64 | None = None
        self._last_good_t: int | None = None  # the last tracked frame ...
        self._last_good_T: F64 | None = None  # ... and its pose
        self._hint_T: F64 | None = None  # pose to restart from after a reset
        self._init_mode: str | None = None
        self._window: list[tuple[int, F64]] = []  # dynamic init: VO frames (t, T_world_body)
        self._online: list[tuple[int, F64, int]] = []  # (t, T in the segment's world, segment)

    # ---- segments -------------------------------------------------------------------------------
    @property
    def segment(self) -> Segment:
        return self.segments[-1]

    def _new_segment(self) -> None:
        self.segments.append(Segment(len(self.segments)))
        self.frames.new_segment()
        self.est = KeyframeEstimator(self.source.rig.imu, self.stereo, self.imu, self.cfg)
        self._nav: NavEstimate | None = None  # the latest keyframe's smoothed state
        self._kf_index = -1  # the latest keyframe's index in the segment
        self._n_active = 0  # landmarks in the smoother
        self._kf_path: list[tuple[int, F64]] = []  # keyframes: time, latest smoothed pose
        self._tracked_offset: F64 | None = None  # last tracked pose @ inv(its prediction)
        self._cov_sampled_t = -(1 << 62)  # the last keyframe whose covariance was sampled

    def _file_prior_map(self, prior: PriorMap) -> None:
        """The earlier map as segment 0 (no frames): its keyframes in the place database, its
        landmarks as that segment's map; the session starts as the next segment."""
        if self.places is None or not self.cfg.places.merge:
            raise ConfigError(
                "--map needs place recognition and merging (places.enabled, places.merge: true)"
            )
        prior.check(self.source.rig, self.places.vocabulary_id)
        seg = Segment(MAP_SEGMENT, solution=prior.solution())
        self.segments.append(seg)
        self.frames.new_segment()
        self.places.file_saved(prior.map.keyframes, MAP_SEGMENT)
        self.summary.prior_map = prior.summary()

    def saved_map(self) -> SavedMap | None:
        """The run's map for later sessions (after `run`); None without place recognition."""
        if self.places is None:
            return None

        def points_in_frame(segment: int, ids: np.ndarray) -> F64:
            C = self.frames.T_frame_seg[segment]
            return self._map_points(segment, ids) @ C[:3, :3].T + C[:3, 3]

        src, n = self.source, len(self.segments)
        return build_map(
            self.places, n, points_in_frame, self.prior_map, src.name, src.rig, self.cfg.mode
        )

    def _finish_segment(self) -> None:
        """Final batch over the segment's graph; the segment keeps the solution (and place
        recognition the keyframes' final poses)."""
        seg = self.segment
        if self._nav is None or not seg.records:
            return
        t0 = time.perf_counter()
        seg.solution = self.est.finish(seg.frame_refs())
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
        self._new_segment()
        self.state = PipelineState.INIT
        self._init_mode = None
        self._window = []
        self._hint_T = T_hint

    # ---- main loop ------------------------------------------------------------------------------
    def run(
        self,
        t_start_ns: int | None = None,
        t_end_ns: int | None = None,
        on_progress: Callable[[FrameOutput], None] | None = None,
    ) -> RunResult:
        # BLAS on this thread alone: its products are small (landmarks x 3, one pose's Jacobian)
        # and a second BLAS thread competes with the extraction workers for the cores, spinning
        # while it waits (V2_03: 6 s of 102 s CPU; the results are bit-identical)
        with threadpool_limits(limits=1, user_api="blas"):
            return self._run(t_start_ns, t_end_ns, on_progress)

    def _run(
        self,
        t_start_ns: int | None,
        t_end_ns: int | None,
        on_progress: Callable[[FrameOutput], None] | None,
    ) -> RunResult:
        wall0 = time.perf_counter()
        cpu0 = time.process_time()
        thread0 = time.thread_time()
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
        s = self.summary
        s.wall_s = time.perf_counter() - wall0
        s.cpu_s = time.process_time() - cpu0  # the workers' is added with their cost
        s.tracking_cpu_s = time.thread_time() - thread0
        s.cores = usable_cores()
        s.peak_rss_mb = peak_rss_mb()
        s.add_extraction_cost(self.features.cost)
        if t_first is not None and t_last is not None:
            s.duration_s = (t_last - t_first) * 1e-9 + 1.0 / max(self.source.rig.cam0.rate_hz, 1e-9)
        return self.result()

    def step(self, ff: FrameFeatures) -> FrameOutput:
        """Process one frame (features already extracted)."""
        s = self.summary
        s.frames += 1
        for k in ("decode", "rectify", "orb", "stereo_matching"):
            if k in ff.timings_ms:
                s.add_time(k, ff.timings_ms[k])
        if ff.problem == SKIPPED and self.state != PipelineState.LOST:
            out = self._between(ff.t_ns)  # lost, it is a frame without images
        elif self.state == PipelineState.INIT:
            out = self._step_init(ff)
        else:
            out = self._step_tracking(ff)
        if out.frontend is not None:
            s.landmarks_reused += out.frontend.n_reused
            if out.frontend.track_path:
                s.count_path(out.frontend.track_path)
            if "track_total" in out.frontend.timings_ms:
                s.add_time("tracking", out.frontend.timings_ms["track_total"])
        s.state_frames[out.state.value] = s.state_frames.get(out.state.value, 0) + 1
        if out.T_world_body is not None:
            s.frames_with_pose += 1
            self._last_pose = out.T_world_body
        return out

    def _between(self, t: int) -> FrameOutput:
        """A frame left out by `frontend.track_every`: the IMU's motion since the last tracked
        frame is its pose (across an IMU dropout, the estimator's constant velocity); in a
        dynamic start's VO window, the motion between its last two tracked frames."""
        if self.state == PipelineState.INIT:
            T_vo = extrapolate_last(self._window, t)
            if T_vo is not None:
                self.segment.records.append(FrameRecord(t, T_vo, -1))
            self.summary.count_path(VO_BETWEEN)
            return self._emit(t, PipelineState.INIT, T_vo, None, left_out=True)
        T = self.est.predict(t).T_world_body
        T = T if self._tracked_offset is None else self._tracked_offset @ T
        self.segment.records.append(FrameRecord(t, T, self._kf_index))
        self.summary.count_path(IMU_BETWEEN)
        return self._emit(t, PipelineState.TRACKING, T, None, self._nav, left_out=True)

    # ---- TRACKING / LOST ------------------------------------------------------------------------
    def _step_tracking(self, ff: FrameFeatures) -> FrameOutput:
        nav = self._nav
        assert nav is not None
        t = ff.t_ns
        pred = self.est.predict(t)
        if not self.cfg.inertial:
            # visual-only: constant velocity from the last two poses (the tracker's own model)
            seg = self.segment.index
            T_cv = extrapolate_last([(o[0], o[1]) for o in self._online[-2:] if o[2] == seg], t)
            T_cv = nav.T_world_body if T_cv is None else T_cv
            pred = NavEstimate(t, T_cv, pred.v_world, pred.bg, pred.ba)
        # blind for longer than the prediction is worth: no prior, no new map at it
        blind = self.state == PipelineState.LOST and not self._lost_verdict(t).ok
        since_kf = (t - nav.t_ns) * 1e-9
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
        # after a loss, the tracker's own recovery (no prior) must convince at least as much as
        # a place match; the tracker keeps nothing of a frame below that bar
        hc = self.cfg.health
        need = hc.min_tracked
        if blind:
            need = max(need, hc.recover_min_inliers)
            if self.places is not None:
                need = max(need, self.cfg.places.min_inliers)
        fr = self.tracker.track(ff, prior, kf_ok, may_restart=not blind, min_inliers=need)
        T = fr.T_world_body  # tracked (with `need` inliers), or None
        if T is not None and not blind and not self._plausible(t, pred.T_world_body, T).ok:
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
            self.segment.records.append(FrameRecord(t, T, self._kf_index))
            self.state = PipelineState.TRACKING
            self._last_good_t, self._last_good_T = t, T
            self._tracked_offset = T @ inv_T(pred.T_world_body)
            return self._emit(t, PipelineState.TRACKING, T, fr, nav)
        if self.places is not None and ff.problem is None and not blind:
            out = self._relocalize(ff, pred)
            if out is not None:
                return out
        # LOST: bridge with the prediction while it is worth something (stereo-inertial: only
        # an IMU prediction; across an IMU dropout there is none to give)
        verdict = self._lost_verdict(t)
        T = pred.T_world_body
        finite = bool(np.all(np.isfinite(T)))
        bridged = not self.cfg.inertial or self.est.imu_ok_since_keyframe()
        if verdict.ok and finite and (bridged or self.places is None):
            self.state = PipelineState.LOST
            self.segment.records.append(FrameRecord(t, T, self._kf_index))
            return self._emit(t, PipelineState.LOST, T, fr, nav)
        lost_s = (t - (self._last_good_t or t)) * 1e-9
        if self.places is not None and finite and lost_s < self.cfg.places.relocalize_max_s:
            self.state = PipelineState.LOST  # no pose; relocalization goes on
            return self._emit(t, PipelineState.LOST, None, fr, nav)
        reason = verdict.reason if not verdict.ok else "non-finite prediction"
        if self.places is not None and not verdict.ok:
            reason += f"; no place recognised for {lost_s:.1f} s"
        if finite and not bridged:
            # across an IMU dropout the prediction is no pose for this frame, only a place
            # for the next segment to start
            return self._fail(t, reason, T, fr, guess=False)
        return self._fail(t, reason, T if finite else self._last_pose, fr)

    def _lost_verdict(self, t: int) -> Verdict:
        lost_s = (t - (self._last_good_t or t)) * 1e-9
        return self.health.lost(lost_s, self.est.imu_ok_since_keyframe())

    def _relocalize(self, ff: FrameFeatures, pred: NavEstimate) -> FrameOutput | None:
        """A lost frame found in the map by appearance: a new local map there, a keyframe tied
        to the map by its pose."""
        assert self.places is not None
        ok = ff.stereo.valid
        uv = np.column_stack([ff.left.uv[ok, 0], ff.stereo.uR[ok], ff.left.uv[ok, 1]])
        view = self.places.view(ff.t_ns, uv, ff.left.desc[ok], octave=ff.left.octave[ok])
        T = self.places.relocalize(view, self.segment.index)
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
            upd = self.est.add_keyframe(
                t, fr.landmark_ids, fr.stereo_uv, fr.T_world_body, fr.stereo_sigma, pose_prior
            )
        except EstimatorFailure as e:
            return self._fail(t, str(e), pred.T_world_body, fr)
        self.summary.add_time("backend", (time.perf_counter() - t0) * 1e3)
        self._kf_index = upd.index
        T = upd.nav.T_world_body
        verdict = self.health.state(upd.nav)
        if verdict.ok and pose_prior is None:
            verdict = self._plausible(t, pred.T_world_body, T)
        if not verdict.ok:
            return self._fail(t, verdict.reason, pred.T_world_body, fr)
        b = self.cfg.backend
        if b.correct_whole_map:
            # the landmarks the smoother does not hold move rigidly with the keyframe's
            # correction, so the tracker's map stays in one frame (mixing corrected and
            # uncorrected points would bias its pose estimates between keyframes)
            self.tracker.apply(MapCorrection(T, T_new_old=T @ inv_T(fr.T_world_body)))
        if b.correct_landmarks:
            self.tracker.apply(MapCorrection(T, None, upd.landmark_ids, upd.landmark_xyz))
        else:
            self.tracker.apply(MapCorrection(T))
        return self._keyframe(t, upd, fr)

    def _keyframe(self, t: int, upd: KeyframeUpdate, fr: FrontendResult) -> FrameOutput:
        """A keyframe in the smoother: place recognition sees it (and may move the estimate),
        then the segment records it."""
        upd = self._place_keyframe(t, upd, fr)
        seg = self.segment
        T = upd.nav.T_world_body
        seg.kf_T_chain[upd.index] = T
        seg.records.append(FrameRecord(t, T, upd.index))
        self.state = PipelineState.TRACKING
        self._last_good_t, self._last_good_T = t, T
        self._tracked_offset = None  # the predictions start from this keyframe's state
        return self._keyframe_out(t, upd, fr)

    def _place_keyframe(self, t: int, upd: KeyframeUpdate, fr: FrontendResult) -> KeyframeUpdate:
        """Merge (a segment after a reset) or loop closure at this keyframe, then file it."""
        if self.places is None:
            return upd
        p, seg = self.places, self.segment.index
        for k, T in upd.window:
            p.update_pose(seg, k, T)
        view = p.view(t, fr.stereo_uv, fr.descriptors, p.new_key(), fr.landmark_ids, fr.octaves)
        if p.merge(view, seg, upd.nav.T_world_body) is None:
            fix = p.loop(view, seg, upd.nav.T_world_body, self.est.pose_covariance, upd.index)
            if fix is not None:
                upd = self._close_loop(fix, upd)
        # the estimator's uncertainty, sampled for the loop gate (`PlaceStage.loop`)
        cov = None
        if (t - self._cov_sampled_t) * 1e-9 >= self.cfg.places.loop_covariance_every_s:
            cov = self.est.pose_covariance()
            self._cov_sampled_t = t
        p.file(view, seg, upd.index, upd.nav.T_world_body, cov)
        return upd

    def _close_loop(self, fix: LoopFix, upd: KeyframeUpdate) -> KeyframeUpdate:
        """Move the online estimate onto the map it has come back to (`fix.D`): the smoother
        starts again from the moved state, the tracker's map moves with it, and the segment's
        final batch gets the loop edge when the recognised keyframe is in this segment."""
        assert self.places is not None
        ref = self.frames.keyframes[fix.match.key]
        edge = (
            LoopEdge(ref.index, upd.index, fix.T_cand_query)
            if ref.segment == self.segment.index
            else None
        )
        D = fix.D
        if self.cfg.inertial:  # roll and pitch are observed: the loop moves yaw and position
            D = yaw_and_translation(D, upd.nav.T_world_body[:3, 3])
        try:
            moved = self.est.reanchor(D, edge, fix.cov_after)
        except EstimatorFailure:
            return upd  # the estimate stays where it was; map reuse may still close the loop
        self.tracker.apply(MapCorrection(moved.nav.T_world_body, T_new_old=D))
        return moved

    def _map_points(self, segment: int, ids: np.ndarray) -> F64:
        """The map's positions (N, 3) of landmarks by id in a segment's world (NaN: unknown):
        the smoother's latest estimates in the running segment, the final batch's in an
        ended one."""
        if segment == self.segment.index and self.segment.solution is None:
            return self.est.landmark_positions(ids)
        return self.segments[segment].landmark_positions(ids)

    def _plausible(self, t: int, T_pred: F64, T_new: F64) -> Verdict:
        """`Health.motion` of a tracked or smoothed pose at `t`."""
        T_last = self._last_good_T if self._last_good_T is not None else T_pred
        dt = (t - (self._last_good_t if self._last_good_t is not None else t)) * 1e-9
        return self.health.motion(T_pred, T_last, dt, T_new)

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
            self.segment.records.append(FrameRecord(t, T_out, max(self._kf_index, 0)))
        self._reset(t, reason, T_start)
        return self._emit(t, PipelineState.LOST, T_out, fr, segment=seg_index, reset_reason=reason)

    # ---- outputs --------------------------------------------------------------------------------
    def _keyframe_out(self, t: int, upd: KeyframeUpdate, fr: FrontendResult) -> FrameOutput:
        """A keyframe's output: the smoother's state, path and landmarks after the update."""
        self._nav = upd.nav
        self._kf_index = upd.index
        self._n_active = len(upd.landmark_ids)
        self._kf_path.append((t, upd.nav.T_world_body))
        for k, T in upd.window:
            if 0 <= k < len(self._kf_path):
                self._kf_path[k] = (self._kf_path[k][0], T)
        path = KeyframePath(
            np.array([p[0] for p in self._kf_path], dtype=np.int64),
            np.array([p[1] for p in self._kf_path]),
        )
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
        """One frame's output, in the world frame its segment is in (`T`, the path and the
        landmarks are in the segment's own world; a merged segment's are moved)."""
        seg = self.segment.index if segment is None else segment
        if T is not None:
            self._online.append((t, T, seg))
        C = self.frames.T_frame_seg[seg]
        if not np.array_equal(C, np.eye(4)):
            T = None if T is None else C @ T
            if path is not None:
                path = KeyframePath(path.t_ns, C @ path.T_world_body)
            if landmarks is not None:
                landmarks = landmarks @ C[:3, :3].T + C[:3, 3]
        events: tuple[PlaceEvent, ...] = ()
        if self.places is not None and len(self.places.events) > self._events_out:
            events = tuple(self.places.events[self._events_out :])
            self._events_out = len(self.places.events)
        return FrameOutput(
            t,
            state,
            T,
            seg,
            path is not None,
            fr,
            nav,
            reset_reason,
            n_keyframes=self._kf_index + 1 if segment is None else 0,
            n_resets=len(self.summary.resets),
            n_active_landmarks=self._n_active if segment is None else 0,
            keyframe_path=path,
            landmarks=landmarks,
            frame=self.frames.frame_of[seg],
            places=events,
            left_out=left_out,
        )

    def result(self) -> RunResult:
        s = self.summary
        s.segments = sum(1 for seg in self.segments if seg.records)
        book = self.frames
        if self.places is not None:
            self.places.refine_frames()
        final = assemble(self.segments, book.frame_of, book.T_frame_seg)
        s.landmarks = len(final.landmarks)
        if self.places is not None:
            s.places = list(self.places.events)
            s.place_db = self.places.stats()
        if self.prior_map is not None:
            starts = [seg.records[0].t_ns for seg in self.segments if seg.records]
            s.prior_map["localized_after_s"] = localized_after_s(starts, self.places, book.frame_of)
        on_t = np.array([o[0] for o in self._online], dtype=np.int64)
        on_T = np.array([book.T_frame_seg[o[2]] @ o[1] for o in self._online]).reshape(-1, 4, 4)
        on_s = np.array([book.frame_of[o[2]] for o in self._online], dtype=np.int64)
        return RunResult(
            on_t,
            on_T,
            on_s,
            final.t_ns,
            final.T,
            final.segment,
            final.landmarks,
            final.landmark_segment,
            s,
        )
