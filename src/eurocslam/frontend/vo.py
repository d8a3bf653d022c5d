"""Stereo visual odometry: `StereoFrontend` + local bundle adjustment in GTSAM at keyframes.

At every keyframe the last `ba_window_keyframes` keyframe poses and the landmarks they observe
are optimised with `GenericStereoFactor3D` (stereo observations) and
`GenericProjectionFactorCal3_S2` (left-only observations), both with `body_P_sensor =
T_body_rect0` so poses stay body poses, under a Huber loss. The `ba_fixed_keyframes` keyframes
before the window observing the same landmarks are held fixed (gauge and continuity, as in
ORB-SLAM's local BA). Observations that stay outliers after the optimisation are dropped. The
optimised landmarks and the keyframe's pose are pushed back into the frontend (`correct`), so
tracking continues on the refined map.

World frame: the first body pose, or `T_world_body_init` (e.g. gravity-aligned from the IMU).
Every frame gets a pose: frames without a tracked pose (NO_IMAGE, LOST) get the frontend's
constant-velocity prediction and are flagged by their `FrontendResult.state`.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.frontend import FrameFeatures, StereoFrontend
from eurocslam.frontend.types import FrontendResult, RectifiedStereo, TrackingState
from eurocslam.geometry import F64


@dataclass
class _Keyframe:
    index: int  # keyframe counter (gtsam key)
    t_ns: int
    T_world_body: F64
    ids: NDArray[np.int64]
    uv: F64  # (N, 3) uL, uR (NaN: mono), v
    sigma: F64  # (N,) pixel sigma factor (octave scale)


def _X(i: int) -> int:
    return gtsam.symbol("x", i)


def _L(i: int) -> int:
    return gtsam.symbol("l", i)


class VisualOdometry:
    """Frontend + local BA. `process(frame)` -> (FrontendResult, T_world_body)."""

    def __init__(
        self,
        rig: StereoRig,
        config: FrontendConfig | None = None,
        T_world_body_init: F64 | None = None,
    ) -> None:
        self.config = config or FrontendConfig()
        self.frontend = StereoFrontend(rig, self.config, T_world_body_init)
        g = self.frontend.rectified
        self._K_stereo = gtsam.Cal3_S2Stereo(g.fx, g.fy, 0.0, g.cx, g.cy, g.baseline)
        self._K_mono = gtsam.Cal3_S2(g.fx, g.fy, 0.0, g.cx, g.cy)
        self._body_P_rect0 = gtsam.Pose3(g.T_body_rect0)
        c = self.config
        huber = gtsam.noiseModel.mEstimator.Huber.Create(c.ba_huber_k)
        # one robust noise model per pyramid octave (sigma = base * octave scale)
        scales = c.orb_scale_factor ** np.arange(c.orb_levels)
        self._octave_scales = scales
        self._noise3 = [
            gtsam.noiseModel.Robust.Create(
                huber, gtsam.noiseModel.Isotropic.Sigma(3, c.ba_pixel_sigma * s)
            )
            for s in scales
        ]
        self._noise2 = [
            gtsam.noiseModel.Robust.Create(
                huber, gtsam.noiseModel.Isotropic.Sigma(2, c.ba_pixel_sigma * s)
            )
            for s in scales
        ]
        self._fixed = gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
        self._chi2_stereo = c.pose_chi2_stereo
        self._chi2_mono = c.pose_chi2_mono
        self.keyframes: deque[_Keyframe] = deque(
            maxlen=c.ba_window_keyframes + c.ba_fixed_keyframes
        )
        self._kf_counter = 0
        self._T_init = None if T_world_body_init is None else np.asarray(T_world_body_init, float)
        self.ba_ms: list[float] = []

    @property
    def rectified(self) -> RectifiedStereo:
        return self.frontend.rectified

    # ---- per frame ------------------------------------------------------------------------
    def process(
        self, frame: StereoFrame, features: FrameFeatures | None = None
    ) -> tuple[FrontendResult, F64]:
        ff = features if features is not None else self.frontend.extract(frame)
        return self.track(ff)

    def track(self, ff: FrameFeatures) -> tuple[FrontendResult, F64]:
        res = self.frontend.track(ff)
        if res.state == TrackingState.INIT and res.T_world_body is not None:
            # a (re-)initialised map: earlier keyframes share no landmarks with it
            self.keyframes.clear()
        T = res.T_world_body
        if res.is_keyframe and T is not None:
            self.keyframes.append(
                _Keyframe(
                    self._kf_counter,
                    res.t_ns,
                    T.copy(),
                    res.landmark_ids.copy(),
                    res.stereo_uv.copy(),
                    res.stereo_sigma.copy(),
                )
            )
            self._kf_counter += 1
            if self.config.ba_enabled and len(self.keyframes) >= 2:
                t0 = time.perf_counter()
                T = self._local_ba()
                ms = (time.perf_counter() - t0) * 1e3
                res.timings_ms["local_ba"] = ms
                self.ba_ms.append(ms)
        if T is None:
            T = self.frontend.predict(res.t_ns)
        if T is None:
            T = self._T_init if self._T_init is not None else np.eye(4)
        return res, T.copy()

    def run(self, frames: Iterable[StereoFrame]) -> Iterator[tuple[FrontendResult, F64]]:
        """Process a frame stream, extraction one frame ahead in a worker thread."""
        for _, ff in self.frontend.stream(frames):
            yield self.track(ff)

    # ---- local bundle adjustment ----------------------------------------------------------
    def _octave_of(self, sigma: F64) -> NDArray[np.intp]:
        """Pyramid octave of each observation from its sigma factor (scale ** octave)."""
        if sigma.size == 0:
            return np.zeros(0, np.intp)
        o = np.rint(np.log(np.maximum(sigma, 1.0)) / np.log(self.config.orb_scale_factor))
        return np.clip(o.astype(np.intp), 0, self._octave_scales.size - 1)

    def _local_ba(self) -> F64:
        c = self.config
        kfs = list(self.keyframes)
        n_fixed = max(1, len(kfs) - c.ba_window_keyframes)
        n_fixed = min(n_fixed, len(kfs) - 1)
        all_ids, n_obs = np.unique(np.concatenate([kf.ids for kf in kfs]), return_counts=True)
        xyz = self.frontend.landmark_positions(all_ids)
        # landmarks still in the map, seen by two keyframes or more (a landmark seen once
        # constrains no pose) and in stereo at least once (well constrained)
        stereo_ids = np.unique(np.concatenate([kf.ids[np.isfinite(kf.uv[:, 1])] for kf in kfs]))
        keep = np.all(np.isfinite(xyz), axis=1) & np.isin(all_ids, stereo_ids) & (n_obs >= 2)
        ids, xyz, n_obs = all_ids[keep], xyz[keep], n_obs[keep]
        if ids.size > c.ba_max_landmarks:
            # the most observed landmarks constrain the window best; ties broken by a hash of
            # the id (an unbiased sample: ids follow creation order, which is depth order)
            mix = (ids.astype(np.uint64) * np.uint64(2654435761)) % np.uint64(1 << 32)
            order = np.lexsort((mix, -n_obs))[: c.ba_max_landmarks]
            order.sort()
            ids, xyz = ids[order], xyz[order]
        if ids.size == 0:
            return kfs[-1].T_world_body
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        # (graph index, kf position, observation row, stereo?)
        factor_index: list[tuple[int, int, int, bool]] = []
        for pos, kf in enumerate(kfs):
            values.insert(_X(kf.index), gtsam.Pose3(kf.T_world_body))
            if pos < n_fixed:
                graph.add(
                    gtsam.PriorFactorPose3(_X(kf.index), gtsam.Pose3(kf.T_world_body), self._fixed)
                )
            obs = np.nonzero(np.isin(kf.ids, ids))[0]
            octave = self._octave_of(kf.sigma)
            for r in obs.tolist():
                lid = int(kf.ids[r])
                uL, uR, v = kf.uv[r]
                o = int(octave[r])
                if np.isfinite(uR):
                    f = gtsam.GenericStereoFactor3D(
                        gtsam.StereoPoint2(uL, uR, v),
                        self._noise3[o],
                        _X(kf.index),
                        _L(lid),
                        self._K_stereo,
                        self._body_P_rect0,
                    )
                    factor_index.append((graph.size(), pos, r, True))
                else:
                    f = gtsam.GenericProjectionFactorCal3_S2(
                        np.array([uL, v]),
                        self._noise2[o],
                        _X(kf.index),
                        _L(lid),
                        self._K_mono,
                        self._body_P_rect0,
                    )
                    factor_index.append((graph.size(), pos, r, False))
                graph.add(f)
        for lid, p in zip(ids.tolist(), xyz, strict=True):
            values.insert(_L(lid), p)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(c.ba_max_iterations)
        params.setRelativeErrorTol(1e-4)
        try:
            result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        except RuntimeError:
            # an indeterminate system (degenerate geometry): keep the tracked estimates
            return kfs[-1].T_world_body
        # write back keyframe poses
        for kf in kfs:
            kf.T_world_body = result.atPose3(_X(kf.index)).matrix()
        new_xyz = np.array([result.atPoint3(_L(lid)) for lid in ids.tolist()]).reshape(-1, 3)
        # drop observations that remain outliers (whitened error without the robust loss)
        drop: dict[int, list[int]] = {}
        for gi, pos, r, is_stereo in factor_index:
            e = graph.at(gi).unwhitenedError(result)
            sigma = c.ba_pixel_sigma * float(kfs[pos].sigma[r])
            chi2 = float(e @ e) / (sigma * sigma)
            if chi2 > (self._chi2_stereo if is_stereo else self._chi2_mono):
                drop.setdefault(pos, []).append(r)
        for pos, rows in drop.items():
            kf = kfs[pos]
            m = np.ones(kf.ids.size, dtype=bool)
            m[rows] = False
            kf.ids, kf.uv, kf.sigma = kf.ids[m], kf.uv[m], kf.sigma[m]
        self.frontend.correct(kfs[-1].T_world_body, (ids, new_xyz))
        return kfs[-1].T_world_body
