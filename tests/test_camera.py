"""The core camera model: one rectification, importing no frontend / backend / I/O code."""

from __future__ import annotations

import numpy as np

from eurocslam.camera import project_rect, rectify_stereo, triangulate_rect
from eurocslam.dataset.calib import default_rig
from eurocslam.frontend.stereo import StereoRectifier
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
