"""The pipeline's INIT state: how a segment starts (`SlamPipeline` takes these methods).

The initialisation kind is chosen from the IMU around the current frame: *static* (still:
attitude and gyro bias from the IMU mean, the estimator starts at once) or *dynamic* (moving:
the tracker runs as stereo VO for `init.dynamic_window_s`, then VO and preintegrated IMU are
aligned for gravity, velocity and biases). Poses are output from the first frame on in both
cases; during a dynamic window they come from VO in a frame levelled by the mean accelerometer
reading. Visual-only starts at once, in the attitude `init.visual_world` names (nothing measures
gravity).
"""

from __future__ import annotations

import numpy as np

from eurocslam.backend.estimator import KeyframeEstimator
from eurocslam.backend.initializer import (
    InitialState,
    choose_mode,
    dynamic_init,
    gravity_aligned_rotation,
    static_init,
    static_window,
)
from eurocslam.backend.preintegration import make_params
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate
from eurocslam.config import RunConfig
from eurocslam.dataset.types import ImuData, SequenceSource
from eurocslam.frontend.extraction import FrameFeatures
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.frontend.types import FrontendResult, MapCorrection
from eurocslam.geometry import F64, make_T
from eurocslam.pipeline.records import FrameOutput, PipelineState
from eurocslam.pipeline.segments import FrameRecord, Segment, interpolate_between
from eurocslam.pipeline.summary import RunSummary

# an optical camera (x right, y down, z forward) held level, looking along world x (z up)
R_WORLD_CAM_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class Startup:
    """INIT: the first keyframe of a segment. Mixed into `SlamPipeline`."""

    source: SequenceSource
    cfg: RunConfig
    imu: ImuData
    tracker: StereoTracker
    est: KeyframeEstimator
    summary: RunSummary
    state: PipelineState
    _init_mode: str | None
    _hint_T: F64 | None
    _window: list[tuple[int, F64]]
    _last_good_t: int | None
    _last_good_T: F64 | None

    @property
    def segment(self) -> Segment:
        raise NotImplementedError

    def _reset(self, t_ns: int, reason: str, T_hint: F64 | None) -> None:
        raise NotImplementedError

    def _emit(
        self, t: int, state: PipelineState, T: F64 | None, fr: FrontendResult | None
    ) -> FrameOutput:
        raise NotImplementedError

    def _keyframe(self, t: int, upd: KeyframeUpdate, fr: FrontendResult) -> FrameOutput:
        raise NotImplementedError

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
                    return self._emit(t, PipelineState.INIT, None, None)
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
                return self._emit(t, PipelineState.INIT, None, fr)
            return self._start_estimator(init, fr)
        # dynamic: stereo VO in a levelled frame, then align with the IMU
        if not self._window:
            R0 = self._levelled_attitude(t)
            p0 = self._hint_T[:3, 3] if self._hint_T is not None else np.zeros(3)
            fr = self.tracker.track(ff, make_T(R0, p0))
        else:
            fr = self.tracker.track(ff, None)
        if fr.T_world_body is None:
            return self._emit(t, PipelineState.INIT, None, fr)
        self._window.append((t, fr.T_world_body))
        seg.records.append(FrameRecord(t, fr.T_world_body, -1))
        if len(self._window) > 1:  # frames left out (track_every) since the last: interpolated
            interpolate_between(seg.records, self._window[-2], self._window[-1])
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
                    return self._emit(t, PipelineState.INIT, fr.T_world_body, fr)
                init = self._fallback_init()
            return self._finish_dynamic(init, fr)
        return self._emit(t, PipelineState.INIT, fr.T_world_body, fr)

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
            return self._emit(t, PipelineState.INIT, None, fr)
        self.summary.init_modes.append(init.mode)
        T = upd.nav.T_world_body
        if window_frame:
            rec = self.segment.records.pop()  # the keyframe's record is made anew below
            assert rec.t_ns == t
        self.tracker.apply(MapCorrection(T))
        self._hint_T = None
        return self._keyframe(t, upd, fr)
