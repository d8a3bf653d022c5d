"""Place recognition for the pipeline: keyframes filed by appearance, candidates verified by
geometry.

Every keyframe gives a `PlaceView`: the descriptors of its stereo observations, the landmark
ids they observe, their points in the keyframe's body frame (triangulated from the stereo pair)
and its bag-of-words vector. A query (a keyframe, or a lost frame's stereo keypoints) takes the
best-scored candidates from the database and verifies them in score order against the
candidate's points *in the caller's world* (`points(key)`: the map's refined positions of its
landmarks where the map has them; a single stereo pair measures depth too coarsely to tell a
centimetre of drift): descriptor matches (Hamming distance, ratio test), PnP-RANSAC on those
matches, then a motion-only refinement on the stereo measurements with outlier rejection. A
candidate with `places.min_inliers` inliers is a `PlaceMatch`: the query's body pose in that
world. The database only proposes; the geometry decides (two places with the same repetitive
texture look alike to any appearance index).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from eurocslam.camera import RectifiedStereo, triangulate_rect
from eurocslam.config import PlacesConfig
from eurocslam.frontend.features import Features
from eurocslam.frontend.tracking import optimize_pose, pnp_ransac, project_map, search_by_projection
from eurocslam.geometry import F64, inv_T
from eurocslam.places.database import KeyframeDatabase
from eurocslam.places.uncertainty import match_covariance, stereo_point_cov
from eurocslam.places.vocabulary import BowVector, Vocabulary

U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class PlaceView:
    """One keyframe (or query frame) as place recognition sees it."""

    key: int  # the caller's key (unique per keyframe)
    t_ns: int
    stereo_uv: F64  # (N, 3) uL, uR, v in rectified pixels
    desc: U8  # (N, 32)
    landmark_ids: NDArray[np.int64]  # (N,) the landmarks observed (-1: none)
    octave: NDArray[np.int32]  # (N,) the keypoints' pyramid octaves
    p_body: F64  # (N, 3) the stereo points in the frame's body frame
    bow: BowVector

    @property
    def nbytes(self) -> int:
        return int(
            self.stereo_uv.nbytes + self.desc.nbytes + self.p_body.nbytes + self.bow.words.nbytes
        ) + int(self.bow.weights.nbytes + self.landmark_ids.nbytes)


@dataclass(frozen=True)
class CandidatePoints:
    """A candidate keyframe's points in the world a match is wanted in, and its pose there."""

    xyz: F64  # (N, 3), rows of the candidate's view; NaN: the point takes no part
    T_world_body: F64


@dataclass(frozen=True)
class PlaceMatch:
    """A verified place: the query's body pose in the world the candidate's points were in,
    and how uncertain it is (`places/uncertainty.py`: a left perturbation in that world,
    [rotation, translation])."""

    key: int  # the candidate's key
    score: float  # its appearance score
    T_world_query: F64
    n_inliers: int
    cov_world: F64  # (6, 6)


