"""The pipeline's INIT state: how a segment starts (`Startup`, one per segment).

The initialisation kind is chosen from the IMU around the current frame: *static* (still:
attitude and gyro bias from the IMU mean, the estimator starts at once) or *dynamic* (moving:
the tracker runs as stereo VO for `init.dynamic_window_s`, then VO and preintegrated IMU are
aligned for gravity, velocity and biases). Poses are output from the first frame on in both
cases; during a dynamic window they come from VO in a frame levelled by the mean accelerometer
reading. Visual-only starts at once, in the attitude `init.visual_world` names (nothing measures
gravity).

`Startup.step` takes one frame and says what came of it (`StartupStep`): still waiting (with the
frame's VO pose in a dynamic window), the estimator started (its first keyframe), or the
estimator could not start (the pipeline resets). It owns the choice of kind and the VO window;
it writes the frames of the window into the segment it is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from eurocslam.backend.estimator import KeyframeEstimator
from eurocslam.backend.initializer import (
    InitialState,
    InitMode,
    choose_mode,
    dynamic_init,
    gravity_aligned_rotation,
    static_init,
    static_window,
)
from eurocslam.backend.preintegration import make_params
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate
from eurocslam.config import RunConfig
from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.types import ImuData
from eurocslam.frontend.extraction import FrameFeatures
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.frontend.types import FrontendResult
from eurocslam.geometry import F64, extrapolate_last, make_T
from eurocslam.pipeline.segments import FrameRecord, Segment, interpolate_between
from eurocslam.timebase import ns_to_s

# an optical camera (x right, y down, z forward) held level, looking along world x (z up)
R_WORLD_CAM_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class StartupStep:
    """What INIT made of one frame: `started` (the estimator's first keyframe) once it has
    started, `failure` (the reason) when it could not; else still waiting, with the frame's
    pose when it has one (a dynamic window's VO)."""

    fr: FrontendResult | None
    T_world_body: F64 | None = None
    started: KeyframeUpdate | None = None
    mode: InitMode | None = None
    failure: str = ""
    # a dynamic start: the gravity-aligned world <- the VO window's frame, which the tracker's
    # map is still in
    T_world_vo: F64 | None = None


class Startup:
    """INIT of one segment. `hint`: the pose to start from (the last trusted one, after a
    reset); None: the world's origin."""

    def __init__(
        self, cfg: RunConfig, imu: ImuData, rig: StereoRig, hint: F64 | None = None
    ) -> None:
        self.cfg = cfg
        self.imu = imu
        self.rig = rig
        self.hint = hint
        self._mode: InitMode | None = None
        self._window: list[tuple[int, F64]] = []  # dynamic: VO frames (t, T_world_body)

    def between(self, t_ns: int) -> F64 | None:
        """The pose of a frame left out by `track_every` in a dynamic window: the motion between
        its last two tracked frames (None before the first)."""
        return extrapolate_last(self._window, t_ns)

    def step(
        self,
        ff: FrameFeatures,
        tracker: StereoTracker,
        est: KeyframeEstimator,
        segment: Segment,
    ) -> StartupStep:
        t = ff.t_ns
        g = self.cfg.imu.gravity
        if self._mode is None:
            if not self.cfg.inertial:
                self._mode = InitMode.VISUAL
            else:
                self._mode = choose_mode(self.imu, t, self.cfg.init, g)
        if self._mode in (InitMode.STATIC, InitMode.VISUAL):
            if self._mode == InitMode.STATIC:
                try:
                    init = static_init(self.imu, t, self.cfg.init, g)
                except ValueError:
                    self._mode = None
                    return StartupStep(None)
                if self.hint is not None:
                    init = InitialState(
                        t,
                        make_T(init.T_world_body[:3, :3], self.hint[:3, 3]),
                        init.v_world,
                        init.bg,
                        init.ba,
                        InitMode.STATIC,
                    )
            else:
                T0 = (
                    self.hint
                    if self.hint is not None
                    else make_T(self._visual_attitude(), np.zeros(3))
                )
                init = InitialState(t, T0, np.zeros(3), np.zeros(3), np.zeros(3), InitMode.VISUAL)
            fr = tracker.track(ff, init.T_world_body)
            if fr.T_world_body is None:
                return StartupStep(fr)
            return self._start_estimator(init, fr, est, segment)
        # dynamic: stereo VO in a levelled frame, then align with the IMU
        if not self._window:
            R0 = self._levelled_attitude(t)
            p0 = self.hint[:3, 3] if self.hint is not None else np.zeros(3)
            fr = tracker.track(ff, make_T(R0, p0))
        else:
            fr = tracker.track(ff, None)
        if fr.T_world_body is None:
            return StartupStep(fr)
        self._window.append((t, fr.T_world_body))
        segment.records.append(FrameRecord(t, fr.T_world_body, -1))
        if len(self._window) > 1:  # frames left out (track_every) since the last: interpolated
            interpolate_between(segment.records, self._window[-2], self._window[-1])
        span = ns_to_s(t - self._window[0][0])
        c = self.cfg.init
        if span >= c.dynamic_window_s and len(self._window) >= c.dynamic_min_keyframes:
            sel = self._window[::2] if len(self._window) > 30 else self._window
            if sel[-1] is not self._window[-1]:
                sel = [*sel, self._window[-1]]
            try:
                assert self.rig.imu is not None  # stereo-inertial
                params = make_params(self.rig.imu, self.cfg.imu)
                init = dynamic_init(params, self.imu, [w[0] for w in sel], [w[1] for w in sel], g)
            except (ValueError, np.linalg.LinAlgError):
                if span < 3 * c.dynamic_window_s:
                    return StartupStep(fr, fr.T_world_body)
                init = self._fallback_init()
            return self._finish_dynamic(init, fr, tracker, est, segment)
        return StartupStep(fr, fr.T_world_body)

    def _levelled_attitude(self, t: int) -> F64:
        t0, t1 = static_window(t, self.cfg.init)
        w = self.imu.slice(t0, t1)
        if len(w) >= 3:
            return gravity_aligned_rotation(np.mean(w.accel, axis=0))
        if self.hint is not None:
            return self.hint[:3, :3]
        return self._visual_attitude()

    def _visual_attitude(self) -> F64:
        """The first attitude of a world nothing levels (`init.visual_world`): cam0 held level,
        looking along world x, or the first body frame."""
        if self.cfg.init.visual_world == "body":
            return np.eye(3)
        R_body_cam0 = self.rig.cam0.T_body_cam[:3, :3]
        return cast(F64, R_WORLD_CAM_LEVEL @ R_body_cam0.T)

    def _fallback_init(self) -> InitialState:
        """The window could not be aligned (too little motion): keep the levelled VO frame,
        velocity from VO differences, zero biases with their priors."""
        (ta, Ta), (tb, Tb) = self._window[-2], self._window[-1]
        v = (Tb[:3, 3] - Ta[:3, 3]) / max(ns_to_s(tb - ta), 1e-3)
        window = tuple((w[0], w[1], v) for w in self._window)
        return InitialState(
            tb, Tb, v, np.zeros(3), np.zeros(3), InitMode.DYNAMIC, window, np.eye(3)
        )

    def _finish_dynamic(
        self,
        init: InitialState,
        fr: FrontendResult,
        tracker: StereoTracker,
        est: KeyframeEstimator,
        segment: Segment,
    ) -> StartupStep:
        R = init.R_world_vo if init.R_world_vo is not None else np.eye(3)
        C = make_T(R, np.zeros(3))
        # re-express the window in the gravity-aligned world (the tracker's map: the caller)
        for rec in segment.records:
            rec.T_chain = C @ rec.T_chain
        t_last, T_last, v_last = init.window[-1]
        last = InitialState(t_last, T_last, v_last, init.bg, init.ba, InitMode.DYNAMIC)
        self._window = []
        return self._start_estimator(last, fr, est, segment, T_world_vo=C)

    def _start_estimator(
        self,
        init: InitialState,
        fr: FrontendResult,
        est: KeyframeEstimator,
        segment: Segment,
        T_world_vo: F64 | None = None,
    ) -> StartupStep:
        try:
            upd = est.initialize(init, fr.landmark_ids, fr.stereo_uv, fr.stereo_sigma)
        except EstimatorFailure as e:
            return StartupStep(fr, failure=f"initialisation failed: {e}")
        if T_world_vo is not None:
            rec = segment.records.pop()  # the keyframe's record is made anew
            assert rec.t_ns == init.t_ns
        return StartupStep(fr, upd.nav.T_world_body, upd, init.mode, T_world_vo=T_world_vo)
