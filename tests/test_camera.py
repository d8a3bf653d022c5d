"""The core camera model: one rectification, importing no frontend / backend / I/O code."""

from __future__ import annotations

import numpy as np
import pytest

from eurocslam.camera import (
    project_rect,
    rectify_stereo,
    rectifying_rotations,
    triangulate_rect,
)
from eurocslam.dataset.calib import default_rig
from eurocslam.dataset.calib_sources import tumvi_rig
from eurocslam.frontend.stereo import StereoRectifier, raw_to_rect
from eurocslam.geometry import inv_T
from eurocslam.io.ros2_calib import stereo_camera_infos
from import_helpers import modules_loaded_by


def test_camera_module_imports_no_stage_or_io_code() -> None:
    stages = ("eurocslam.frontend", "eurocslam.backend", "eurocslam.io", "eurocslam.pipeline")
    assert not sorted(
        m for m in modules_loaded_by("import eurocslam.camera") if m.startswith(stages)
    )


def test_rectifier_uses_the_shared_rectification() -> None:
    rig = default_rig()
    for alpha in (0.0, 0.5):
        rect = rectify_stereo(rig, alpha)
        r = StereoRectifier(rig, alpha)
        assert rect.alpha == alpha
        assert np.array_equal(r.P0, rect.P0) and np.array_equal(r.P1, rect.P1)
        assert np.array_equal(r.R_rect0_cam0, rect.R_rect0_cam0)
        assert np.array_equal(r.R_rect1_cam1, rect.R_rect1_cam1)
        g, h = r.geometry, rect.geometry
        assert (g.fx, g.fy, g.cx, g.cy, g.baseline) == (h.fx, h.fy, h.cx, h.cy, h.baseline)
        assert np.array_equal(g.T_body_rect0, h.T_body_rect0)
    # the alpha changes the rectified camera
    assert not np.array_equal(rectify_stereo(rig, 0.0).P0, rectify_stereo(rig, 0.5).P0)


def test_project_and_triangulate_are_inverse() -> None:
    g = rectify_stereo(default_rig()).geometry
    p = np.array([[0.3, -0.2, 4.0], [-1.0, 0.5, 9.0]])
    m = project_rect(p, g)
    assert np.allclose(triangulate_rect(m[:, 0], m[:, 1], m[:, 2], g), p)


# ---- a fisheye rig: rectified through its camera models -------------------------------------


def test_rotations_are_opencvs() -> None:
    """`rectifying_rotations` is Bouguet's, as cv2.stereoRectify computes it."""
    rig = default_rig()
    R0, R1 = rectifying_rotations(rig.T_cam1_cam0)
    rect = rectify_stereo(rig)
    np.testing.assert_allclose(R0, rect.R_rect0_cam0, atol=1e-12)
    np.testing.assert_allclose(R1, rect.R_rect1_cam1, atol=1e-12)


def _points_in_view(rect: StereoRectifier, n: int = 300) -> np.ndarray:
    """Points (rect0 frame) inside the rectified image, 0.5-10 m away."""
    rng = np.random.default_rng(0)
    g = rect.geometry
    u, v = rng.uniform(0, g.width - 1, n), rng.uniform(0, g.height - 1, n)
    z = rng.uniform(0.5, 10.0, n)
    return np.column_stack([(u - g.cx) / g.fx * z, (v - g.cy) / g.fy * z, z])


