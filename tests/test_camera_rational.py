"""The rational polynomial camera model (ROS `rational_polynomial`, 8 coefficients) against
OpenCV's own CALIB_RATIONAL_MODEL projection, and its inverse."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from eurocslam.camera_models import PinholeRational, canonical_model_name, make_camera_model

# a wide-angle lens of the kind depthai publishes (k4..k6 in the denominator)
WIDE = PinholeRational(
    600.0, 601.0, 640.0, 400.0, (2.1, 0.9, 0.0004, -0.0003, 0.03, 2.45, 1.6, 0.2)
)


def _points(n: int, max_deg: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    theta = np.radians(rng.uniform(0.0, max_deg, n))
    phi = rng.uniform(-np.pi, np.pi, n)
    z = rng.uniform(0.5, 5.0, n)
    r = np.tan(theta) * z
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def test_projection_equals_opencv() -> None:
    p = _points(500, 55.0)
    ours = WIDE.project(p)
    cv, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), WIDE.K, np.array(WIDE.coeffs))
    np.testing.assert_allclose(ours, cv.reshape(-1, 2), atol=1e-9)


def test_unprojection_inverts_and_jacobian_matches_differences() -> None:
    p = _points(300, 55.0, seed=1)
    uv = WIDE.project(p)
    b = WIDE.unproject(uv)
    np.testing.assert_allclose(b, p / np.linalg.norm(p, axis=1, keepdims=True), atol=1e-9)
    _, J = WIDE.project_jacobian(p)
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        num = (WIDE.project(p + d) - WIDE.project(p - d)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], num, atol=1e-4)


def test_name_count_and_fold() -> None:
    assert canonical_model_name("rational_polynomial") == "rational_polynomial"
    assert WIDE.ros_name == "rational_polynomial" and WIDE.ros_coeffs().size == 8
    with pytest.raises(ValueError, match="takes 8 coefficients, got 5"):
        make_camera_model("rational_polynomial", 1.0, 1.0, 0.0, 0.0, (0.0,) * 5)
    # zero coefficients: the plain pinhole, one to one up to 90 degrees
    flat = make_camera_model("rational_polynomial", 500.0, 500.0, 320.0, 240.0, (0.0,) * 8)
    assert flat.max_angle == pytest.approx(np.pi / 2, abs=1e-3)
    # a denominator that reaches zero bounds the valid region
    pole = PinholeRational(500.0, 500.0, 320.0, 240.0, (0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0))
    assert pole.max_angle < np.arctan(1.0) + 1e-3
