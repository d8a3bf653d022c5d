"""The SLAM pipeline: reader -> frontend -> backend -> observers (MCAP, files), one pass.

State machine (`PipelineState`):

* **INIT**: no estimate yet (start, or after a reset). The initialisation kind is chosen from
  the IMU around the current frame: *static* (still: attitude and gyro bias from the IMU mean,
  the estimator starts at once) or *dynamic* (moving: the frontend runs as stereo VO for
  `init.dynamic_window_s`, then VO and preintegrated IMU are aligned for gravity, velocity and
  biases). Poses are output from the first frame on in both cases; during a dynamic window they
  come from VO in a frame levelled by the mean accelerometer reading.
* **TRACKING**: per frame, the IMU predicts the pose from the latest keyframe state, the frontend
  tracks its local map from that prediction, keyframes go into the smoother (and the frontend
  adopts the smoothed pose and landmarks). The online pose of a frame is the smoothed state for
  keyframes and the frontend's tracked pose otherwise.
* **LOST**: blank / missing images or failed tracking: the IMU prediction bridges the frames
  (constant velocity without IMU). Too long without vision (`health.max_lost_s`), an IMU dropout
  while blind, a smoother failure, NaN, or out-of-bounds velocity/biases reset the estimator:
  the segment ends (final batch) and a new one starts with a fresh initialisation.

Outputs: the online (causal) trajectory, the final trajectory (each segment's keyframes after a
full batch optimisation, other frames attached to their keyframe by their online relative
pose), the map (batch-optimised landmarks), and a summary with per-stage timings. Observers get
every frame as it is processed (`FrameObserver.on_frame`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum
from typing import Protocol

import numpy as np

from eurocslam.backend.estimator import (
    EstimatorFailure,
    ImuCheck,
    NavEstimate,
    StereoInertialEstimator,
)
from eurocslam.backend.health import check_lost, check_state, check_step
from eurocslam.backend.initializer import (
    InitialState,
    choose_mode,
    dynamic_init,
    gravity_aligned_rotation,
    static_init,
    static_window,
)
from eurocslam.config import RunConfig
from eurocslam.dataset.types import SequenceSource, StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.frontend import FrameFeatures, StereoFrontend
from eurocslam.frontend.types import FrontendResult, TrackingState
from eurocslam.geometry import F64, inv_T, make_T, so3_exp, so3_log
from eurocslam.memory import peak_rss_mb

# EuRoC mounting (body x up, body z forward): the visual-only world's initial attitude
R_WORLD_BODY_MOUNT = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])


class PipelineState(str, Enum):
    INIT = "INIT"
    TRACKING = "TRACKING"
    LOST = "LOST"


STATE_CODE = {PipelineState.INIT: 0, PipelineState.TRACKING: 1, PipelineState.LOST: 2}


@dataclass(frozen=True)
class FrameOutput:
    """What the pipeline produced for one stereo frame."""

    t_ns: int
    state: PipelineState
    T_world_body: F64 | None  # online pose (None: no estimate for this frame)
    segment: int
    is_keyframe: bool
    frontend: FrontendResult | None
    nav: NavEstimate | None  # latest backend state (velocity, biases)
    reset_reason: str = ""  # non-empty when this frame ended a segment


class FrameObserver(Protocol):
    def on_frame(self, frame: StereoFrame, out: FrameOutput, pipeline: SlamPipeline) -> None: ...


@dataclass
class _FrameRecord:
    t_ns: int
    T_online: F64
    T_chain: F64  # pose in the segment's frame used to attach it to its reference keyframe
    ref_kf: int  # keyframe index (in the segment) this frame hangs from; -1: the first one


@dataclass
class _Segment:
    index: int
    records: list[_FrameRecord] = field(default_factory=list)
    kf_T_chain: dict[int, F64] = field(default_factory=dict)
    final_kf: dict[int, F64] = field(default_factory=dict)
    final_frames: dict[int, F64] = field(default_factory=dict)  # record index -> IMU-bridged pose
    landmarks: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    init_mode: str = ""


def _cpu_seconds() -> float:
    """CPU time of this process and of its finished children (the frontend's extraction
    workers, once the stream has ended)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Windows
        return time.process_time()
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ru.ru_utime + ru.ru_stime


