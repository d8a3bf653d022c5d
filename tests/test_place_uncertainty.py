"""The covariance of a place match's pose (places/uncertainty.py) against Monte Carlo: the
candidate keyframe triangulates its points from one noisy stereo pair, the query measures them
with noisy pixels, the pose is fitted as the recognizer fits it; the scatter of the fitted pose
is what `match_covariance` predicts, and far points (small disparity) widen it."""

from __future__ import annotations

import numpy as np
import pytest

from eurocslam.camera import RectifiedStereo, project_rect, triangulate_rect
from eurocslam.frontend.tracking import optimize_pose
from eurocslam.geometry import F64, inv_T, make_T, se3_log, so3_exp
from eurocslam.places.uncertainty import match_covariance, stereo_point_cov

# EuRoC's rectified rig, roughly
GEOM = RectifiedStereo(436.0, 436.0, 376.0, 240.0, 0.11, 752, 480, np.eye(4))
SIGMA_PX = 1.0


def _scene(rng: np.random.Generator, n: int, depth: tuple[float, float]) -> tuple[F64, F64, F64]:
    """Points in the world, the candidate's and the query's T_rect0_world (body = rect0)."""
    T_cand = np.eye(4)
    z = rng.uniform(*depth, n)
    uv = np.column_stack([rng.uniform(40, 712, n), rng.uniform(40, 440, n)])
    pts = triangulate_rect(uv[:, 0], uv[:, 0] - GEOM.fx * GEOM.baseline / z, uv[:, 1], GEOM)
    T_query = make_T(so3_exp(np.radians([1.0, -4.0, 2.0])), np.array([0.15, 0.05, -0.2]))
    return pts, T_cand, T_query


def _trial(rng: np.random.Generator, pts: F64, T_cand: F64, T_query: F64) -> tuple[F64, F64, F64]:
    """One noisy candidate triangulation and query measurement: (pose error as a world-frame
    twist, predicted covariance, the candidate's measurements)."""
    m_cand = project_rect(pts @ T_cand[:3, :3].T + T_cand[:3, 3], GEOM)
    m_cand += rng.normal(0.0, SIGMA_PX, m_cand.shape)
    m_cand[:, 1] = np.minimum(m_cand[:, 1], m_cand[:, 0] - 0.2)
    Tw_c = inv_T(T_cand)
    p_noisy = triangulate_rect(m_cand[:, 0], m_cand[:, 1], m_cand[:, 2], GEOM)
    p_noisy = p_noisy @ Tw_c[:3, :3].T + Tw_c[:3, 3]
    m_q = project_rect(pts @ T_query[:3, :3].T + T_query[:3, 3], GEOM)
    m_q += rng.normal(0.0, SIGMA_PX, m_q.shape)
    sigma = np.full(len(pts), SIGMA_PX)
    T_fit, inl, _ = optimize_pose(T_query, p_noisy, m_q, sigma, GEOM, 1e9, 1e9)
    assert inl.all()
    cov_pts = Tw_c[:3, :3] @ stereo_point_cov(m_cand, sigma, GEOM) @ Tw_c[:3, :3].T
    cov = match_covariance(T_fit, p_noisy, cov_pts, m_q, sigma, GEOM)
    # the fitted body (= rect0) pose against the true one, a left perturbation in the world
    return se3_log(inv_T(T_fit) @ T_query), cov, m_cand


@pytest.mark.parametrize("depth", [(1.0, 5.0), (3.0, 20.0)])
def test_the_predicted_covariance_is_the_scatter_of_the_fit(depth: tuple[float, float]) -> None:
    """Along every principal direction of the predicted covariance the fits scatter by what it
    says (within 25 %). Near points: the errors are chi-square(6) about the true pose. Far ones
    (3-20 m on an 11 cm baseline, 1 px): also about their mean, which is off the true pose by
    a few sigma: depth from one noisy disparity is biased far (E[fb/d] > fb/E[d])."""
    rng = np.random.default_rng(7)
    pts, T_cand, T_query = _scene(rng, 80, depth)
    runs = [_trial(rng, pts, T_cand, T_query) for _ in range(300)]
    xi = np.array([r[0] for r in runs])
    predicted = np.mean([r[1] for r in runs], axis=0)
    w, V = np.linalg.eigh(predicted)
    ratio = np.diag(V.T @ np.cov(xi.T) @ V) / w
    assert np.all((ratio > 0.75) & (ratio < 1.25)), ratio
    about = xi - xi.mean(axis=0) if depth[1] > 10 else xi
    chi2 = [float(x @ np.linalg.solve(c, x)) for x, (_, c, _) in zip(about, runs, strict=True)]
    assert np.mean(chi2) == pytest.approx(6.0, rel=0.2)


def test_far_points_make_a_wider_match() -> None:
    rng = np.random.default_rng(8)
    near = _trial(rng, *_scene(rng, 80, (1.0, 4.0)))[1]
    far = _trial(rng, *_scene(rng, 80, (10.0, 40.0)))[1]
    assert np.trace(far[3:, 3:]) > 10 * np.trace(near[3:, 3:])


def test_a_point_triangulated_from_one_pair_is_uncertain_along_its_ray() -> None:
    """sigma_Z = Z^2 / (f b) * sigma_d, sigma_d = sqrt(2) px for two independent columns."""
    z = np.array([2.0, 8.0])
    m = project_rect(np.column_stack([np.zeros(2), np.zeros(2), z]), GEOM)
    cov = stereo_point_cov(m, np.full(2, SIGMA_PX), GEOM)
    sigma_z = np.sqrt(cov[:, 2, 2])
    np.testing.assert_allclose(sigma_z, z**2 / (GEOM.fx * GEOM.baseline) * np.sqrt(2), rtol=1e-9)