def test_fisheye_rectification_is_exact() -> None:
    """TUM-VI's rig: a point seen by both raw fisheyes lands on one row of the rectified pair,
    at the disparity fx b / z, and raw <-> rectified round trips."""
    rig = tumvi_rig()
    r = StereoRectifier(rig, 0.0, 120.0)
    rect, g = r.rectification, r.geometry
    assert not rect.passthrough and rect.fov_deg == 120.0
    assert 140.0 < rect.fov_limit_deg < 160.0  # TUM-VI's 512 px sensor: about 150 degrees
    assert g.fx == pytest.approx(256.0 / np.tan(np.radians(60.0)))
    assert g.baseline == pytest.approx(rig.baseline, abs=1e-12)
    p_r0 = _points_in_view(r)
    p_b = p_r0 @ g.T_body_rect0[:3, :3].T + g.T_body_rect0[:3, 3]
    raw = []
    for cam in (rig.cam0, rig.cam1):
        T = inv_T(cam.T_body_cam)
        raw.append(cam.model.project(p_b @ T[:3, :3].T + T[:3, 3]))
    left = r.raw_to_rect0(raw[0])
    right = raw_to_rect(raw[1], rig.cam1, r.R_rect1_cam1, r.P1)
    expect = project_rect(p_r0, g)
    np.testing.assert_allclose(left, expect[:, [0, 2]], atol=1e-8)
    np.testing.assert_allclose(right[:, 0], expect[:, 1], atol=1e-8)
    np.testing.assert_allclose(right[:, 1], left[:, 1], atol=1e-8)
    np.testing.assert_allclose(r.rect0_to_raw(left), raw[0], atol=1e-8)


def test_fisheye_fov_is_capped_where_both_cameras_see_everything() -> None:
    rig = tumvi_rig()
    wide = rectify_stereo(rig, fov_deg=170.0)
    assert wide.fov_deg == wide.fov_limit_deg < 170.0
    r = StereoRectifier(rig, 0.0, 170.0)
    black = np.zeros((512, 512), np.uint8) + 200
    for img in (r.rectify_left(black), r.rectify_right(black)):
        assert img.min() == 200  # every rectified pixel comes from the raw image
    # at the cap the remap tables reach the raw images' borders
    narrow = rectify_stereo(rig, fov_deg=90.0)
    assert narrow.fov_deg == 90.0 and narrow.geometry.fx == pytest.approx(256.0)


def test_fisheye_camera_info_is_equidistant() -> None:
    rig = tumvi_rig()
    i0, i1 = stereo_camera_infos(rig, 0.0, 110.0)
    assert i0.distortion_model == i1.distortion_model == "equidistant"
    np.testing.assert_array_equal(i0.D, rig.cam0.distortion)
    assert len(i1.D) == 4
    rect = rectify_stereo(rig, fov_deg=110.0)
    np.testing.assert_array_equal(i1.P, rect.P1)
    assert i1.P[0, 3] == pytest.approx(-rect.geometry.fx * rect.geometry.baseline)
    e0, _ = stereo_camera_infos(default_rig())
    assert e0.distortion_model == "plumb_bob" and len(e0.D) == 5


def test_focal_sized_rectification_keeps_the_centres_resolution() -> None:
    """`rectify_size: focal`: the rectified pinhole keeps cam0's focal length and its image
    grows with the field of view; raw-size frames still pass the frontend's size check."""
    from eurocslam.camera import rectified_size
    from eurocslam.frontend.config import FrontendConfig
    from eurocslam.frontend.extraction import Extractor

    rig = tumvi_rig()
    assert rectified_size(rig, 120.0, "image") == (512, 512)
    assert rectified_size(rig, 120.0, "focal") == (662, 662)
    r = StereoRectifier(rig, 0.0, 120.0, "focal")
    g = r.geometry
    assert (g.width, g.height) == (662, 662) and g.fx == pytest.approx(rig.cam0.fx, rel=2e-3)
    assert r.rectify_left(np.zeros((512, 512), np.uint8)).shape == (662, 662)
    p = _points_in_view(r, 50)
    raw = r.rect0_to_raw(project_rect(p, g)[:, [0, 2]])
    np.testing.assert_allclose(r.raw_to_rect0(raw), project_rect(p, g)[:, [0, 2]], atol=1e-8)
    ex = Extractor.for_rig(rig, FrontendConfig(rectify_fov_deg=120.0, rectify_size="focal"))
    from eurocslam.dataset.types import StereoFrame

    img = np.random.default_rng(0).integers(0, 255, (512, 512), dtype=np.uint8)
    assert ex.frame_problem(StereoFrame(0, img, img)) is None
    assert ex.frame_problem(StereoFrame(0, img[:500], img)) == "size"