class PlaceRecognizer:
    """The keyframe database with its views, and the geometric verification."""

    def __init__(
        self,
        vocabulary: Vocabulary,
        geometry: RectifiedStereo,
        scales: F64,
        radius_px: float,
        cfg: PlacesConfig,
    ) -> None:
        """`scales`: the ORB pyramid's scale per octave; `radius_px`: the projection search
        window at octave 0 (the tracker's)."""
        self.vocabulary = vocabulary
        self.geometry = geometry
        self.scales = scales
        self.radius_px = radius_px
        self.cfg = cfg
        self.db = KeyframeDatabase()
        self._views: dict[int, PlaceView] = {}
        self.n_verified = 0  # candidates verified (for the summary)
        self.verify_ms = 0.0

    def __len__(self) -> int:
        return len(self._views)

    def view(
        self,
        key: int,
        t_ns: int,
        stereo_uv: F64,
        desc: U8,
        landmark_ids: NDArray[np.int64] | None = None,
        octave: NDArray[np.int32] | None = None,
    ) -> PlaceView:
        """A view of stereo observations (rows with a finite uR and a positive disparity);
        `octave`: each keypoint's pyramid octave (default 0)."""
        uv = np.asarray(stereo_uv, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(desc, dtype=np.uint8).reshape(-1, 32)
        ids = np.full(len(uv), -1, np.int64) if landmark_ids is None else landmark_ids
        octv = np.zeros(len(uv), np.int32) if octave is None else octave
        ok = np.isfinite(uv).all(axis=1) & (uv[:, 0] - uv[:, 1] > 0.5)
        uv, d = uv[ok], d[ok]
        ids, octv = np.asarray(ids, dtype=np.int64)[ok], np.asarray(octv, dtype=np.int32)[ok]
        g = self.geometry
        p_rect = triangulate_rect(uv[:, 0], uv[:, 1], uv[:, 2], g)
        T = g.T_body_rect0
        p_body = p_rect @ T[:3, :3].T + T[:3, 3]
        return PlaceView(key, t_ns, uv, d, ids, octv, p_body, self.vocabulary.transform(d))

    def add(self, v: PlaceView) -> None:
        self._views[v.key] = v
        self.db.add(v.key, v.bow)

    def get(self, key: int) -> PlaceView:
        return self._views[key]

    @property
    def memory_bytes(self) -> int:
        return self.db.memory_bytes() + sum(v.nbytes for v in self._views.values())

    def find(
        self,
        query: PlaceView,
        accept: Callable[[int], bool],
        points: Callable[[PlaceView], CandidatePoints],
        exclude_last: int = 0,
        min_score: float = 0.0,
    ) -> PlaceMatch | None:
        """The best verified candidate among the keys `accept` admits (None: no place);
        `points(candidate view)`: its points and pose in the world the match is wanted in,
        asked for only when the descriptors match well enough for the geometry to be tried
        (most candidates fail before: MH_04 replica, 738 of 847). `min_score`: candidates
        scoring lower are not verified (at least `places.min_score`)."""
        c = self.cfg
        for cand in self.db.query(
            query.bow,
            c.candidates,
            exclude=(query.key,),
            exclude_last=exclude_last,
            accept=accept,
            min_score=max(c.min_score, min_score),
        ):
            v = self._views[cand.key]
            m = self._timed(query, v, partial(points, v))
            if m is not None:
                return replace(m, score=cand.score)
        return None

    def verify(self, query: PlaceView, cand: PlaceView, pts: CandidatePoints) -> PlaceMatch | None:
        """The match when the query's keypoints see the candidate's points `pts` (rows of
        `cand`; rows that are NaN take no part); its score is NaN (no database query)."""
        return self._timed(query, cand, lambda: pts)

    def _timed(
        self, query: PlaceView, cand: PlaceView, points: Callable[[], CandidatePoints]
    ) -> PlaceMatch | None:
        t0 = time.perf_counter()
        try:
            matches = self._descriptor_matches(query, cand)
            return None if matches is None else self._verify(query, cand, points(), *matches)
        finally:
            self.n_verified += 1
            self.verify_ms += (time.perf_counter() - t0) * 1e3

    def _descriptor_matches(
        self, query: PlaceView, cand: PlaceView
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]] | None:
        """Rows of the query and of the candidate whose descriptors match (the nearest within
        `max_hamming` and nearer than `ratio` x the second nearest), or None when fewer than
        `min_inliers` do. The two nearest come from one `cv2.batchDistance`: the kernel
        BFMatcher's knnMatch runs, the same rows, without a DMatch object per row (the 847
        matchings of a MH_04 replica run, interleaved: 3.59 against 3.80 ms of CPU each)."""
        c = self.cfg
        if len(query.desc) < c.min_inliers or len(cand.desc) < max(c.min_inliers, 2):
            return None
        dist, nearest = cv2.batchDistance(
            query.desc, cand.desc, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2
        )
        ok = (dist[:, 0] <= c.max_hamming) & (dist[:, 0] < c.ratio * dist[:, 1])
        q = np.flatnonzero(ok)
        if q.size < c.min_inliers:
            return None
        return q, nearest[q, 0].astype(np.intp)

    def _verify(
        self,
        query: PlaceView,
        cand: PlaceView,
        pts: CandidatePoints,
        q: NDArray[np.intp],
        k: NDArray[np.intp],
    ) -> PlaceMatch | None:
        """The geometry of descriptor matches `q` (query rows) <-> `k` (candidate rows)."""
        c, g = self.cfg, self.geometry
        pts_world = pts.xyz
        placed = np.isfinite(pts_world[k]).all(axis=1)  # points without a position: no part
        q, k = q[placed], k[placed]
        if q.size < c.min_inliers:
            return None
        T_rc, inl = pnp_ransac(
            pts_world[k],
            query.stereo_uv[q][:, [0, 2]],
            g,
            None,
            c.pnp_reprojection_px,
            c.pnp_iterations,
        )
        if T_rc is None or inl.sum() < c.min_inliers:
            return None
        # guided: every candidate point projected with that pose and matched nearby (the
        # global matches' near-misses on repetitive texture bias a pose by centimetres), then
        # the pose refined on the stereo measurements, twice
        feats = Features(
            query.stereo_uv[:, [0, 2]], query.octave, np.zeros(len(query.desc)), query.desc
        )
        tree = cKDTree(feats.uv)
        oct_max = self.scales.size - 1
        n = 0
        has_position = np.isfinite(pts_world).all(axis=1)
        for radius in (2.0 * self.radius_px, self.radius_px):
            proj = project_map(T_rc, pts_world, g)
            rows, kps, _ = search_by_projection(
                proj,
                np.nonzero(proj.in_view & has_position)[0],
                cand.desc,
                cand.octave,
                feats,
                query.stereo_uv[:, 1],
                tree,
                self.scales,
                radius,
                c.max_hamming,
                0.9,
            )
            if rows.size < c.min_inliers:
                return None
            sigma = self.scales[np.clip(query.octave[kps], 0, oct_max)]
            T_rc, inl2, _ = optimize_pose(
                T_rc, pts_world[rows], query.stereo_uv[kps], sigma, g, 7.815, 5.991
            )
            n = int(inl2.sum())
            if n < c.min_inliers:
                return None
        # the fit's uncertainty: the inliers' pixels, and the candidate's points as its own
        # stereo pair measured them (a map landmark seen more often is known better: this
        # errs on the side of a wider match)
        rows, kps = rows[inl2], kps[inl2]
        R_world_rect = pts.T_world_body[:3, :3] @ g.T_body_rect0[:3, :3]
        cov_pts = stereo_point_cov(
            cand.stereo_uv[rows], self.scales[np.clip(cand.octave[rows], 0, oct_max)], g
        )
        cov = match_covariance(
            T_rc,
            pts_world[rows],
            R_world_rect @ cov_pts @ R_world_rect.T,
            query.stereo_uv[kps],
            sigma[inl2],
            g,
        )
        return PlaceMatch(cand.key, float("nan"), inv_T(g.T_body_rect0 @ T_rc), n, cov)