def _finite(x: float) -> float | None:
    """Rounded for JSON; NaN (not measured) as null."""
    return None if math.isnan(x) else round(x, 3)


@dataclass
class RunSummary:
    sequence: str = ""
    mode: str = "stereo-inertial"
    frames: int = 0
    frames_with_pose: int = 0
    keyframes: int = 0
    landmarks: int = 0
    landmarks_reused: int = 0  # archived landmarks re-found (map reuse: loop closures)
    segments: int = 0
    resets: list[tuple[int, str]] = field(default_factory=list)
    init_modes: list[str] = field(default_factory=list)
    imu_checks: list[ImuCheck] = field(default_factory=list)  # final batch, per segment
    state_frames: dict[str, int] = field(default_factory=dict)
    timings_ms: dict[str, list[float]] = field(default_factory=dict)
    wall_s: float = 0.0
    cpu_s: float = 0.0  # CPU time of the process (every thread) and its workers
    peak_rss_mb: float = math.nan  # this process's peak resident memory
    worker_peak_rss_mb: list[float] = field(default_factory=list)  # extraction workers'
    duration_s: float = 0.0

    def add_time(self, stage: str, ms: float) -> None:
        self.timings_ms.setdefault(stage, []).append(ms)

    @property
    def coverage(self) -> float:
        return self.frames_with_pose / self.frames if self.frames else 0.0

    @property
    def realtime_factor(self) -> float:
        return self.duration_s / self.wall_s if self.wall_s > 0 else 0.0

    def timing_table(self) -> list[tuple[str, int, float, float, float]]:
        """(stage, calls, median ms, total s, share of wall time)."""
        rows = []
        for stage, v in self.timings_ms.items():
            a = np.asarray(v)
            rows.append(
                (
                    stage,
                    a.size,
                    float(np.median(a)),
                    float(a.sum()) / 1e3,
                    float(a.sum()) / 1e3 / self.wall_s if self.wall_s else 0.0,
                )
            )
        return rows

    def to_dict(self) -> dict[str, object]:
        return {
            "sequence": self.sequence,
            "mode": self.mode,
            "frames": self.frames,
            "frames_with_pose": self.frames_with_pose,
            "coverage": round(self.coverage, 4),
            "keyframes": self.keyframes,
            "landmarks": self.landmarks,
            "landmarks_reused": self.landmarks_reused,
            "segments": self.segments,
            "resets": [{"t_ns": t, "reason": r} for t, r in self.resets],
            "init_modes": self.init_modes,
            "imu_check": [
                {
                    "ratio": _finite(c.ratio),
                    "accel_scale": round(c.accel_scale, 3),
                    "ratio_after": _finite(c.ratio_after),
                }
                for c in self.imu_checks
            ],
            "state_frames": self.state_frames,
            "duration_s": round(self.duration_s, 3),
            "wall_s": round(self.wall_s, 3),
            "cpu_s": round(self.cpu_s, 3),
            "peak_rss_mb": _finite(self.peak_rss_mb),
            "worker_peak_rss_mb": [_finite(m) for m in self.worker_peak_rss_mb],
            "realtime_factor": round(self.realtime_factor, 3),
            "timings": {
                s: {
                    "calls": n,
                    "median_ms": round(m, 3),
                    "total_s": round(t, 3),
                    "share": round(sh, 4),
                }
                for s, n, m, t, sh in self.timing_table()
            },
        }

    def lines(self) -> list[str]:
        out = [
            f"{self.sequence}: {self.mode}, {self.frames} frames, pose for "
            f"{self.frames_with_pose} ({100 * self.coverage:.1f} %), {self.keyframes} keyframes, "
            f"{self.landmarks} landmarks ({self.landmarks_reused} re-found), "
            f"{self.segments} segment(s), {len(self.resets)} reset(s)",
            f"init: {', '.join(self.init_modes) or 'none'}; frames per state: "
            + ", ".join(f"{k} {v}" for k, v in sorted(self.state_frames.items())),
            f"{self.duration_s:.1f} s of data in {self.wall_s:.1f} s wall "
            f"(real-time factor {self.realtime_factor:.2f}), {self.cpu_s:.1f} s CPU",
            f"peak memory {self.peak_rss_mb:.0f} MB"
            + (
                f" + {len(self.worker_peak_rss_mb)} extraction workers "
                + " + ".join(f"{m:.0f}" for m in self.worker_peak_rss_mb)
                + " MB"
                if self.worker_peak_rss_mb
                else ""
            ),
        ]
        for c in self.imu_checks:
            if math.isnan(c.ratio):
                out.append("final batch: too few IMU or stereo factors to check the IMU")
                continue
            out.append(
                f"final batch: IMU residuals {c.ratio:.2f}x the stereo residuals (chi-square per "
                "redundancy)"
                + (
                    f"; accelerometer covariances scaled by {c.accel_scale:.1f}: "
                    f"{c.ratio_after:.2f}x"
                    if c.accel_scale != 1.0
                    else ""
                )
            )
        for t, r in self.resets:
            out.append(f"  reset at t={t} ns: {r}")
        out.append(f"  {'stage':<18}{'calls':>7}{'median ms':>11}{'total s':>9}{'share':>8}")
        for s, n, m, tot, sh in self.timing_table():
            out.append(f"  {s:<18}{n:>7}{m:>11.2f}{tot:>9.2f}{100 * sh:>7.1f}%")
        return out