def test_sigma_scale_is_the_resampling_stretch() -> None:
    """Rectified pixels per raw pixel: 1 for EuRoC's pinhole rig (unchanged weights), the
    square root of the area ratio of the rect -> raw map for a fisheye, at least 1."""
    uv = np.array([[10.0, 10.0], [300.0, 200.0]])
    assert StereoRectifier(default_rig()).sigma_scale(uv).tolist() == [1.0, 1.0]
    r = StereoRectifier(tumvi_rig(), 0.0, 90.0)
    pts = np.array([[255.5, 255.5], [5.0, 255.5], [5.0, 5.0], [400.0, 100.0]])
    h = 0.5
    eu, ev = np.array([h, 0.0]), np.array([0.0, h])
    du = (r.rect0_to_raw(pts + eu) - r.rect0_to_raw(pts - eu)) / (2 * h)
    dv = (r.rect0_to_raw(pts + ev) - r.rect0_to_raw(pts - ev)) / (2 * h)
    area = np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0])
    np.testing.assert_allclose(r.sigma_scale(pts), np.maximum(1 / np.sqrt(area), 1), rtol=2e-2)
    assert r.sigma_scale(pts)[0] == pytest.approx(256.0 / tumvi_rig().cam0.fx, rel=1e-2)
    assert r.sigma_scale(pts)[2] > 2.5  # the corner: a raw pixel over ~2.8 rectified ones
    wide = StereoRectifier(tumvi_rig(), 0.0, 150.0)
    assert wide.sigma_scale(pts[:1])[0] == 1.0  # downsampled centre: a rectified pixel


def test_keypoint_sigma_is_the_octave_with_the_stretch_in_quadrature() -> None:
    """A rectified keypoint's sigma: its octave scale where the rectification does not stretch
    (every pinhole rig: EuRoC's weights are the octave scales, bit for bit), and the stretch s
    only in quadrature, sqrt(octave^2 + (s^2 - 1) / 3), on a fisheye: not octave x s."""
    from eurocslam.frontend.stereo import RESAMPLING_SIGMA

    octave = 1.2 ** np.arange(4, dtype=np.float64)
    uv = np.array([[10.0, 10.0], [300.0, 200.0], [376.0, 240.0], [700.0, 470.0]])
    euroc = StereoRectifier(default_rig())
    assert euroc.keypoint_sigma(octave, uv).tolist() == octave.tolist()
    r = StereoRectifier(tumvi_rig(), 0.0, 120.0)
    pts = np.array([[255.5, 255.5], [100.0, 255.5], [20.0, 255.5], [5.0, 5.0]])
    s = r.sigma_scale(pts)
    assert s[0] == 1.0 and s[2] > 1.8 and s[3] > 2.8  # centre downsampled; edges stretched
    sig = r.keypoint_sigma(np.ones(4), pts)
    assert sig[0] == 1.0  # no stretch: the octave scale
    np.testing.assert_allclose(sig, np.sqrt(1.0 + RESAMPLING_SIGMA**2 * (s * s - 1.0)))
    assert np.all(sig <= s) and sig[3] < 0.7 * s[3]  # below the old octave x stretch
    # a coarse octave already locates the keypoint coarser than the raw pixel: the stretch
    # adds little to it
    coarse = r.keypoint_sigma(np.full(4, 1.2**5), pts)
    assert np.all(coarse >= 1.2**5) and coarse[2] < 1.07 * 1.2**5


def test_fov_zero_keeps_the_centres_focal_length() -> None:
    from eurocslam.camera import centre_keeping_fov_deg

    rig = tumvi_rig()
    assert centre_keeping_fov_deg(rig) == pytest.approx(106.55, abs=0.01)
    r = rectify_stereo(rig, fov_deg=0.0)
    assert r.fov_deg == pytest.approx(106.55, abs=0.01)
    assert r.geometry.fx == pytest.approx(rig.cam0.fx, rel=1e-9)
    assert r.geometry.width == rig.cam0.width
