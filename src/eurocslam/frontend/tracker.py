"""Tracking, the second stage of the frontend: `FrameFeatures` in, `FrontendResult` out.

`StereoTracker.track(features, prediction)` tracks a local map of landmarks (`local_map.py`):
project the map with the predicted pose (the caller's, e.g. from the IMU, else a
constant-velocity model) and match by descriptor in a window (`projection.py`), optimise the
pose on stereo reprojection errors with outlier rejection (two passes, the second at the refined
pose), find it from descriptors and PnP RANSAC when the prediction fails (`pose_solver.py`),
create landmarks at keyframes, re-find archived ones (map reuse) and cull unreliable ones.
Sequential: one tracker per trajectory segment (`restarted`).

The backend's corrections come back through one method, `apply(MapCorrection)`.
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from eurocslam.camera import RectifiedStereo, triangulate_rect
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import FrameFeatures
from eurocslam.frontend.features import Features
from eurocslam.frontend.local_map import CullRules, LocalMap
from eurocslam.frontend.motion import VelocityModel
from eurocslam.frontend.pose_solver import optimize_pose, pose_from_descriptors
from eurocslam.frontend.projection import (
    MatchRule,
    Projection,
    body_T_from_rect,
    octave_sigma,
    project_map,
    pyramid_scales,
    rect_T_from_body,
    search_by_projection,
)
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.frontend.types import FrontendResult, MapCorrection, TrackingState, TrackPath
from eurocslam.geometry import F64, inv_T, rigid, transform_points
from eurocslam.timebase import ns_to_s, s_to_ns

# the projection search's window, in `track_radius_deg`s
WINDOW_NO_PRIOR = 1.5  # the first pass without the caller's prediction (constant velocity)
WINDOW_WIDE = 3.0  # the second try when the first finds too few
WINDOW_REFINE = 0.5  # the last pass, at the refined pose
REFINE_MIN_KEPT = 0.8  # the last pass stands when it keeps this share of the inliers before
# the descriptor path (no prior): best under this times the second best; stricter than the
# projection search's `track_ratio`, which only compares keypoints near the prediction
DESCRIPTOR_RATIO = 0.8
PARALLAX_MIN_SEEN = 10  # tracked landmarks seen at the last keyframe to measure the parallax


class StereoTracker:
    """Tracks stereo features against a local map. See the module docstring."""

    def __init__(
        self,
        rectifier: StereoRectifier,
        config: FrontendConfig | None = None,
        first_landmark_id: int = 0,
    ) -> None:
        self.config = c = config or FrontendConfig()
        c.validate()
        self._rectifier = rectifier
        self._T_body_rect0 = rectifier.geometry.T_body_rect0
        self.scale = pyramid_scales(c)
        fx = rectifier.geometry.fx  # angles in the configuration -> pixels on this rig
        self._track_radius_px = fx * np.radians(c.track_radius_deg)
        self._reuse_radius_px = max(fx * np.radians(c.reuse_radius_deg), c.reuse_radius_min_px)
        self._kf_parallax_px = fx * np.radians(c.kf_parallax_deg)
        self._cull_rules = CullRules(
            s_to_ns(c.landmark_max_unseen_s),
            c.landmark_min_visible_for_ratio,
            c.landmark_min_found_ratio,
            c.max_landmarks,
            c.archive_min_found if c.reuse_map else None,
        )
        self.map = LocalMap(first_landmark_id, c.archive_max_landmarks)
        self._motion = VelocityModel(c.max_velocity_m_s, c.max_angular_velocity_rad_s)
        self._t_ns = 0  # the frame being tracked
        self._initialized = False
        self._lost_count = 0
        self._last_kf_t_ns: int | None = None
        self._ref_kf_tracked = 0
        self.last_T_world_body: F64 | None = None

    def restarted(self) -> StereoTracker:
        """A fresh tracker for a new segment (empty map, no motion) that continues the landmark
        ids, so that ids stay unique over the run."""
        return StereoTracker(self._rectifier, self.config, first_landmark_id=self.map.next_id)

    # ---- public interface ------------------------------------------------------------------
    @property
    def rectified(self) -> RectifiedStereo:
        return self._rectifier.geometry

    def landmark_positions(self, ids: NDArray[np.int64]) -> F64:
        """World positions (N, 3) of landmark ids; NaN rows for ids no longer in the map."""
        return self.map.positions(ids)

    def apply(self, correction: MapCorrection) -> None:
        """Adopt the backend's correction of the *last processed frame*: its pose, then a rigid
        motion of the whole map (`T_new_old`, if any), then the landmark positions given
        (unknown ids and non-finite positions are ignored)."""
        c = correction
        self._adopt_pose(c.T_world_body)
        if c.T_new_old is not None:
            self.map.move_all(c.T_new_old)
        if c.landmark_ids is not None and c.landmark_xyz is not None:
            self.map.set_positions(c.landmark_ids, c.landmark_xyz)

    def _adopt_pose(self, T_world_body: F64) -> None:
        T_new = rigid(np.asarray(T_world_body, dtype=np.float64))
        if self.last_T_world_body is not None:
            self._motion.shift(T_new @ inv_T(self.last_T_world_body))
        self.last_T_world_body = T_new.copy()

    # ---- tracking ---------------------------------------------------------------------------
    def track(
        self,
        ff: FrameFeatures,
        T_world_body_pred: F64 | None = None,
        keyframe_allowed: bool = True,
        may_restart: bool = True,
        min_inliers: int = 0,
    ) -> FrontendResult:
        """Track one frame. `T_world_body_pred`: the caller's prediction (the IMU's), else the
        constant-velocity model's; with `motion_prior: false`, neither: the last pose.
        `keyframe_allowed`: the caller would take this frame as a keyframe (the backend's
        minimum interval has passed); otherwise it is not made one (no new landmarks).
        `may_restart`: after `reinit_after_lost_frames` lost frames, start a new map at the
        prediction (false while the caller relocalizes: the prediction is worthless then).
        `min_inliers`: fewer pose inliers than this (or `min_tracked`) is LOST, and nothing of
        the frame enters the map (the caller's bar for a pose found without a prior)."""
        self._t_ns = ff.t_ns
        timings = dict(ff.timings_ms)
        t0 = time.perf_counter()
        if T_world_body_pred is None:
            pred = self._motion.predict(ff.t_ns)
        else:
            pred = rigid(np.asarray(T_world_body_pred, dtype=np.float64))
        if not self.config.motion_prior and self._initialized:
            # no prior: the last pose (a new map still starts where the caller puts it)
            T_world_body_pred, pred = None, self.last_T_world_body
        if ff.problem is not None:
            return self._result(ff, TrackingState.NO_IMAGE, None, timings, t0)
        if not self._initialized:
            return self._initialize(ff, pred, timings, t0)
        if pred is None:  # initialised but never had a pose: cannot happen; be safe
            pred = self.last_T_world_body if self.last_T_world_body is not None else np.eye(4)
        T_world_body, inlier_rows, inlier_kps, path = self._track_local_map(
            ff,
            pred,
            T_world_body_pred is not None,
            timings,
            max(self.config.min_tracked, min_inliers),
        )
        if T_world_body is None:
            self._lost_count += 1
            if may_restart and self._lost_count >= self.config.reinit_after_lost_frames:
                # re-create the map from stereo at the best available pose
                return self._initialize(ff, pred, timings, t0, reinit=True)
            return self._result(
                ff, TrackingState.LOST, None, timings, t0, track_path=TrackPath.LOST
            )
        self._lost_count = 0
        self._motion.update(ff.t_ns, T_world_body)
        self.last_T_world_body = T_world_body
        m = self.map
        m.mark_found(inlier_rows, ff.t_ns, ff.left.desc[inlier_kps])
        is_kf = keyframe_allowed and self._need_keyframe(ff, inlier_rows, inlier_kps)
        ids = m.ids[inlier_rows]
        obs_kps = inlier_kps
        tracked = np.zeros(len(ff.left), dtype=bool)
        tracked[inlier_kps] = True
        n_tracked = int(inlier_rows.size)
        if is_kf:
            used = tracked.copy()
            old_ids, old_kps = self._reuse(ff, T_world_body, used)
            used[old_kps] = True
            new_ids, new_kps = self._create_landmarks(ff, T_world_body, used)
            ids = np.concatenate([ids, old_ids, new_ids])
            obs_kps = np.concatenate([inlier_kps, old_kps, new_kps])
            m.set_keyframe_view(ids, ff.left.uv[obs_kps])
            self._last_kf_t_ns = ff.t_ns
            self._ref_kf_tracked = n_tracked
        m.cull(self._t_ns, self._cull_rules)
        return self._result(
            ff,
            TrackingState.OK,
            T_world_body,
            timings,
            t0,
            ids=ids,
            is_kf=is_kf,
            tracked=tracked,
            n_tracked=n_tracked,
            obs_kps=obs_kps,
            n_reused=int(old_kps.size) if is_kf else 0,
            track_path=path,
        )

    def restart_map(self, ff: FrameFeatures, T_world_body: F64) -> FrontendResult:
        """A new local map from this frame's stereo points at `T_world_body` (a pose found by
        relocalization): an INIT result, or LOST when the frame has too few stereo points."""
        self._t_ns = ff.t_ns
        t0 = time.perf_counter()
        return self._initialize(ff, rigid(T_world_body), dict(ff.timings_ms), t0, reinit=True)

    # ---- internals --------------------------------------------------------------------------
    def _initialize(
        self,
        ff: FrameFeatures,
        pred: F64 | None,
        timings: dict[str, float],
        t0: float,
        reinit: bool = False,
    ) -> FrontendResult:
        T_world_body = pred if pred is not None else np.eye(4)
        n_stereo = int(ff.stereo.valid.sum())
        if n_stereo < self.config.min_tracked:
            # too few stereo points to start a map: keep waiting (pose unknown when lost)
            state = TrackingState.LOST if reinit else TrackingState.INIT
            return self._result(ff, state, None, timings, t0)
        # a new map: the old one's reliable landmarks wait in the archive (map reuse finds them
        # again where the new map meets the old one), the rest go
        self.map.restart(self._cull_rules.archive_min_found)
        self._motion.reset_motion()
        ids, kps = self._create_landmarks(
            ff, T_world_body, np.zeros(len(ff.left), dtype=bool), limit=None
        )
        self.map.set_keyframe_view(ids, ff.left.uv[kps])
        self._initialized = True
        self._lost_count = 0
        self._motion.update(ff.t_ns, T_world_body)
        self.last_T_world_body = T_world_body.copy()
        self._last_kf_t_ns = ff.t_ns
        self._ref_kf_tracked = int(ids.size)
        return self._result(
            ff,
            TrackingState.INIT,
            T_world_body,
            timings,
            t0,
            ids=ids,
            is_kf=True,
            obs_kps=kps,
        )

    def _create_landmarks(
        self,
        ff: FrameFeatures,
        T_world_body: F64,
        used: NDArray[np.bool_],
        limit: int | None = -1,
    ) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
        """New landmarks from stereo keypoints not already tracked, closest first; far ones
        (beyond `far_depth_baselines` baselines) only to make up `min_new_landmarks`."""
        c = self.config
        if limit == -1:
            limit = c.max_new_landmarks_per_keyframe
        cand = np.nonzero(ff.stereo.valid & ~used)[0]
        if cand.size == 0:
            return np.zeros(0, np.int64), cand
        depth = ff.stereo.depth[cand]
        cand = cand[np.argsort(depth, kind="stable")]
        if c.far_depth_baselines > 0:
            n_close = int(np.sum(depth < c.far_depth_baselines * self.rectified.baseline))
            cand = cand[: max(n_close, c.min_new_landmarks)]
        if limit is not None:
            cand = cand[:limit]
        ids = self.map.add(
            self._triangulate_world(ff, cand, T_world_body),
            ff.left.desc[cand],
            ff.left.octave[cand],
            np.full((cand.size, 2), np.nan),
            self._t_ns,
        )
        return ids, cand

    def _triangulate_world(
        self, ff: FrameFeatures, kps: NDArray[np.intp], T_world_body: F64
    ) -> F64:
        """World positions (N, 3) of stereo keypoints `kps` seen from `T_world_body`."""
        uv = ff.left.uv[kps]
        p_rect = triangulate_rect(uv[:, 0], ff.stereo.uR[kps], uv[:, 1], self.rectified)
        T_world_rect0 = T_world_body @ self._T_body_rect0
        return transform_points(T_world_rect0, p_rect)

    def _match_and_optimize(
        self,
        ff: FrameFeatures,
        tree: cKDTree,
        T_rc: F64,
        radius: float,
        sigma_all: F64,
        proj: Projection | None = None,
    ) -> tuple[F64, NDArray[np.intp], NDArray[np.intp], int]:
        """Projection search at T_rc (`proj`: the map projected there already), then pose
        optimisation. (T, inlier rows, kps, n_matched)."""
        c, g, m = self.config, self.rectified, self.map
        proj = project_map(T_rc, m.xyz, g) if proj is None else proj
        rows_vis = np.nonzero(proj.in_view)[0]
        rows, kps, _ = search_by_projection(
            proj, rows_vis, m.desc, m.octave, ff.left, ff.stereo.uR, tree, self.scale,
            MatchRule(radius, c.track_max_hamming, c.track_ratio),
        )  # fmt: skip
        if rows.size < c.min_tracked:
            return T_rc, rows[:0], kps[:0], int(rows.size)
        meas = ff.stereo_uv(kps)
        T_opt, inl, _ = optimize_pose(
            T_rc, m.xyz[rows], meas, sigma_all[kps], g, c.pose_chi2_stereo, c.pose_chi2_mono
        )
        return T_opt, rows[inl], kps[inl], int(rows.size)

    def _track_local_map(
        self,
        ff: FrameFeatures,
        pred: F64,
        have_pred: bool,
        timings: dict[str, float],
        min_inliers: int,
    ) -> tuple[F64 | None, NDArray[np.intp], NDArray[np.intp], TrackPath]:
        """The pose of this frame against the local map, its inlier rows and keypoints, and the
        path that found it: PROJECTION (the map projected with the predicted pose, a window of
        `track_radius_deg`), PROJECTION_WIDE (`WINDOW_WIDE` times the window), DESCRIPTOR (no
        prior: the frame's descriptors matched against the whole local map, PnP RANSAC on the
        matches, then the projection at that pose) or LOST (fewer than `min_inliers`)."""
        c, g, m = self.config, self.rectified, self.map
        empty = np.zeros(0, np.intp)
        if len(m) == 0 or len(ff.left) == 0:
            return None, empty, empty, TrackPath.LOST
        tree = cKDTree(ff.left.uv)
        sigma_all = octave_sigma(self.scale, ff.left.octave)
        T_pred_rc = rect_T_from_body(pred, self._T_body_rect0)
        # predicted-visible statistics for culling
        proj = project_map(T_pred_rc, m.xyz, g)
        m.mark_visible(proj.in_view)
        t0 = time.perf_counter()
        pnp_ms = 0.0
        radius = self._track_radius_px
        # pass 1: at the prediction (wider window without an external prediction)
        r1 = radius * (1.0 if have_pred else WINDOW_NO_PRIOR)
        path = TrackPath.PROJECTION
        T_rc, rows, kps, n_match = self._match_and_optimize(
            ff, tree, T_pred_rc, r1, sigma_all, proj
        )
        if rows.size < c.min_tracked:
            path = TrackPath.PROJECTION_WIDE
            T_rc, rows, kps, n_match = self._match_and_optimize(
                ff, tree, T_pred_rc, WINDOW_WIDE * radius, sigma_all, proj
            )
        if rows.size < max(c.min_tracked, n_match // 2):
            # verify / recover without the prior: descriptor matching + PnP RANSAC
            tp = time.perf_counter()
            T_pnp = self._pose_from_descriptors(ff)
            pnp_ms += (time.perf_counter() - tp) * 1e3
            if T_pnp is not None:
                T2, rows2, kps2, _ = self._match_and_optimize(ff, tree, T_pnp, radius, sigma_all)
                if rows2.size > rows.size:
                    T_rc, rows, kps, path = T2, rows2, kps2, TrackPath.DESCRIPTOR
        if rows.size < c.min_tracked:
            return self._lost(timings, t0, pnp_ms)
        # pass 2: refined pose, tight window, every visible landmark
        T2, rows2, kps2, _ = self._match_and_optimize(
            ff, tree, T_rc, WINDOW_REFINE * radius, sigma_all
        )
        if rows2.size >= rows.size * REFINE_MIN_KEPT and rows2.size >= c.min_tracked:
            T_rc, rows, kps = T2, rows2, kps2
        if rows.size < min_inliers:
            return self._lost(timings, t0, pnp_ms)
        _record_time(timings, t0, pnp_ms)
        return body_T_from_rect(T_rc, self._T_body_rect0), rows, kps, path

    @staticmethod
    def _lost(
        timings: dict[str, float], t0: float, pnp_ms: float
    ) -> tuple[None, NDArray[np.intp], NDArray[np.intp], TrackPath]:
        _record_time(timings, t0, pnp_ms)
        empty = np.zeros(0, np.intp)
        return None, empty, empty, TrackPath.LOST

    def _pose_from_descriptors(self, ff: FrameFeatures) -> F64 | None:
        """The frame's pose (T_rect0_world) without a prior: its descriptors matched to every
        local-map landmark, PnP RANSAC (not place recognition's relocalization: this map only)."""
        c, m = self.config, self.map
        return pose_from_descriptors(
            ff.left.desc,
            ff.left.uv,
            m.xyz,
            m.desc,
            self.rectified,
            DESCRIPTOR_RATIO,
            c.track_max_hamming,
            c.min_tracked,
            c.pnp_reprojection_px,
            c.pnp_iterations,
        )

    def _reuse(
        self, ff: FrameFeatures, T_world_body: F64, used: NDArray[np.bool_]
    ) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
        """Re-find archived landmarks among the stereo keypoints not `used`: projection search
        at the tracked pose (stereo-consistent, strict descriptor distance). They return to the
        map under their old ids, as seen now (position, descriptor, octave)."""
        c, a = self.config, self.map.archive
        none = np.zeros(0, np.int64), np.zeros(0, np.intp)
        if not c.reuse_map or len(a) == 0:
            return none
        free = np.nonzero(ff.stereo.valid & ~used)[0]
        if free.size == 0:
            return none
        T_rc = rect_T_from_body(T_world_body, self._T_body_rect0)
        proj = project_map(T_rc, a.xyz[: a.n], self.rectified)
        rows = np.nonzero(proj.in_view & a.live[: a.n])[0]
        if rows.size == 0:
            return none
        fl = ff.left
        cand = Features(fl.uv[free], fl.octave[free], fl.response[free], fl.desc[free])
        rows, kps, _ = search_by_projection(
            proj, rows, a.desc, a.octave, cand, ff.stereo.uR[free], cKDTree(cand.uv), self.scale,
            MatchRule(self._reuse_radius_px, c.reuse_max_hamming, c.reuse_ratio),
        )  # fmt: skip
        if rows.size == 0:
            return none
        kps = free[kps]
        xyz = self._triangulate_world(ff, kps, T_world_body)
        ids = self.map.revive(rows, xyz, fl.desc[kps], fl.octave[kps], fl.uv[kps], self._t_ns)
        return ids, kps

    def _need_keyframe(
        self, ff: FrameFeatures, rows: NDArray[np.intp], kps: NDArray[np.intp]
    ) -> bool:
        c = self.config
        n = rows.size
        if self._last_kf_t_ns is None:
            return True
        if ns_to_s(ff.t_ns - self._last_kf_t_ns) >= c.kf_max_interval_s:
            return True
        if n < c.kf_min_tracked or n < c.kf_min_tracked_ratio * self._ref_kf_tracked:
            return True
        kf_uv = self.map.kf_uv[rows]
        seen = np.all(np.isfinite(kf_uv), axis=1)
        if seen.sum() >= PARALLAX_MIN_SEEN:
            shift = np.linalg.norm(ff.left.uv[kps[seen]] - kf_uv[seen], axis=1)
            if float(np.median(shift)) > self._kf_parallax_px:
                return True
        return False

    def _keypoint_sigma(self, ff: FrameFeatures, kps: NDArray[np.intp]) -> F64:
        """Keypoints' pixel sigmas: the octave scale, with a fisheye's resampling stretch."""
        octave = octave_sigma(self.scale, ff.left.octave[kps])
        return self._rectifier.keypoint_sigma(octave, ff.left.uv[kps])

    def _result(
        self,
        ff: FrameFeatures,
        state: TrackingState,
        T_world_body: F64 | None,
        timings: dict[str, float],
        t0: float,
        ids: NDArray[np.int64] | None = None,
        is_kf: bool = False,
        tracked: NDArray[np.bool_] | None = None,
        n_tracked: int = 0,
        obs_kps: NDArray[np.intp] | None = None,
        n_reused: int = 0,
        track_path: TrackPath | None = None,
    ) -> FrontendResult:
        t_draw = time.perf_counter()
        draw = self._rectifier.rect0_to_raw(ff.left.uv) if len(ff.left) else np.zeros((0, 2))
        timings["draw"] = (time.perf_counter() - t_draw) * 1e3
        timings["track_total"] = (time.perf_counter() - t0) * 1e3
        return FrontendResult(
            t_ns=ff.t_ns,
            state=state,
            landmark_ids=np.zeros(0, np.int64) if ids is None else ids.astype(np.int64),
            stereo_uv=np.zeros((0, 3)) if obs_kps is None else ff.stereo_uv(obs_kps),
            T_world_body=None if T_world_body is None else T_world_body.copy(),
            is_keyframe=is_kf,
            n_features=len(ff.left),
            n_stereo=int(ff.stereo.valid.sum()),
            n_tracked=n_tracked,
            n_reused=n_reused,
            track_path=track_path,
            draw_uv=draw,
            draw_tracked=tracked if tracked is not None else np.zeros(len(ff.left), dtype=bool),
            timings_ms=timings,
            stereo_sigma=np.zeros(0) if obs_kps is None else self._keypoint_sigma(ff, obs_kps),
            descriptors=(np.zeros((0, 32), np.uint8) if obs_kps is None else ff.left.desc[obs_kps]),
            octaves=np.zeros(0, np.int32) if obs_kps is None else ff.left.octave[obs_kps],
        )


def _record_time(timings: dict[str, float], t0: float, pnp_ms: float) -> None:
    """Tracking's time since `t0` without the PnP's, which is recorded on its own."""
    timings["tracking"] = (time.perf_counter() - t0) * 1e3 - pnp_ms
    timings["pnp"] = pnp_ms
