"""Close and far stereo points (ORB-SLAM's rule, frontend.far_depth_baselines): a new map starts
its landmarks from the close points, and from the nearest far ones only to make up
`min_new_landmarks` (a far point's depth rests on a disparity of a few pixels)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from eurocslam.dataset.calib import CameraCalib, StereoRig, default_rig
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import FrameFeatures
from eurocslam.frontend.features import Features
from eurocslam.frontend.matching import StereoMatches
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.geometry import make_T


def kitti_like_rig() -> StereoRig:
    """KITTI odometry's rectified grey pair (sequences 00-02): 0.54 m baseline, fx 719 px,
    1241 x 376, no distortion (the real excerpt's calibration)."""

    def cam(name: str, x: float) -> CameraCalib:
        return CameraCalib(
            name=name,
            T_body_cam=make_T(np.eye(3), np.array([x, 0.0, 0.0])),
            rate_hz=10.0,
            width=1241,
            height=376,
            fx=718.856,
            fy=718.856,
            cx=607.1928,
            cy=185.2157,
            distortion=(0.0, 0.0, 0.0, 0.0),
            distortion_model="none",
        )

    return StereoRig(cam("cam0", 0.0), cam("cam1", 0.5371657), None)


RIGS = {"euroc_0.11m": default_rig, "kitti_0.54m": kitti_like_rig}


def _first_frame_landmark_depths(
    cfg: FrontendConfig, depths: np.ndarray, rig: StereoRig | None = None
) -> np.ndarray:
    """Depths of the landmarks a new map takes from one frame of stereo points at `depths`."""
    rect = StereoRectifier(rig or default_rig(), cfg.rectify_alpha)
    g = rect.geometry
    rng = np.random.default_rng(0)
    n = depths.size
    u_lo = min(g.fx * g.baseline / depths.min() + 20, g.width / 2)  # uR stays in the image
    uv = np.column_stack([rng.uniform(u_lo, g.width - 20, n), rng.uniform(20, g.height - 20, n)])
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


@pytest.mark.parametrize("rig_name", list(RIGS))
def test_the_rule_at_two_baselines(rig_name: str) -> None:
    """The same rule on EuRoC's 0.11 m rig and KITTI's 0.54 m one: the cut is a depth of 40
    baselines (4.4 m / 21.5 m), so a disparity of fx / 40 px (10.9 px / 18.0 px): a parallax angle
    of 1/40 rad, set by the focal length, not the baseline. In depth noise it is not one rule:
    the relative depth sigma at the cut, sigma_d / d for a disparity sigma sigma_d, is 40 sigma_d
    / fx, 0.92 % on EuRoC and 0.56 % on KITTI at 0.1 px; the KITTI excerpt and the MH_04 replica
    have the same disparities (median 10.7 / 10.4 px, 10th percentile 2.9 / 3.2 px) and the same
    estimated disparity noise (RESULTS.md, "The far-point rule at two baselines")."""
    cfg = FrontendConfig()
    g = StereoRectifier(RIGS[rig_name](), cfg.rectify_alpha).geometry
    far_m = cfg.far_depth_baselines * g.baseline
    cut_px = g.fx * g.baseline / far_m
    assert cut_px == pytest.approx(g.fx / cfg.far_depth_baselines)
    expected = {"euroc_0.11m": (4.40, 10.9, 0.0092), "kitti_0.54m": (21.5, 18.0, 0.0056)}
    m, px, rel = expected[rig_name]
    assert far_m == pytest.approx(m, abs=0.05)
    assert cut_px == pytest.approx(px, abs=0.05)
    assert 0.1 / cut_px == pytest.approx(rel, abs=0.0001)  # sigma_z / z at the cut, 0.1 px
    # behaviour around the cut, in disparities: 1 px above it close, 1 px below far
    close = g.fx * g.baseline / np.linspace(cut_px + 1.0, 4.0 * cut_px, 120)
    far = g.fx * g.baseline / np.linspace(cut_px - 1.0, 1.0, 200)
    got = _first_frame_landmark_depths(cfg, np.concatenate([far, close]), RIGS[rig_name]())
    assert got.size == cfg.min_new_landmarks
    assert np.allclose(got[:120], np.sort(close)) and np.allclose(got[120:], np.sort(far)[:80])
    many_close = g.fx * g.baseline / np.linspace(cut_px + 1.0, 4.0 * cut_px, 250)
    got = _first_frame_landmark_depths(cfg, np.concatenate([far, many_close]), RIGS[rig_name]())
    assert got.size == 250 and got.max() < far_m
