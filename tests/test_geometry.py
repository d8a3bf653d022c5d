"""SE(3) / quaternion helpers: round trips, conventions (wxyz vs xyzw), so3 exp/log."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eurocslam.geometry import (
    inv_T,
    make_T,
    normalize_quat,
    quat_wxyz_to_rot,
    rot_to_quat_wxyz,
    rot_z,
    rotation_angle,
    rotation_between,
    skew,
    so3_exp,
    so3_log,
    transform_points,
    wxyz_to_xyzw,
    xyzw_to_wxyz,
    yaw_of,
)

RNG = np.random.default_rng(7)


def random_quats(n: int) -> np.ndarray:
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_wxyz_xyzw_round_trip_and_layout() -> None:
    q = np.array([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(wxyz_to_xyzw(q), [0.2, 0.3, 0.4, 0.1])
    np.testing.assert_array_equal(xyzw_to_wxyz(wxyz_to_xyzw(q)), q)
    qs = random_quats(10)
    np.testing.assert_array_equal(xyzw_to_wxyz(wxyz_to_xyzw(qs)), qs)
    assert wxyz_to_xyzw(qs).shape == (10, 4)


def test_quaternion_convention_matches_scipy() -> None:
    """Hamilton, w-first here; scipy is x,y,z,w (scalar last), an independent reference."""
    q = random_quats(50)
    expected = Rotation.from_quat(wxyz_to_xyzw(q)).as_matrix()
    np.testing.assert_allclose(quat_wxyz_to_rot(q), expected, atol=1e-12)


def test_quat_90deg_about_z() -> None:
    s = np.sqrt(0.5)
    r = quat_wxyz_to_rot(np.array([s, 0.0, 0.0, s]))
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)


def test_rot_quat_round_trip_all_branches() -> None:
    q = random_quats(200)
    # include rotations near pi about each axis (the non-w branches of Shepperd's method)
    eps = 1e-9
    q = np.vstack([q, [[eps, 1, 0, 0], [eps, 0, 1, 0], [eps, 0, 0, 1], [1, 0, 0, 0]]])
    q = normalize_quat(q)
    r = quat_wxyz_to_rot(q)
    back = rot_to_quat_wxyz(r)
    assert np.all(back[:, 0] >= 0)
    # same rotation (q and -q), canonical w >= 0
    dots = np.abs(np.sum(back * q, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)
    np.testing.assert_allclose(quat_wxyz_to_rot(back), r, atol=1e-9)
    rtr = np.einsum("nji,njk->nik", r, r)
    np.testing.assert_allclose(rtr, np.broadcast_to(np.eye(3), rtr.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)


def test_normalize_quat_rejects_zero() -> None:
    with pytest.raises(ValueError, match="zero-norm"):
        normalize_quat(np.zeros(4))
    np.testing.assert_allclose(np.linalg.norm(normalize_quat(np.array([2.0, 0, 0, 0]))), 1.0)


def test_se3_inverse_compose_and_points() -> None:
    r = quat_wxyz_to_rot(random_quats(20))
    t = RNG.normal(size=(20, 3))
    T = make_T(r, t)
    eye = np.broadcast_to(np.eye(4), T.shape)
    np.testing.assert_allclose(T @ inv_T(T), eye, atol=1e-12)
    np.testing.assert_allclose(inv_T(T) @ T, eye, atol=1e-12)
    np.testing.assert_allclose(inv_T(inv_T(T)), T, atol=1e-12)
    p = RNG.normal(size=(7, 3))
    homog = np.hstack([p, np.ones((7, 1))]) @ T[0].T
    np.testing.assert_allclose(transform_points(T[0], p), homog[:, :3], atol=1e-12)
    # T_a_c = T_a_b @ T_b_c maps c-points into a
    np.testing.assert_allclose(
        transform_points(T[0] @ T[1], p), transform_points(T[0], transform_points(T[1], p))
    )


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-5, 0.3, 1.5, 3.0, np.pi - 1e-8, np.pi])
def test_so3_exp_log_round_trip(angle: float) -> None:
    for axis in (np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), RNG.normal(size=3)):
        w = axis / np.linalg.norm(axis) * angle
        r = so3_exp(w)
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
        w2 = so3_log(r)
        np.testing.assert_allclose(so3_exp(w2), r, atol=1e-7)
        if angle < np.pi - 1e-6:
            np.testing.assert_allclose(w2, w, atol=1e-7)
        assert rotation_angle(r) == pytest.approx(angle, abs=1e-6)


def test_so3_exp_matches_quaternion() -> None:
    axis = np.array([0.3, -0.5, 0.8])
    axis /= np.linalg.norm(axis)
    a = 0.9
    q = np.concatenate([[np.cos(a / 2)], axis * np.sin(a / 2)])
    np.testing.assert_allclose(so3_exp(axis * a), quat_wxyz_to_rot(q), atol=1e-12)
    np.testing.assert_allclose(skew(axis) @ [1.0, 2.0, 3.0], np.cross(axis, [1.0, 2.0, 3.0]))


@pytest.mark.parametrize(
    "a,b",
    [
        ([0, 0, 1], [0, 0, 1]),
        ([0, 0, 1], [0, 0, -1]),
        ([1, 0, 0], [-1, 0, 0]),
        ([9.81, 0.1, -3.0], [0, 0, 1]),
        ([1, 2, 3], [-3, 0.5, 2]),
    ],
)
def test_rotation_between(a: list[float], b: list[float]) -> None:
    a_, b_ = np.asarray(a, float), np.asarray(b, float)
    r = rotation_between(a_, b_)
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r @ (a_ / np.linalg.norm(a_)), b_ / np.linalg.norm(b_), atol=1e-12)
    # the smallest rotation: its angle is the angle between the vectors
    cos = np.dot(a_, b_) / np.linalg.norm(a_) / np.linalg.norm(b_)
    assert rotation_angle(r) == pytest.approx(np.arccos(np.clip(cos, -1, 1)), abs=1e-9)


def test_yaw() -> None:
    for y in (-3.0, -0.5, 0.0, 1.2, 3.1):
        assert yaw_of(rot_z(y)) == pytest.approx(y)
    # yaw of a rotation with pitch/roll added keeps the heading
    r = rot_z(0.7) @ so3_exp(np.array([0.0, 0.2, 0.0]))
    assert yaw_of(r) == pytest.approx(0.7, abs=1e-12)


def test_se3_exp_is_the_inverse_of_se3_log() -> None:
    """`se3_exp(se3_log(T)) == T` and back, small and large rotations (and none)."""
    from eurocslam.geometry import se3_exp, se3_log

    rng = np.random.default_rng(7)
    for angle in (0.0, 1e-6, 0.3, 2.5):  # below pi: the log's range
        axis = rng.normal(size=3)
        xi = np.r_[axis / np.linalg.norm(axis) * angle, rng.normal(size=3)]
        np.testing.assert_allclose(se3_log(se3_exp(xi)), xi, atol=1e-9)
    T = se3_exp(np.r_[0.2, -0.1, 0.7, 1.0, 2.0, -0.5])
    np.testing.assert_allclose(se3_exp(se3_log(T)), T, atol=1e-12)
