"""Geometric verification of places (places/recognizer.py) on rendered stereo frames: a true
revisit is verified with the right pose, and in a room tiled with one texture, where appearance
proposes a different place as strongly as a revisit, the geometry refuses it (a false loop is
worse than none)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from eurocslam.config import PlacesConfig
from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor
from eurocslam.frontend.projection import pyramid_scales
from eurocslam.geometry import inv_T, se3_log
from eurocslam.pipeline.frames import WorldFrames
from eurocslam.pipeline.places import PlaceStage
from eurocslam.places import default_vocabulary
from eurocslam.places.recognizer import CandidatePoints, PlaceMatch, PlaceRecognizer, PlaceView
from eurocslam.synth import Scene
from places_helpers import far_apart_frames, repetitive_scene


class Views:
    """Stereo frames of a rendered scene as place views, with their true body poses."""

    def __init__(self, scene: Scene) -> None:
        cfg = FrontendConfig()
        self.scene = scene
        self.extractor = Extractor.for_rig(scene.rig, cfg)
        g = self.extractor.geometry
        radius_px = np.deg2rad(cfg.track_radius_deg) * g.fx
        self.recognizer = PlaceRecognizer(
            default_vocabulary(), g, pyramid_scales(cfg), radius_px, PlacesConfig()
        )

    def view(self, k: int) -> PlaceView:
        s = self.scene
        t_ns = int(s.cam_t_ns[k])
        ff = self.extractor.extract(StereoFrame(t_ns, s.image(k, 0)[0], s.image(k, 1)[0]))
        ok = ff.stereo.valid
        uv = np.column_stack([ff.left.uv[:, 0], ff.stereo.uR, ff.left.uv[:, 1]])
        return self.recognizer.view(k, t_ns, uv[ok], ff.left.desc[ok], octave=ff.left.octave[ok])

    def T_world_body(self, k: int) -> np.ndarray:
        return self.scene.T_world_body(float(self.scene.t_s(self.scene.cam_t_ns[k])))

    def points_world(self, v: PlaceView) -> CandidatePoints:
        """The candidate's stereo points in the world, placed with its true pose."""
        T = self.T_world_body(v.key)
        return CandidatePoints(v.p_body @ T[:3, :3].T + T[:3, 3], T)

    def verify(self, query: int, cand: int) -> PlaceMatch | None:
        c = self.view(cand)
        return self.recognizer.verify(self.view(query), c, self.points_world(c))


@pytest.fixture(scope="module")
def tiled() -> Views:
    return Views(repetitive_scene(seed=0))


def test_a_revisit_is_verified_with_its_pose(tiled: Views) -> None:
    """Positive control, in the same tiled room: the same place 0.2 s later is verified and
    the recovered pose is the true one to a centimetre and a fraction of a degree."""
    a, _ = far_apart_frames(tiled.scene)
    m = tiled.verify(a + 4, a)
    assert m is not None
    T_est, inliers = m.T_world_query, m.n_inliers
    T_true = tiled.T_world_body(a + 4)
    assert inliers >= PlacesConfig().min_inliers
    assert np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) < 0.01
    dR = T_est[:3, :3].T @ T_true[:3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 0.5
    # the match says how uncertain it is, and its error is one it allows (chi-square, 6 dof,
    # 99.9 %): the loop gate weighs a loop by this
    xi = se3_log(T_est @ inv_T(T_true))
    assert np.all(np.linalg.eigvalsh(m.cov_world) > 0)
    assert float(xi @ np.linalg.solve(m.cov_world, xi)) < 22.46
    assert np.sqrt(np.trace(m.cov_world[3:, 3:])) < 0.02


@pytest.mark.parametrize("start", [100, 300])
def test_a_look_alike_place_is_not_verified(tiled: Views, start: int) -> None:
    """Two places at least 2 m apart looking 60+ deg apart in the tiled room: they score like
    a revisit and have more descriptor matches (ratio test) than a verified place needs
    inliers; the geometry rejects them both ways."""
    a, b = far_apart_frames(tiled.scene, start=start)
    va, vb = tiled.view(a), tiled.view(b)
    assert va.bow.score(vb.bow) > 0.15
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(va.desc, vb.desc, k=2)
    c = PlacesConfig()
    matched = [p for p in knn if len(p) == 2 and p[0].distance <= c.max_hamming]
    assert sum(p[0].distance < c.ratio * p[1].distance for p in matched) > c.min_inliers
    assert tiled.verify(a, b) is None
    assert tiled.verify(b, a) is None


def test_points_without_a_position_take_no_part(tiled: Views) -> None:
    """A candidate's points that are NaN (far stereo points the map does not hold: the place
    stage leaves them out) take no part: the revisit is still verified with its pose from the
    others, and with none left it is not verified."""
    a, _ = far_apart_frames(tiled.scene)
    cand, query = tiled.view(a), tiled.view(a + 4)
    pts = tiled.points_world(cand)
    full = tiled.recognizer.verify(query, cand, pts)
    assert full is not None
    disparity = cand.stereo_uv[:, 0] - cand.stereo_uv[:, 1]
    half = pts.xyz.copy()
    half[disparity < np.median(disparity)] = np.nan
    m = tiled.recognizer.verify(query, cand, CandidatePoints(half, pts.T_world_body))
    assert m is not None
    assert PlacesConfig().min_inliers <= m.n_inliers < full.n_inliers
    assert np.linalg.norm(m.T_world_query[:3, 3] - tiled.T_world_body(a + 4)[:3, 3]) < 0.01
    # the far half left out: the match knows less
    assert np.trace(m.cov_world) > np.trace(full.cov_world)
    none = CandidatePoints(np.full_like(pts.xyz, np.nan), pts.T_world_body)
    assert tiled.recognizer.verify(query, cand, none) is None


@pytest.mark.parametrize(("baselines", "found"), [(40.0, True), (1e-3, False)])
def test_the_stage_verifies_with_close_points_only(
    tiled: Views, baselines: float, found: bool
) -> None:
    """The place stage verifies a candidate with the map's landmarks and, where the map has
    none, with the candidate's own stereo points closer than `verify_max_depth_baselines`:
    at 40 baselines the revisit is found, with every point far (a tiny bound) it is not."""
    cfg = PlacesConfig(verify_max_depth_baselines=baselines)
    r = tiled.recognizer
    frames = WorldFrames()
    frames.new_segment()
    stage = PlaceStage.create(
        cfg,
        r.geometry,
        r.scales,
        r.radius_px,
        frames,
        lambda seg, ids: np.full((ids.size, 3), np.nan),
    )
    a, _ = far_apart_frames(tiled.scene)
    cand, query = tiled.view(a), tiled.view(a + 4)
    stage.file(cand, 0, 0, tiled.T_world_body(a))
    T = stage.relocalize(query, 0).T_seg_query
    assert (T is not None) == found
    if T is not None:
        assert np.linalg.norm(T[:3, 3] - tiled.T_world_body(a + 4)[:3, 3]) < 0.01