@dataclass
class RunResult:
    online_t_ns: np.ndarray
    online_T: F64  # (N, 4, 4)
    online_segment: np.ndarray
    final_t_ns: np.ndarray
    final_T: F64
    final_segment: np.ndarray
    landmarks: F64  # (M, 3) batch-optimised map
    landmark_segment: np.ndarray
    summary: RunSummary


class SlamPipeline:
    """Stereo-inertial (or visual-only) SLAM over a `SequenceSource`."""

    def __init__(
        self,
        source: SequenceSource,
        cfg: RunConfig | None = None,
        *,
        use_imu: bool = True,
        observers: Iterable[FrameObserver] = (),
    ) -> None:
        self.source = source
        self.cfg = cfg or RunConfig()
        self.use_imu = use_imu
        self.observers = list(observers)
        self.fe_cfg = FrontendConfig.from_dict(self.cfg.frontend)
        self.imu = source.imu
        self.summary = RunSummary(
            sequence=source.name, mode="stereo-inertial" if use_imu else "visual-only"
        )
        self.frontend = StereoFrontend(source.rig, self.fe_cfg)
        self.stereo = self.frontend.rectified
        self.state = PipelineState.INIT
        self.segments: list[_Segment] = []
        self.est: StereoInertialEstimator | None = None
        self._new_segment()
        self._last_pose: F64 | None = None
        self._last_good_t: int | None = None
        self._hint_T: F64 | None = None  # pose to restart from after a reset
        self._init_mode: str | None = None
        self._window: list[tuple[int, F64, np.ndarray, F64]] = []  # dynamic init VO frames
        self._online: list[tuple[int, F64, int]] = []
        self._kf_path: list[tuple[int, F64]] = []  # current segment's keyframes (for /slam/path)

    # ---- segments -------------------------------------------------------------------------------
    @property
    def segment(self) -> _Segment:
        return self.segments[-1]

    def _new_segment(self) -> None:
        self.segments.append(_Segment(len(self.segments)))
        self.est = StereoInertialEstimator(
            self.source.rig.imu, self.stereo, self.imu, self.cfg, use_imu=self.use_imu
        )
        self._kf_path = []

    def _finish_segment(self) -> None:
        """Final batch over the segment's graph, then attach every frame to its keyframe."""
        seg, est = self.segment, self.est
        if est is None or est.state is None or not seg.records:
            return
        t0 = time.perf_counter()
        if self.cfg.backend.final_batch:
            kf, lms = est.final_batch(self.cfg.backend.final_batch_max_iterations)
        else:
            kf = {k: e.T_world_body for k, e in est.kf_estimates.items()}
            lms = dict(enumerate(est.active_landmarks()[1]))
        seg.final_kf = kf
        if est.imu_check is not None:
            self.summary.imu_checks.append(est.imu_check)
        if self.use_imu and self.cfg.backend.final_batch:
            self._bridge_frames(seg, est)
        self.summary.add_time("final_batch", (time.perf_counter() - t0) * 1e3)
        seg.landmarks = np.array(list(lms.values())).reshape(-1, 3)
        self.summary.keyframes += len(kf)

    @staticmethod
    def _bridge_frames(seg: _Segment, est: StereoInertialEstimator) -> None:
        """Final poses of the frames between two keyframes from the IMU between their final
        states (the frames' own tracking is noisier than the preintegration over < 0.5 s)."""
        groups: dict[int, list[int]] = {}
        kf_t = set(est.segment.kf_times)
        for i, rec in enumerate(seg.records):
            if rec.ref_kf >= 0 and rec.t_ns not in kf_t:
                groups.setdefault(rec.ref_kf, []).append(i)
        for k, idx in groups.items():
            Ts = est.imu_bridge(k, [seg.records[i].t_ns for i in idx])
            if Ts is not None:
                seg.final_frames.update(zip(idx, Ts, strict=True))

    def _reset(self, t_ns: int, reason: str, T_hint: F64 | None) -> None:
        self.summary.resets.append((t_ns, reason))
        self._finish_segment()
        next_id = self.frontend.map.next_id
        self.frontend = StereoFrontend(self.source.rig, self.fe_cfg, first_landmark_id=next_id)
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
        on_progress: object | None = None,
    ) -> RunResult:
        wall0 = time.perf_counter()
        cpu0 = _cpu_seconds()
        frames = self.source.frames(
            include_incomplete=True, t_start_ns=t_start_ns, t_end_ns=t_end_ns
        )
        t_first = t_last = None
        # extraction is stateless: the first frontend's stream serves every segment
        extractor = self.frontend
        for frame, ff in extractor.stream(frames):
            if t_first is None:
                t_first = frame.t_ns
            t_last = frame.t_ns
            out = self.step(frame, ff)
            t0 = time.perf_counter()
            for ob in self.observers:
                ob.on_frame(frame, out, self)
            self.summary.add_time("output", (time.perf_counter() - t0) * 1e3)
            if callable(on_progress):
                on_progress(out)
        self._finish_segment()
        self.summary.wall_s = time.perf_counter() - wall0
        self.summary.cpu_s = _cpu_seconds() - cpu0
        self.summary.peak_rss_mb = peak_rss_mb()
        self.summary.worker_peak_rss_mb = list(extractor.worker_peak_rss_mb)
        if t_first is not None and t_last is not None:
            self.summary.duration_s = (t_last - t_first) * 1e-9 + 1.0 / max(
                self.source.rig.cam0.rate_hz, 1e-9
            )
        return self.result()

    def step(self, frame: StereoFrame, ff: FrameFeatures) -> FrameOutput:
        """Process one frame (features already extracted)."""
        s = self.summary
        s.frames += 1
        for k in ("decode", "rectify", "orb", "stereo_matching"):
            if k in ff.timings_ms:
                s.add_time(k, ff.timings_ms[k])
        if self.state == PipelineState.INIT:
            out = self._step_init(frame, ff)
        else:
            out = self._step_tracking(frame, ff)
        if out.frontend is not None:
            s.landmarks_reused += out.frontend.n_reused
            if "track_total" in out.frontend.timings_ms:
                s.add_time("tracking", out.frontend.timings_ms["track_total"])
        s.state_frames[out.state.value] = s.state_frames.get(out.state.value, 0) + 1
        if out.T_world_body is not None:
            s.frames_with_pose += 1
            self._online.append((out.t_ns, out.T_world_body, out.segment))
            self._last_pose = out.T_world_body
        return out

    # ---- INIT -----------------------------------------------------------------------------------
    def _step_init(self, frame: StereoFrame, ff: FrameFeatures) -> FrameOutput:
        t = ff.t_ns
        g = self.cfg.imu.gravity
        if self._init_mode is None:
            if not self.use_imu:
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
                    return self._out(t, PipelineState.INIT, None, False, None)
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
                    else make_T(R_WORLD_BODY_MOUNT, np.zeros(3))
                )
                init = InitialState(t, T0, np.zeros(3), np.zeros(3), np.zeros(3), "visual")
            fr = self.frontend.track(ff, init.T_world_body)
            if fr.T_world_body is None:
                return self._out(t, PipelineState.INIT, None, False, fr)
            return self._start_estimator(init, fr)
        # dynamic: stereo VO in a levelled frame, then align with the IMU
        if not self._window:
            R0 = self._levelled_attitude(t)
            p0 = self._hint_T[:3, 3] if self._hint_T is not None else np.zeros(3)
            fr = self.frontend.track(ff, make_T(R0, p0))
        else:
            fr = self.frontend.track(ff, None)
        if fr.T_world_body is None:
            return self._out(t, PipelineState.INIT, None, False, fr)
        self._window.append((t, fr.T_world_body, fr.landmark_ids, fr.stereo_uv))
        seg.records.append(_FrameRecord(t, fr.T_world_body, fr.T_world_body, -1))
        span = (t - self._window[0][0]) * 1e-9
        c = self.cfg.init
        if span >= c.dynamic_window_s and len(self._window) >= c.dynamic_min_keyframes:
            sel = self._window[::2] if len(self._window) > 30 else self._window
            if sel[-1] is not self._window[-1]:
                sel = [*sel, self._window[-1]]
            try:
                init = dynamic_init(
                    self.est.params, self.imu, [w[0] for w in sel], [w[1] for w in sel], g
                )
            except (ValueError, np.linalg.LinAlgError):
                if span < 3 * c.dynamic_window_s:
                    return self._out(t, PipelineState.INIT, fr.T_world_body, False, fr)
                init = self._fallback_init()
            return self._finish_dynamic(init, fr)
        return self._out(t, PipelineState.INIT, fr.T_world_body, False, fr)

    def _levelled_attitude(self, t: int) -> F64:
        t0, t1 = static_window(t, self.cfg.init)
        w = self.imu.slice(t0, t1)
        if len(w) >= 3:
            return gravity_aligned_rotation(np.mean(w.accel, axis=0))
        if self._hint_T is not None:
            return self._hint_T[:3, :3]
        return R_WORLD_BODY_MOUNT

    def _fallback_init(self) -> InitialState:
        """The window could not be aligned (too little motion): keep the levelled VO frame,
        velocity from VO differences, zero biases with their priors."""
        (ta, Ta, _, _), (tb, Tb, _, _) = self._window[-2], self._window[-1]
        v = (Tb[:3, 3] - Ta[:3, 3]) / max((tb - ta) * 1e-9, 1e-3)
        window = tuple((w[0], w[1], v) for w in self._window)
        return InitialState(tb, Tb, v, np.zeros(3), np.zeros(3), "dynamic", window, np.eye(3))

    def _finish_dynamic(self, init: InitialState, fr: FrontendResult) -> FrameOutput:
        R = init.R_world_vo if init.R_world_vo is not None else np.eye(3)
        C = make_T(R, np.zeros(3))
        # re-express the window and the frontend's map in the gravity-aligned world
        for rec in self.segment.records:
            rec.T_chain = C @ rec.T_chain
        m = self.frontend.map
        if len(m):
            self.frontend.correct(C @ fr.T_world_body, (m.ids.copy(), m.xyz @ R.T))
        t_last, T_last, v_last = init.window[-1]
        last = InitialState(t_last, T_last, v_last, init.bg, init.ba, "dynamic")
        self._window = []
        return self._start_estimator(last, fr, window_frame=True)

    def _start_estimator(
        self, init: InitialState, fr: FrontendResult, window_frame: bool = False
    ) -> FrameOutput:
        assert self.est is not None
        t = init.t_ns
        try:
            nav = self.est.initialize(init, fr.landmark_ids, fr.stereo_uv, fr.stereo_sigma)
        except EstimatorFailure as e:
            self._reset(t, f"initialisation failed: {e}", self._hint_T)
            return self._out(t, PipelineState.INIT, None, False, fr)
        seg = self.segment
        seg.init_mode = init.mode
        self.summary.init_modes.append(init.mode)
        seg.kf_T_chain[0] = nav.T_world_body
        if window_frame:
            seg.records[-1].T_chain = nav.T_world_body
            seg.records[-1].ref_kf = 0
        else:
            seg.records.append(_FrameRecord(t, nav.T_world_body, nav.T_world_body, 0))
        self.frontend.correct(nav.T_world_body)
        self.state = PipelineState.TRACKING
        self._last_good_t = t
        self._hint_T = None
        self._kf_path.append((t, nav.T_world_body))
        return self._out(t, PipelineState.TRACKING, nav.T_world_body, True, fr, nav)

    # ---- TRACKING / LOST ------------------------------------------------------------------------
    def _step_tracking(self, frame: StereoFrame, ff: FrameFeatures) -> FrameOutput:
        est = self.est
        assert est is not None and est.state is not None
        t = ff.t_ns
        hc = self.cfg.health
        pred = est.predict(t)
        if self.use_imu:
            fr = self.frontend.track(ff, pred.T_world_body)
        else:
            # visual-only: constant velocity from the last two poses (the frontend's own model)
            pred = NavEstimate(t, self._constant_velocity(t), pred.v_world, pred.bg, pred.ba)
            fr = self.frontend.track(ff, None)
        tracked = fr.T_world_body is not None and (
            fr.state == TrackingState.INIT or fr.n_tracked >= hc.min_tracked
        )
        if tracked and fr.T_world_body is not None:
            v = check_step(pred.T_world_body, fr.T_world_body, hc)
            if not v.ok:
                tracked = False
                self.frontend.correct(pred.T_world_body)
        if tracked and fr.T_world_body is not None:
            since_kf = (t - est.state.t_ns) * 1e-9
            bc = self.cfg.backend
            need_kf = (
                (fr.is_keyframe and since_kf >= bc.min_keyframe_interval_s)
                or fr.state == TrackingState.INIT
                or self.state == PipelineState.LOST
                or since_kf >= bc.max_keyframe_interval_s
            )
            if need_kf:
                t0 = time.perf_counter()
                try:
                    nav = est.add_keyframe(
                        t, fr.landmark_ids, fr.stereo_uv, fr.T_world_body, fr.stereo_sigma
                    )
                except EstimatorFailure as e:
                    return self._fail(t, str(e), pred.T_world_body, fr)
                self.summary.add_time("backend", (time.perf_counter() - t0) * 1e3)
                verdict = check_state(nav, hc, self.use_imu)
                if verdict.ok:
                    verdict = check_step(pred.T_world_body, nav.T_world_body, hc)
                if not verdict.ok:
                    return self._fail(t, verdict.reason, pred.T_world_body, fr)
                self._correct_frontend(nav.T_world_body, fr.T_world_body)
                seg = self.segment
                seg.kf_T_chain[est.k] = nav.T_world_body
                seg.records.append(_FrameRecord(t, nav.T_world_body, nav.T_world_body, est.k))
                self._kf_path.append((t, nav.T_world_body))
                self.state = PipelineState.TRACKING
                self._last_good_t = t
                return self._out(t, PipelineState.TRACKING, nav.T_world_body, True, fr, nav)
            T = fr.T_world_body
            self.segment.records.append(_FrameRecord(t, T, T, est.k))
            self.state = PipelineState.TRACKING
            self._last_good_t = t
            return self._out(t, PipelineState.TRACKING, T, False, fr, est.state)
        # LOST: bridge with the IMU prediction (constant velocity without IMU)
        lost_s = (t - (self._last_good_t or t)) * 1e-9
        verdict = check_lost(lost_s, est.imu_ok_since_keyframe(), self.use_imu, hc)
        T = pred.T_world_body
        if not verdict.ok or not np.all(np.isfinite(T)):
            reason = verdict.reason if not verdict.ok else "non-finite prediction"
            return self._fail(t, reason, T if np.all(np.isfinite(T)) else self._last_pose, fr)
        self.state = PipelineState.LOST
        self.segment.records.append(_FrameRecord(t, T, T, est.k))
        return self._out(t, PipelineState.LOST, T, False, fr, est.state)

    def _correct_frontend(self, T_new: F64, T_frontend: F64) -> None:
        """Hand the smoothed keyframe pose and landmarks to the frontend. Landmarks the
        smoother does not hold are moved rigidly with the keyframe's correction, so the
        frontend's map stays in one frame (mixing corrected and uncorrected points would bias
        its pose estimates between keyframes)."""
        assert self.est is not None
        m = self.frontend.map
        if len(m) and self.cfg.backend.correct_whole_map:
            D = T_new @ inv_T(T_frontend)
            self.frontend.correct(T_new, (m.ids.copy(), m.xyz @ D[:3, :3].T + D[:3, 3]))
        if self.cfg.backend.correct_landmarks:
            self.frontend.correct(T_new, self.est.active_landmarks())
        else:
            self.frontend.correct(T_new)

    def _constant_velocity(self, t: int) -> F64:
        """Pose at `t` extrapolated from the last two online poses of this segment."""
        seg = self.segment.index
        pts = [o for o in self._online[-2:] if o[2] == seg]
        if not pts:
            assert self.est is not None and self.est.state is not None
            return self.est.state.T_world_body
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
        if T_out is not None and self.est is not None:
            self.segment.records.append(_FrameRecord(t, T_out, T_out, max(self.est.k, 0)))
        self._reset(t, reason, T_out)
        return FrameOutput(t, PipelineState.LOST, T_out, seg_index, False, fr, None, reason)

    def _out(
        self,
        t: int,
        state: PipelineState,
        T: F64 | None,
        is_kf: bool,
        fr: FrontendResult | None,
        nav: NavEstimate | None = None,
    ) -> FrameOutput:
        return FrameOutput(t, state, T, self.segment.index, is_kf, fr, nav)

    # ---- views for observers -------------------------------------------------------------------
    def keyframe_path(self) -> tuple[np.ndarray, F64]:
        """The current segment's keyframes: latest smoothed poses where still in the window."""
        est = self.est
        if not self._kf_path:
            return np.zeros(0, np.int64), np.zeros((0, 4, 4))
        t = np.array([p[0] for p in self._kf_path], dtype=np.int64)
        T = np.array([p[1] for p in self._kf_path])
        if est is not None:
            for k, e in est.kf_estimates.items():
                if 0 <= k < len(T):
                    T[k] = e.T_world_body
        return t, T

    def n_active_landmarks(self) -> int:
        return 0 if self.est is None else self.est.n_active_landmarks

    def active_landmarks(self) -> F64:
        if self.est is None:
            return np.zeros((0, 3))
        return self.est.active_landmarks()[1]

    # ---- results --------------------------------------------------------------------------------
    def result(self) -> RunResult:
        s = self.summary
        s.segments = sum(1 for seg in self.segments if seg.records)
        ft, fT, fs, lm, ls = [], [], [], [], []
        for seg in self.segments:
            if not seg.records:
                continue
            for i, rec in enumerate(seg.records):
                ref = rec.ref_kf if rec.ref_kf >= 0 else 0
                if i in seg.final_frames:
                    T = seg.final_frames[i]
                elif ref in seg.final_kf and ref in seg.kf_T_chain:
                    T = seg.final_kf[ref] @ inv_T(seg.kf_T_chain[ref]) @ rec.T_chain
                else:
                    T = rec.T_chain
                ft.append(rec.t_ns)
                fT.append(T)
                fs.append(seg.index)
            lm.append(seg.landmarks)
            ls.append(np.full(len(seg.landmarks), seg.index, np.int64))
        s.landmarks = int(sum(len(x) for x in lm))
        on_t = np.array([o[0] for o in self._online], dtype=np.int64)
        on_T = np.array([o[1] for o in self._online]).reshape(-1, 4, 4)
        on_s = np.array([o[2] for o in self._online], dtype=np.int64)
        order = np.argsort(np.array(ft, dtype=np.int64), kind="stable")
        return RunResult(
            on_t,
            on_T,
            on_s,
            np.array(ft, dtype=np.int64)[order],
            np.array(fT).reshape(-1, 4, 4)[order],
            np.array(fs, dtype=np.int64)[order],
            np.concatenate(lm) if lm else np.zeros((0, 3)),
            np.concatenate(ls) if ls else np.zeros(0, np.int64),
            s,
        )
