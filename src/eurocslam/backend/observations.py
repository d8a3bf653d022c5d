"""A keyframe's stereo observations into the factor graph: which ones (the cap per keyframe, spread
over the image), under which landmark keys, and the anchors of re-found landmarks.

The smoother takes at most `backend.max_landmarks_per_keyframe` observations per keyframe (its
update cost grows fast with them), spread over the image (4 x 3 cells, round-robin), in each cell
landmarks already in the graph first, then the nearest; the final batch takes up to
`final_max_landmarks_per_keyframe`, the rest picked the same way and kept for it alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L

from eurocslam.backend.factors import StereoModel, huber
from eurocslam.backend.landmarks import LandmarkKeys
from eurocslam.camera import bucket_select
from eurocslam.config import BackendConfig
from eurocslam.geometry import F64


@dataclass(frozen=True)
class StereoAdded:
    """A keyframe's stereo observations as `StereoObservations.add` turned them into graph
    pieces: the stereo factors (in order), the new landmarks' initial positions and the
    timestamps of every landmark it observes (new or re-observed), the factors the global graph
    takes instead (by index in `factors`: those of landmarks whose smoother key is not their
    first), priors for the smoother alone (re-found landmarks anchored at their last position),
    observations beyond the smoother's cap for the final batch alone, and how many landmarks
    are new."""

    factors: list[gtsam.NonlinearFactor]
    new_points: list[tuple[int, F64]]  # (gtsam key, initial position)
    stamps: dict[int, float]
    subst: dict[int, gtsam.NonlinearFactor]
    anchors: list[gtsam.NonlinearFactor]
    final_only: list[tuple[int, int, float, float, float, float]]
    n_new: int

    @property
    def n_factors(self) -> int:
        return len(self.factors)


class StereoObservations:
    """Stereo observations of keyframes -> factors on landmark keys."""

    def __init__(
        self, cfg: BackendConfig, inertial: bool, stereo: StereoModel, lms: LandmarkKeys
    ) -> None:
        self.cfg = cfg
        self.inertial = inertial
        self.stereo = stereo
        self.lms = lms
        # a landmark the smoother let go and the tracker re-found (map reuse) is anchored at its
        # last smoothed position: the online estimate stays in the frame of the map it returns
        # to instead of drifting away from it (`_anchor`). The smoother alone takes these
        # priors; the final batch has the landmark's observations then and now on one variable
        self._fixed_anchor: gtsam.noiseModel.Base | None = None
        if cfg.refound_prior_sigma_m > 0:
            self._fixed_anchor = gtsam.noiseModel.Isotropic.Sigma(3, cfg.refound_prior_sigma_m)
            if cfg.refound_prior_huber:
                self._fixed_anchor = huber(self._fixed_anchor, cfg.huber_k)

    def add(
        self,
        k: int,
        T_world_body: F64,
        landmark_ids: np.ndarray,
        stereo_uv: F64,
        stereo_sigma: F64 | None,
        tk: float,
        after_loss: bool = False,
    ) -> StereoAdded:
        """Keyframe `k`'s observations as graph pieces (`StereoAdded`), its landmarks stamped
        at `tk`. `after_loss`: the keyframe was found again after a loss; landmarks the smoother
        held before come first."""
        b = self.cfg
        st = self.stereo.geometry
        lms = self.lms
        ids = np.asarray(landmark_ids, dtype=np.int64)
        uv = np.asarray(stereo_uv, dtype=np.float64).reshape(-1, 3)
        scale = (
            np.ones(len(uv))
            if stereo_sigma is None or len(stereo_sigma) != len(uv)
            else np.round(np.asarray(stereo_sigma, dtype=np.float64), 3)
        )
        anchors: list[gtsam.NonlinearFactor] = []
        disp = uv[:, 0] - uv[:, 1]
        ok = np.isfinite(uv).all(axis=1) & (disp >= b.min_disparity_px)
        depth = np.where(ok, st.fx * st.baseline / np.where(ok, disp, 1.0), np.inf)
        idx = np.nonzero(ok)[0]
        cap = b.max_landmarks_per_keyframe if self.inertial else b.max_landmarks_per_keyframe_no_imu
        final_cap = max(cap, b.final_max_landmarks_per_keyframe) if b.final_batch else cap
        extra = idx[:0]
        if idx.size > cap:
            # spread over the image (4 x 3 cells, round-robin), in each cell landmarks the
            # smoother holds first, after a loss then those it held before (they tie now to
            # then; in ordinary flight preferring them over near ones cost accuracy: full-length
            # MH_02 replica 3.1 -> 5.2 mm), then the nearest: the nearest alone can crowd one
            # region
            active = np.array([lms.is_active(int(ids[i])) for i in idx], dtype=bool)
            seen = (
                np.array([lms.was_smoothed(int(ids[i])) for i in idx], dtype=bool)
                if after_loss
                else np.zeros(idx.size, dtype=bool)
            )
            priority = np.where(active, 2e6, np.where(seen, 1e6, 0.0)) - depth[idx]
            pick = bucket_select(uv[idx][:, [0, 2]], priority, cap, st.width, st.height, 4, 3)
            rest = np.setdiff1d(np.arange(idx.size), pick)
            if final_cap > cap:  # the final batch's share, picked the same way from the rest
                more = bucket_select(
                    uv[idx[rest]][:, [0, 2]],
                    priority[rest],
                    final_cap - cap,
                    st.width,
                    st.height,
                    4,
                    3,
                )
                extra = idx[rest[more]]
            idx = idx[pick]
        T_world_rect0 = np.asarray(T_world_body) @ st.T_body_rect0
        info = None  # the observations' information in the world frame, for later anchors
        if b.refound_prior_views and idx.size:
            R = T_world_rect0[:3, :3]
            info_rect = self.stereo.point_information(uv[idx], np.asarray(scale[idx], np.float64))
            info = np.einsum("ij,njk,lk->nil", R, info_rect, R)

        def world_point(i: int) -> F64:
            z = depth[i]
            Xc = np.array([(uv[i, 0] - st.cx) * z / st.fx, (uv[i, 2] - st.cy) * z / st.fy, z])
            return cast(F64, T_world_rect0[:3, :3] @ Xc + T_world_rect0[:3, 3])

        n_new = 0
        factors: list[gtsam.NonlinearFactor] = []
        new_points: list[tuple[int, F64]] = []
        stamps: dict[int, float] = {}
        subst: dict[int, gtsam.NonlinearFactor] = {}
        final_only: list[tuple[int, int, float, float, float, float]] = []
        for n_obs, i in enumerate(idx.tolist()):
            fid = int(ids[i])
            key_i = lms.key_of.get(fid)
            if key_i is None or not lms.active[key_i]:
                old = key_i
                key_i = lms.new_key(fid, k)
                Xw = world_point(i)
                new_points.append((L(key_i), Xw))
                lms.pos[key_i] = Xw
                n_new += 1
                if self._fixed_anchor is not None and old is not None and lms.smoothed[old]:
                    a = self._anchor(old, Xw, uv[i], float(scale[i]), T_world_rect0)
                    if a is not None:
                        anchors.append(gtsam.PriorFactorPoint3(L(key_i), lms.pos[old], a))
            stamps[L(key_i)] = tk  # new or re-observed: (re-)stamp
            obs = (uv[i, 0], uv[i, 1], uv[i, 2], float(scale[i]))
            gkey = int(lms.gkey[key_i])
            lms.nobs[gkey] += 1
            if info is not None:
                lms.info[gkey] += info[n_obs]
            if gkey != key_i:
                subst[len(factors)] = self.stereo.factor(k, gkey, *obs)
            factors.append(self.stereo.factor(k, key_i, *obs))
        # beyond the smoother's cap: observations for the final batch alone. A landmark not yet
        # known gets a key that the smoother never holds (it re-keys it if it picks it later)
        for i in extra.tolist():
            fid = int(ids[i])
            key_i = lms.key_of.get(fid)
            if key_i is None:
                key_i = lms.new_key(fid, k)
                lms.active[key_i] = False
                lms.pos[key_i] = world_point(i)
            gkey = int(lms.gkey[key_i])
            lms.nobs[gkey] += 1
            final_only.append((k, gkey, uv[i, 0], uv[i, 1], uv[i, 2], scale[i]))
        return StereoAdded(factors, new_points, stamps, subst, anchors, final_only, n_new)

    def _anchor(
        self, old: int, p_new: F64, uv: F64, scale: float, T_world_rect0: F64
    ) -> gtsam.noiseModel.Base | None:
        """The noise of the anchor holding a re-found landmark at its archived position (key
        index `old`), or None for no anchor. The archived position is known to the sigma
        (`refound_prior_sigma_m`: the poses it was mapped from), plus with `refound_prior_views`
        the inverse of the information of its observations the smoother took (how well its
        views fixed it). `refound_prior_gate_chi2` (0: always): it and the re-finding stereo
        point `p_new` (world) agree within that covariance and the stereo triangulation's
        (chi-square, 3 DoF), as a loop must agree with the estimator's uncertainty before it
        moves the estimate. `refound_prior_stereo`: the anchor's covariance adds the
        triangulation's. Robust with `refound_prior_huber`."""
        b, lms = self.cfg, self.lms
        shaped = b.refound_prior_stereo or b.refound_prior_views  # a covariance, not the sigma
        if b.refound_prior_gate_chi2 <= 0 and not shaped:
            return self._fixed_anchor
        cov_old = b.refound_prior_sigma_m**2 * np.eye(3)
        if b.refound_prior_views:
            info = lms.info[lms.gkey[old]]
            if np.linalg.det(info) > 0:
                cov_old = cov_old + np.linalg.inv(info)
        R = T_world_rect0[:3, :3]
        cov_new = R @ self.stereo.point_covariance(uv[0], uv[1], uv[2], scale) @ R.T
        if b.refound_prior_gate_chi2 > 0:
            d = np.asarray(lms.pos[old], dtype=np.float64) - p_new
            if not d @ np.linalg.solve(cov_new + cov_old, d) <= b.refound_prior_gate_chi2:
                return None
        if not shaped:
            return self._fixed_anchor
        cov = cov_new + cov_old if b.refound_prior_stereo else cov_old
        noise: gtsam.noiseModel.Base = gtsam.noiseModel.Gaussian.Covariance(cov)
        return huber(noise, b.huber_k) if b.refound_prior_huber else noise
