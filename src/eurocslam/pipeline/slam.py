"""The SLAM pipeline's state machine: frames in, one `FrameOutput` per frame out.

Stages, each behind a typed record: extraction (`FeatureStream`: `StereoFrame` ->
`FrameFeatures`, in worker processes) -> tracking (`StereoTracker.track` -> `FrontendResult`;
corrections go back as one `MapCorrection`) -> estimator (`KeyframeEstimator`: `KeyframeUpdate`
per keyframe, `SegmentSolution` per segment) -> observers (`on_frame(frame, FrameOutput)`).
The mode (stereo-inertial or visual-only) is the configuration's, resolved once.

States (`PipelineState`):

* **INIT**: no estimate yet (start, or after a reset). The initialisation kind is chosen from
  the IMU around the current frame: *static* (still: attitude and gyro bias from the IMU mean,
  the estimator starts at once) or *dynamic* (moving: the tracker runs as stereo VO for
  `init.dynamic_window_s`, then VO and preintegrated IMU are aligned for gravity, velocity and
  biases). Poses are output from the first frame on in both cases; during a dynamic window they
  come from VO in a frame levelled by the mean accelerometer reading. Visual-only starts at
  once, in `init`'s mounting attitude.
* **TRACKING**: per frame, the estimator predicts the pose from the latest keyframe state, the
  tracker tracks its local map from that prediction, keyframes go into the smoother (and the
  tracker adopts the smoothed pose and landmarks). The online pose of a frame is the smoothed
  state for keyframes and the tracker's pose otherwise.
* **LOST**: blank / missing images or failed tracking: the prediction bridges the frames.
  Too long without vision (`health.max_lost_s`), an IMU dropout while blind, a smoother
  failure, NaN, or out-of-bounds velocity/biases reset the estimator: the segment ends (final
  batch) and a new one starts with a fresh initialisation.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np

from eurocslam.backend.estimator import KeyframeEstimator
from eurocslam.backend.health import Health, Verdict
from eurocslam.backend.initializer import (
    InitialState,
    choose_mode,
    dynamic_init,
    gravity_aligned_rotation,
    static_init,
    static_window,
)
from eurocslam.backend.preintegration import make_params
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate, NavEstimate
from eurocslam.config import RunConfig, resolve_mode
from eurocslam.dataset.types import SequenceSource, has_imu
from eurocslam.frontend.extraction import FrameFeatures
from eurocslam.frontend.stream import FeatureStream
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.frontend.types import FrontendResult, MapCorrection, TrackingState
from eurocslam.geometry import F64, inv_T, make_T, so3_exp, so3_log
from eurocslam.memory import peak_rss_mb
from eurocslam.pipeline.records import (
    FrameObserver,
    FrameOutput,
    KeyframePath,
    PipelineState,
    RunResult,
)
from eurocslam.pipeline.segments import FrameRecord, Segment, assemble
from eurocslam.pipeline.summary import RunSummary, cpu_seconds

# an optical camera (x right, y down, z forward) held level, looking along world x (z up)
R_WORLD_CAM_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class SlamPipeline:
    """Stereo-inertial or visual-only SLAM over a `SequenceSource` (`cfg.mode`; `auto` is
    resolved against the source's IMU)."""

    def __init__(
        self,
        source: SequenceSource,
        cfg: RunConfig | None = None,
        *,
        observers: Iterable[FrameObserver] = (),
    ) -> None:
        self.source = source
        self.cfg = resolve_mode(cfg or RunConfig(), has_imu(source), source.name)
        self.observers = list(observers)
        self.imu = source.imu
        self.summary = RunSummary(sequence=source.name, mode=self.cfg.mode)
        self.features = FeatureStream(source.rig, self.cfg.frontend)
        self.stereo = self.features.extractor.geometry
        self.health = Health(self.cfg.health, self.cfg.inertial)
        self.tracker = StereoTracker(self.features.extractor.rectifier, self.cfg.frontend)
        self.state = PipelineState.INIT
        self.segments: list[Segment] = []
        self._new_segment()
        self._last_pose: F64 | None = None
        self._last_good_t: int | None = None  # the last tracked frame ...
        self._last_good_T: F64 | None = None  # ... and its pose
        self._hint_T: F64 | None = None  # pose to restart from after a reset
        self._init_mode: str | None = None
        self._window: list[tuple[int, F64]] = []  # dynamic init: VO frames (t, T_world_body)
        self._online: list[tuple[int, F64, int]] = []

    # ---- segments -------------------------------------------------------------------------------
    @property
    def segment(self) -> Segment:
        return self.segments[-1]

    def _new_segment(self) -> None:
        self.segments.append(Segment(len(self.segments)))
        self.est = KeyframeEstimator(self.source.rig.imu, self.stereo, self.imu, self.cfg)
        self._nav: NavEstimate | None = None  # the latest keyframe's smoothed state
        self._kf_index = -1  # the latest keyframe's index in the segment
        self._n_active = 0  # landmarks in the smoother
        self._kf_path: list[tuple[int, F64]] = []  # keyframes: time, latest smoothed pose

    def _finish_segment(self) -> None:
        """Final batch over the segment's graph; the segment keeps the solution."""
        seg = self.segment
        if self._nav is None or not seg.records:
            return
        t0 = time.perf_counter()
        seg.solution = self.est.finish(seg.frame_refs())
        if seg.solution.imu_check is not None:
            self.summary.imu_checks.append(seg.solution.imu_check)
        self.summary.add_time("final_batch", (time.perf_counter() - t0) * 1e3)
        self.summary.keyframes += len(seg.solution.keyframes)

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
        wall0 = time.perf_counter()
        cpu0 = cpu_seconds()
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
        s.cpu_s = cpu_seconds() - cpu0
        s.peak_rss_mb = peak_rss_mb()
        s.worker_peak_rss_mb = list(self.features.worker_peak_rss_mb)
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
        out = self._step_init(ff) if self.state == PipelineState.INIT else self._step_tracking(ff)
        if out.frontend is not None:
            s.landmarks_reused += out.frontend.n_reused
            if out.frontend.track_path:
                p = out.frontend.track_path
                s.track_paths[p] = s.track_paths.get(p, 0) + 1
            if "track_total" in out.frontend.timings_ms:
                s.add_time("tracking", out.frontend.timings_ms["track_total"])
        s.state_frames[out.state.value] = s.state_frames.get(out.state.value, 0) + 1
        if out.T_world_body is not None:
            s.frames_with_pose += 1
            self._online.append((out.t_ns, out.T_world_body, out.segment))
            self._last_pose = out.T_world_body
        return out

    # ---- INIT -----------------------------------------------------------------------------------
    def _step_init(self, ff: FrameFeatures) -> FrameOutput:
        t = ff.t_ns
        g = self.cfg.imu.gravity
        if self._init_mode is None:
            if not self.cfg.inertial:
                self._init_mode = "visual"
            else:
                self._init_mode = choose_mode(self.imu, t, self.cfg.init, g)
        seg = self.segment
        if self._init_mode in ("static", "visual"):
            if self._init_mode == "static":
                try:
                    init = static_init(self.imu, t, self.cfg.init, g)
                except ValueError:
                    self._init_mode = None
                    return self._out(t, PipelineState.INIT, None, None)
                if self._hint_T is not None:
                    init = InitialState(
                        t,
                        make_T(init.T_world_body[:3, :3], self._hint_T[:3, 3]),
                        init.v_world,
                        init.bg,
                        init.ba,
                        "static",
                    )
            else:
                T0 = (
                    self._hint_T
                    if self._hint_T is not None
                    else make_T(self._visual_attitude(), np.zeros(3))
                )
                init = InitialState(t, T0, np.zeros(3), np.zeros(3), np.zeros(3), "visual")
            fr = self.tracker.track(ff, init.T_world_body)
            if fr.T_world_body is None:
                return self._out(t, PipelineState.INIT, None, fr)
            return self._start_estimator(init, fr)
        # dynamic: stereo VO in a levelled frame, then align with the IMU
        if not self._window:
            R0 = self._levelled_attitude(t)
            p0 = self._hint_T[:3, 3] if self._hint_T is not None else np.zeros(3)
            fr = self.tracker.track(ff, make_T(R0, p0))
        else:
            fr = self.tracker.track(ff, None)
        if fr.T_world_body is None:
            return self._out(t, PipelineState.INIT, None, fr)
        self._window.append((t, fr.T_world_body))
        seg.records.append(FrameRecord(t, fr.T_world_body, -1))
        span = (t - self._window[0][0]) * 1e-9
        c = self.cfg.init
        if span >= c.dynamic_window_s and len(self._window) >= c.dynamic_min_keyframes:
            sel = self._window[::2] if len(self._window) > 30 else self._window
            if sel[-1] is not self._window[-1]:
                sel = [*sel, self._window[-1]]
            try:
                assert self.source.rig.imu is not None  # stereo-inertial
                params = make_params(self.source.rig.imu, self.cfg.imu)
                init = dynamic_init(params, self.imu, [w[0] for w in sel], [w[1] for w in sel], g)
            except (ValueError, np.linalg.LinAlgError):
                if span < 3 * c.dynamic_window_s:
                    return self._out(t, PipelineState.INIT, fr.T_world_body, fr)
                init = self._fallback_init()
            return self._finish_dynamic(init, fr)
        return self._out(t, PipelineState.INIT, fr.T_world_body, fr)

    def _levelled_attitude(self, t: int) -> F64:
        t0, t1 = static_window(t, self.cfg.init)
        w = self.imu.slice(t0, t1)
        if len(w) >= 3:
            return gravity_aligned_rotation(np.mean(w.accel, axis=0))
        if self._hint_T is not None:
            return self._hint_T[:3, :3]
        return self._visual_attitude()

    def _visual_attitude(self) -> F64:
        """The first attitude of a world nothing levels (`init.visual_world`): cam0 held level,
        looking along world x, or the first body frame."""
        if self.cfg.init.visual_world == "body":
            return np.eye(3)
        R_body_cam0 = self.source.rig.cam0.T_body_cam[:3, :3]
        return R_WORLD_CAM_LEVEL @ R_body_cam0.T

    def _fallback_init(self) -> InitialState:
        """The window could not be aligned (too little motion): keep the levelled VO frame,
        velocity from VO differences, zero biases with their priors."""
        (ta, Ta), (tb, Tb) = self._window[-2], self._window[-1]
        v = (Tb[:3, 3] - Ta[:3, 3]) / max((tb - ta) * 1e-9, 1e-3)
        window = tuple((w[0], w[1], v) for w in self._window)
        return InitialState(tb, Tb, v, np.zeros(3), np.zeros(3), "dynamic", window, np.eye(3))

    def _finish_dynamic(self, init: InitialState, fr: FrontendResult) -> FrameOutput:
        R = init.R_world_vo if init.R_world_vo is not None else np.eye(3)
        C = make_T(R, np.zeros(3))
        # re-express the window and the tracker's map in the gravity-aligned world
        for rec in self.segment.records:
            rec.T_chain = C @ rec.T_chain
        assert fr.T_world_body is not None
        self.tracker.apply(MapCorrection(C @ fr.T_world_body, T_new_old=C))
        t_last, T_last, v_last = init.window[-1]
        last = InitialState(t_last, T_last, v_last, init.bg, init.ba, "dynamic")
        self._window = []
        return self._start_estimator(last, fr, window_frame=True)

    def _start_estimator(
        self, init: InitialState, fr: FrontendResult, window_frame: bool = False
    ) -> FrameOutput:
        t = init.t_ns
        try:
            upd = self.est.initialize(init, fr.landmark_ids, fr.stereo_uv, fr.stereo_sigma)
        except EstimatorFailure as e:
            self._reset(t, f"initialisation failed: {e}", self._hint_T)
            return self._out(t, PipelineState.INIT, None, fr)
        seg = self.segment
        self.summary.init_modes.append(init.mode)
        T = upd.nav.T_world_body
        seg.kf_T_chain[0] = T
        if window_frame:
            seg.records[-1].T_chain = T
            seg.records[-1].ref_kf = 0
        else:
            seg.records.append(FrameRecord(t, T, 0))
        self.tracker.apply(MapCorrection(T))
        self.state = PipelineState.TRACKING
        self._last_good_t, self._last_good_T = t, T
        self._hint_T = None
        return self._keyframe_out(t, upd, fr)

    # ---- TRACKING / LOST ------------------------------------------------------------------------
    def _step_tracking(self, ff: FrameFeatures) -> FrameOutput:
        nav = self._nav
        assert nav is not None
        t = ff.t_ns
        hc = self.cfg.health
        pred = self.est.predict(t)
        since_kf = (t - nav.t_ns) * 1e-9
        bc = self.cfg.backend
        kf_ok = since_kf >= bc.min_keyframe_interval_s
        if self.cfg.inertial:
            fr = self.tracker.track(ff, pred.T_world_body, kf_ok)
        else:
            # visual-only: constant velocity from the last two poses (the tracker's own model)
            pred = NavEstimate(t, self._constant_velocity(t), pred.v_world, pred.bg, pred.ba)
            fr = self.tracker.track(ff, None, kf_ok)
        tracked = fr.T_world_body is not None and (
            fr.state == TrackingState.INIT or fr.n_tracked >= hc.min_tracked
        )
        if tracked and fr.T_world_body is not None:
            v = self._plausible(t, pred.T_world_body, fr.T_world_body)
            if not v.ok:
                tracked = False
                self.tracker.apply(MapCorrection(pred.T_world_body))
        if tracked and fr.T_world_body is not None:
            need_kf = (
                fr.is_keyframe
                or fr.state == TrackingState.INIT
                or self.state == PipelineState.LOST
                or since_kf >= bc.max_keyframe_interval_s
            )
            if need_kf:
                return self._add_keyframe(t, fr, pred)
            T = fr.T_world_body
            self.segment.records.append(FrameRecord(t, T, self._kf_index))
            self.state = PipelineState.TRACKING
            self._last_good_t, self._last_good_T = t, T
            return self._out(t, PipelineState.TRACKING, T, fr, nav)
        # LOST: bridge with the prediction
        lost_s = (t - (self._last_good_t or t)) * 1e-9
        verdict = self.health.lost(lost_s, self.est.imu_ok_since_keyframe())
        T = pred.T_world_body
        if not verdict.ok or not np.all(np.isfinite(T)):
            reason = verdict.reason if not verdict.ok else "non-finite prediction"
            return self._fail(t, reason, T if np.all(np.isfinite(T)) else self._last_pose, fr)
        self.state = PipelineState.LOST
        self.segment.records.append(FrameRecord(t, T, self._kf_index))
        return self._out(t, PipelineState.LOST, T, fr, nav)

    def _add_keyframe(self, t: int, fr: FrontendResult, pred: NavEstimate) -> FrameOutput:
        assert fr.T_world_body is not None
        t0 = time.perf_counter()
        try:
            upd = self.est.add_keyframe(
                t, fr.landmark_ids, fr.stereo_uv, fr.T_world_body, fr.stereo_sigma
            )
        except EstimatorFailure as e:
            return self._fail(t, str(e), pred.T_world_body, fr)
        self.summary.add_time("backend", (time.perf_counter() - t0) * 1e3)
        self._kf_index = upd.index
        T = upd.nav.T_world_body
        verdict = self.health.state(upd.nav)
        if verdict.ok:
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
        seg = self.segment
        seg.kf_T_chain[upd.index] = T
        seg.records.append(FrameRecord(t, T, upd.index))
        self.state = PipelineState.TRACKING
        self._last_good_t, self._last_good_T = t, T
        return self._keyframe_out(t, upd, fr)

    def _plausible(self, t: int, T_pred: F64, T_new: F64) -> Verdict:
        """`Health.motion` of a tracked or smoothed pose at `t`."""
        T_last = self._last_good_T if self._last_good_T is not None else T_pred
        dt = (t - (self._last_good_t if self._last_good_t is not None else t)) * 1e-9
        return self.health.motion(T_pred, T_last, dt, T_new)

    def _constant_velocity(self, t: int) -> F64:
        """Pose at `t` extrapolated from the last two online poses of this segment."""
        seg = self.segment.index
        pts = [o for o in self._online[-2:] if o[2] == seg]
        if not pts:
            assert self._nav is not None
            return self._nav.T_world_body
        if len(pts) == 1 or pts[1][0] <= pts[0][0]:
            return pts[-1][1]
        (ta, Ta, _), (tb, Tb, _) = pts
        s = (t - tb) / (tb - ta)
        d = inv_T(Ta) @ Tb
        step = make_T(so3_exp(so3_log(d[:3, :3]) * s), d[:3, 3] * s)
        return Tb @ step

    def _fail(
        self, t: int, reason: str, T_hint: F64 | None, fr: FrontendResult | None
    ) -> FrameOutput:
        """Reset: end the segment; this frame gets the last trusted estimate (if any)."""
        seg_index = self.segment.index
        ok_hint = T_hint is not None and np.all(np.isfinite(T_hint))
        T_out = T_hint if ok_hint else None
        if T_out is not None:
            self.segment.records.append(FrameRecord(t, T_out, max(self._kf_index, 0)))
        self._reset(t, reason, T_out)
        return FrameOutput(
            t,
            PipelineState.LOST,
            T_out,
            seg_index,
            False,
            fr,
            None,
            reason,
            n_resets=len(self.summary.resets),
        )

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
        return self._out(
            t, PipelineState.TRACKING, upd.nav.T_world_body, fr, upd.nav, path, upd.landmark_xyz
        )

    def _out(
        self,
        t: int,
        state: PipelineState,
        T: F64 | None,
        fr: FrontendResult | None,
        nav: NavEstimate | None = None,
        path: KeyframePath | None = None,
        landmarks: F64 | None = None,
    ) -> FrameOutput:
        return FrameOutput(
            t,
            state,
            T,
            self.segment.index,
            path is not None,
            fr,
            nav,
            n_keyframes=self._kf_index + 1,
            n_resets=len(self.summary.resets),
            n_active_landmarks=self._n_active,
            keyframe_path=path,
            landmarks=landmarks,
        )

    def result(self) -> RunResult:
        s = self.summary
        s.segments = sum(1 for seg in self.segments if seg.records)
        final = assemble(self.segments)
        s.landmarks = len(final.landmarks)
        on_t = np.array([o[0] for o in self._online], dtype=np.int64)
        on_T = np.array([o[1] for o in self._online]).reshape(-1, 4, 4)
        on_s = np.array([o[2] for o in self._online], dtype=np.int64)
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
