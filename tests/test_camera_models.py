"""Camera models: each against OpenCV's own implementation, round trips, analytic Jacobians
against finite differences, the valid region, and the model registry."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from eurocslam.camera_models import (
    MODELS,
    CameraModel,
    Pinhole,
    PinholeEquidistant,
    PinholeRadTan,
    canonical_model_name,
    make_camera_model,
)

# TUM-VI's cam0 (dso/camchain.yaml of the 512x512 sequences) and EuRoC's cam0
TUMVI = PinholeEquidistant(
    190.97847715128717,
    190.9733070521226,
    254.93170605935475,
    256.8974428996504,
    (0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182),
)
EUROC = PinholeRadTan(
    458.654, 457.296, 367.215, 248.375, (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
)
RADTAN5 = PinholeRadTan(400.0, 410.0, 320.0, 240.0, (-0.2, 0.05, 0.001, -0.002, 0.01))
PINHOLE = Pinhole(718.856, 718.856, 607.1928, 185.2157)


def _rays(n: int, max_deg: float, seed: int = 0) -> np.ndarray:
    """Points at angles up to `max_deg` from the optical axis, at 0.5-20 m."""
    rng = np.random.default_rng(seed)
    theta = np.radians(max_deg) * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(-np.pi, np.pi, n)
    d = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    return d * rng.uniform(0.5, 20.0, (n, 1))


@pytest.mark.parametrize("model", [EUROC, RADTAN5])
def test_radtan_is_opencv(model: PinholeRadTan) -> None:
    p = _rays(2000, 45.0)
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), model.K, np.array(model.coeffs))
    np.testing.assert_allclose(model.project(p), ref.reshape(-1, 2), atol=1e-8)


def test_equidistant_is_opencv_fisheye() -> None:
    p = _rays(2000, 85.0)
    ref, _ = cv2.fisheye.projectPoints(
        p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), TUMVI.K, np.array(TUMVI.coeffs)
    )
    np.testing.assert_allclose(TUMVI.project(p), ref.reshape(-1, 2), atol=1e-8)
    uv = TUMVI.project(p)
    und = cv2.fisheye.undistortPoints(
        uv.reshape(-1, 1, 2), TUMVI.K, np.array(TUMVI.coeffs), criteria=(3, 50, 1e-14)
    ).reshape(-1, 2)
    b = TUMVI.unproject(uv)
    np.testing.assert_allclose(b[:, :2] / b[:, 2:], und, atol=1e-7)


@pytest.mark.parametrize(
    ("model", "max_deg"), [(EUROC, 50.0), (RADTAN5, 40.0), (PINHOLE, 60.0), (TUMVI, 110.0)]
)
def test_round_trips(model: CameraModel, max_deg: float) -> None:
    p = _rays(3000, max_deg, seed=1)
    uv = model.project(p)
    assert np.isfinite(uv).all()
    b = model.unproject(uv)
    np.testing.assert_allclose(b, p / np.linalg.norm(p, axis=1, keepdims=True), atol=1e-10)
    np.testing.assert_allclose(model.project(b), uv, atol=1e-7)


@pytest.mark.parametrize("model", [EUROC, RADTAN5, PINHOLE, TUMVI])
def test_project_jacobian_matches_finite_differences(model: CameraModel) -> None:
    p = _rays(300, 100.0 if model is TUMVI else 40.0, seed=2)
    p[0] = [0.0, 0.0, 2.0]  # on the optical axis
    uv, J = model.project_jacobian(p)
    np.testing.assert_allclose(uv, model.project(p), atol=1e-12)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        num = (model.project(p + e) - model.project(p - e)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], num, atol=1e-4 * model.fx, rtol=1e-5)


@pytest.mark.parametrize("model", [EUROC, PINHOLE, TUMVI])
def test_unproject_jacobian_matches_finite_differences(model: CameraModel) -> None:
    uv = model.project(_rays(200, 100.0 if model is TUMVI else 40.0, seed=3))
    b, J = model.unproject_jacobian(uv)
    np.testing.assert_allclose(b, model.unproject(uv), atol=1e-15)
    np.testing.assert_allclose(np.einsum("ni,nij->nj", b, J), 0.0, atol=1e-12)  # on the sphere
    h = 1e-4
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        num = (model.unproject(uv + e) - model.unproject(uv - e)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], num, atol=1e-8)


def test_fisheye_sees_behind_the_image_plane() -> None:
    """A ray 100 degrees off the axis (z < 0) projects; the pinhole models refuse z <= 0."""
    p = np.array([[np.sin(np.radians(100.0)), 0.0, np.cos(np.radians(100.0))]])
    assert np.isfinite(TUMVI.project(p)).all()
    assert np.isnan(EUROC.project(p)).all() and np.isnan(PINHOLE.project(p)).all()
    assert TUMVI.max_angle == pytest.approx(np.pi)  # TUM-VI's polynomial never folds


def test_valid_region_ends_where_the_polynomial_folds() -> None:
    folding = PinholeEquidistant(190.0, 190.0, 256.0, 256.0, (-0.2, 0.0, 0.0, 0.0))
    # d theta_d / d theta = 1 - 0.6 theta^2 = 0 at theta = 1.29 rad
    assert folding.max_angle == pytest.approx(np.sqrt(1 / 0.6), abs=2e-3)
    r_max = folding.fx * folding.max_theta_d
    uv = np.array([[256.0 + r_max - 1.0, 256.0], [256.0 + r_max + 1.0, 256.0]])
    assert folding.valid(uv).tolist() == [True, False]
    assert np.isnan(folding.project(np.array([[1.0, 0.0, -0.5]]))).all()  # beyond the fold
    mask = folding.valid_mask(512, 512)
    assert mask[256, 256] and not mask[0, 0]
    assert TUMVI.valid_mask(512, 512).all()
    # radial-tangential: EuRoC's never folds; a strong barrel does
    assert EUROC.max_angle == pytest.approx(np.pi / 2, abs=1e-3)
    barrel = PinholeRadTan(400.0, 400.0, 320.0, 240.0, (-0.5, 0.0, 0.0, 0.0))
    assert barrel.max_angle == pytest.approx(np.arctan(np.sqrt(1 / 1.5)), abs=2e-3)


def test_registry_and_names() -> None:
    assert set(MODELS) == {"none", "radial-tangential", "equidistant", "rational_polynomial"}
    for alias, name in [
        ("radtan", "radial-tangential"),
        ("plumb_bob", "radial-tangential"),
        ("Equidistant", "equidistant"),
        ("KANNALA_BRANDT", "equidistant"),
        ("pinhole-equi", "equidistant"),
        ("none", "none"),
    ]:
        assert canonical_model_name(alias) == name
    assert canonical_model_name("double_sphere") is None
    m = make_camera_model("radtan", 1.0, 1.0, 0.0, 0.0, (0.1, 0, 0, 0))
    assert isinstance(m, PinholeRadTan) and m.ros_name == "plumb_bob"
    assert TUMVI.ros_name == "equidistant" and TUMVI.ros_coeffs().tolist() == list(TUMVI.coeffs)
    with pytest.raises(ValueError, match="unknown"):
        make_camera_model("double_sphere", 1.0, 1.0, 0.0, 0.0, ())
    with pytest.raises(ValueError, match="takes 4 coefficients, got 5"):
        make_camera_model("equidistant", 1.0, 1.0, 0.0, 0.0, (0.0,) * 5)
    with pytest.raises(ValueError, match="no coefficients"):
        Pinhole(1.0, 1.0, 0.0, 0.0, (0.1, 0.0, 0.0, 0.0))


def test_zero_radtan_is_the_pinhole() -> None:
    p = _rays(100, 50.0, seed=4)
    z = PinholeRadTan(PINHOLE.fx, PINHOLE.fy, PINHOLE.cx, PINHOLE.cy, (0.0,) * 4)
    np.testing.assert_allclose(z.project(p), PINHOLE.project(p), atol=1e-9)
