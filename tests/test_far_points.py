"""Close and far stereo points (ORB-SLAM's rule, frontend.far_depth_baselines): a new map starts
its landmarks from the close points, and from the nearest far ones only to make up
`min_new_landmarks` (a far point's depth rests on a disparity of a few pixels)."""

from __future__ import annotations

import dataclasses

import numpy as np

from eurocslam.dataset.calib import default_rig
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import FrameFeatures
from eurocslam.frontend.features import Features
from eurocslam.frontend.matching import StereoMatches
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.frontend.tracker import StereoTracker


def _first_frame_landmark_depths(cfg: FrontendConfig, depths: np.ndarray) -> np.ndarray:
    """Depths of the landmarks a new map takes from one frame of stereo points at `depths`."""
    rect = StereoRectifier(default_rig(), cfg.rectify_alpha)
    g = rect.geometry
    rng = np.random.default_rng(0)
    n = depths.size
    uv = np.column_stack([rng.uniform(250, g.width - 20, n), rng.uniform(20, g.height - 20, n)])
    uR = uv[:, 0] - g.fx * g.baseline / depths
    left = Features(uv, np.zeros(n, np.int32), np.ones(n), rng.integers(0, 256, (n, 32), np.uint8))
    right = Features(np.column_stack([uR, uv[:, 1]]), left.octave, left.response, left.desc.copy())
    ff = FrameFeatures(0, None, left, right, StereoMatches(uR, depths, np.arange(n)))
    fr = StereoTracker(rect, cfg).track(ff, np.eye(4))
    d = fr.stereo_uv[:, 0] - fr.stereo_uv[:, 1]
    return np.sort(g.fx * g.baseline / d)


def test_far_points_only_make_up_the_minimum() -> None:
    cfg = FrontendConfig()
    b = StereoRectifier(default_rig(), cfg.rectify_alpha).geometry.baseline
    far_m = cfg.far_depth_baselines * b  # 4.4 m on EuRoC's rig
    close = np.linspace(1.0, 0.9 * far_m, 120)
    far = np.linspace(1.1 * far_m, 8 * far_m, 200)
    got = _first_frame_landmark_depths(cfg, np.concatenate([far, close]))
    assert got.size == cfg.min_new_landmarks == 200
    assert np.allclose(got[:120], close) and np.allclose(got[120:], far[:80])  # nearest far
    # enough close points: no far one at all
    many_close = np.linspace(1.0, 0.9 * far_m, 250)
    got = _first_frame_landmark_depths(cfg, np.concatenate([far, many_close]))
    assert got.size == 250 and got.max() < far_m
    # the rule off: every stereo point, nearest first, up to max_new_landmarks_per_keyframe
    off = dataclasses.replace(cfg, far_depth_baselines=0.0)
    got = _first_frame_landmark_depths(off, np.concatenate([far, close]))
    assert got.size == 320


def test_stereo_inertial_runs_take_their_own_far_rule() -> None:
    cfg = FrontendConfig()
    assert cfg.for_mode(inertial=False) is cfg
    inertial = cfg.for_mode(inertial=True)
    assert inertial.far_depth_baselines == cfg.far_depth_baselines_inertial == 0.0
    assert dataclasses.replace(inertial, far_depth_baselines=cfg.far_depth_baselines) == cfg
