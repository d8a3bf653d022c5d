"""Unit tests of the frontend's building blocks (no dataset needed)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from eurocslam.camera import bucket_select, project_rect, triangulate_rect
from eurocslam.dataset.calib import default_rig
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import image_problem
from eurocslam.frontend.features import Features, OrbExtractor, hamming, hamming_pairs
from eurocslam.frontend.local_map import LocalMap
from eurocslam.frontend.pose_solver import optimize_pose, pnp_ransac
from eurocslam.frontend.stereo import StereoRectifier, undistort_points
from eurocslam.geometry import inv_T, make_T, rotation_angle, so3_exp


@pytest.fixture(scope="module")
def rectifier() -> StereoRectifier:
    return StereoRectifier(default_rig())


def test_rectified_geometry_matches_calibration(rectifier: StereoRectifier) -> None:
    g = rectifier.geometry
    rig = default_rig()
    assert g.baseline == pytest.approx(rig.baseline, rel=1e-6)
    assert 0.10 < g.baseline < 0.12  # EuRoC's ~11 cm stereo rig
    assert g.fx == g.fy and 400 < g.fx < 470
    # rect0 differs from cam0 by a pure rotation: same origin in the body frame
    np.testing.assert_allclose(g.T_body_rect0[:3, 3], rig.cam0.T_body_cam[:3, 3], atol=1e-12)
    R = g.T_body_rect0[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    # cam1's centre lies on rect0's +x axis at the baseline
    c1_in_rect0 = (inv_T(g.T_body_rect0) @ rig.cam1.T_body_cam)[:3, 3]
    np.testing.assert_allclose(c1_in_rect0, [g.baseline, 0, 0], atol=1e-9)


def test_raw_rect_round_trip(rectifier: StereoRectifier) -> None:
    rng = np.random.default_rng(0)
    uv_raw = rng.uniform([40, 40], [712, 440], size=(200, 2))
    back = rectifier.rect0_to_raw(rectifier.raw_to_rect0(uv_raw))
    np.testing.assert_allclose(back, uv_raw, atol=1e-3)


def test_rectification_puts_a_3d_point_on_one_row(rectifier: StereoRectifier) -> None:
    """A world point projected through the raw distorted cameras lands on the same rectified
    row in both images, at the disparity fx * b / z of its rect0 depth."""
    rig = default_rig()
    g = rectifier.geometry
    rng = np.random.default_rng(1)
    p_rect0 = np.column_stack(
        [rng.uniform(-1, 1, 50), rng.uniform(-0.6, 0.6, 50), rng.uniform(1.0, 6.0, 50)]
    )
    T_body_rect0 = g.T_body_rect0
    for cam, R_rect, P in (
        (rig.cam0, rectifier.R_rect0_cam0, rectifier.P0),
        (rig.cam1, rectifier.R_rect1_cam1, rectifier.P1),
    ):
        T_cam_rect0 = inv_T(cam.T_body_cam) @ T_body_rect0
        p_cam = p_rect0 @ T_cam_rect0[:3, :3].T + T_cam_rect0[:3, 3]
        raw, _ = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), cam.K, cam.D)
        rect = undistort_points(raw, cam.K, cam.D, R_rect, P).reshape(-1, 2)
        if cam.name == "cam0":
            left = rect
        else:
            right = rect
    expected = project_rect(p_rect0, g)
    np.testing.assert_allclose(left[:, 1], right[:, 1], atol=1e-3)
    np.testing.assert_allclose(left[:, 0], expected[:, 0], atol=1e-3)
    np.testing.assert_allclose(right[:, 0], expected[:, 1], atol=1e-3)
    tri = triangulate_rect(left[:, 0], right[:, 0], left[:, 1], g)
    np.testing.assert_allclose(tri, p_rect0, rtol=1e-4, atol=1e-4)


def test_bucket_select_spreads_features() -> None:
    rng = np.random.default_rng(2)
    # 2,000 strong corners crowded in one corner, 400 weak ones spread everywhere
    crowd = rng.uniform([0, 0], [90, 60], size=(2000, 2))
    spread = rng.uniform([0, 0], [752, 480], size=(400, 2))
    uv = np.vstack([crowd, spread])
    resp = np.concatenate([rng.uniform(50, 100, 2000), rng.uniform(1, 10, 400)])
    keep = bucket_select(uv, resp, 300, 752, 480, 8, 6)
    assert keep.size == 300 and np.unique(keep).size == 300
    cells = np.unique(
        (uv[keep, 1] * 6 // 480).astype(int) * 8 + (uv[keep, 0] * 8 // 752).astype(int)
    )
    assert cells.size >= 40  # nearly every one of the 48 cells is represented
    # within each crowded cell the strongest are kept first: no corner of a cell is left out
    # while a weaker one of the same cell is kept
    in_crowd = keep[keep < 2000]
    assert in_crowd.size > 0
    cell = (uv[:2000, 1] * 6 // 480).astype(int) * 8 + (uv[:2000, 0] * 8 // 752).astype(int)
    kept = np.zeros(2000, dtype=bool)
    kept[in_crowd] = True
    for c in np.unique(cell[in_crowd]):
        mine = cell == c
        assert resp[:2000][mine & kept].min() >= resp[:2000][mine & ~kept].max(initial=-np.inf)


def test_hamming_matches_opencv() -> None:
    rng = np.random.default_rng(3)
    a = rng.integers(0, 256, size=(50, 32), dtype=np.uint8)
    b = rng.integers(0, 256, size=(50, 32), dtype=np.uint8)
    ours = hamming(a, b)
    ref = [cv2.norm(a[i], b[i], cv2.NORM_HAMMING) for i in range(50)]
    np.testing.assert_array_equal(ours, ref)
    assert ours.dtype == np.int32


def test_hamming_pairs_gathers_rows() -> None:
    """`hamming_pairs(a, ia, b, ib)` is `hamming(a[ia], b[ib])`: the same int32 distances,
    all-bits-different rows (256) and non-contiguous inputs included."""
    rng = np.random.default_rng(5)
    a = rng.integers(0, 256, size=(40, 32), dtype=np.uint8)
    b = rng.integers(0, 256, size=(30, 32), dtype=np.uint8)
    b[7] = ~a[3]  # every bit differs: a distance of 256, beyond a uint8 count
    ia = rng.integers(0, 40, size=500)
    ib = rng.integers(0, 30, size=500)
    ia[0], ib[0] = 3, 7
    ours = hamming_pairs(a, ia, b, ib)
    np.testing.assert_array_equal(ours, hamming(a[ia], b[ib]))
    assert ours.dtype == np.int32 and ours[0] == 256
    wide = np.zeros((40, 64), np.uint8)
    wide[:, ::2] = a  # a strided view: gathered as it is
    np.testing.assert_array_equal(hamming_pairs(wide[:, ::2], ia, b, ib), ours)
    assert hamming_pairs(a, ia[:0], b, ib[:0]).shape == (0,)


def test_orb_extractor_count_and_blank_image() -> None:
    cfg = FrontendConfig(n_features=500)
    ex = OrbExtractor(cfg, 752, 480)
    rng = np.random.default_rng(4)
    img = cv2.GaussianBlur(rng.integers(0, 256, (480, 752), dtype=np.uint8), (3, 3), 0)
    f = ex.extract(img)
    assert 0.9 * 500 <= len(f) <= 500
    assert f.desc.shape == (len(f), 32) and f.desc.dtype == np.uint8
    assert len(ex.extract(np.zeros((480, 752), np.uint8))) == 0


def test_orb_extractor_falls_back_to_a_low_fast_threshold() -> None:
    """A low-contrast image gives few corners at FAST 20: the extractor detects again at
    `min_fast_threshold` and still returns about `n_features` (a dark EuRoC frame)."""
    rng = np.random.default_rng(5)
    img = cv2.GaussianBlur(rng.integers(0, 256, (480, 752), dtype=np.uint8), (5, 5), 0)
    dim = (img // 4 + 40).astype(np.uint8)  # contrast / 4
    strict = OrbExtractor(FrontendConfig(min_fast_threshold=20), 752, 480).extract(dim)
    assert len(strict) < 100  # FAST 20 alone starves on it (measured: 3)
    f = OrbExtractor(FrontendConfig(), 752, 480).extract(dim)
    assert len(f) == 1000


def test_image_problem_detects_degraded_frames() -> None:
    cfg = FrontendConfig()
    rng = np.random.default_rng(5)
    good = rng.integers(0, 256, (480, 752), dtype=np.uint8)
    assert image_problem(good, cfg) is None
    assert image_problem(None, cfg) == "missing"
    assert image_problem(np.zeros((480, 752), np.uint8), cfg) == "black"
    assert image_problem(np.full((480, 752), 255, np.uint8), cfg) == "saturated"
    assert image_problem(np.full((480, 752), 128, np.uint8), cfg) == "blank"


def _scene(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(2.0, 8.0, n)])


def test_optimize_pose_recovers_pose_and_flags_outliers(rectifier: StereoRectifier) -> None:
    g = rectifier.geometry
    rng = np.random.default_rng(6)
    xyz = _scene(rng, 300)  # world == rect0 of the reference pose
    T_true = make_T(so3_exp(np.array([0.02, -0.05, 0.03])), np.array([0.10, -0.05, 0.20]))
    p = xyz @ T_true[:3, :3].T + T_true[:3, 3]
    meas = project_rect(p, g)[:, [0, 1, 2]] + rng.normal(0, 0.5, (300, 3))
    meas[:100, 1] = np.nan  # a third of the points seen in the left image only
    outliers = rng.choice(300, 30, replace=False)
    meas[outliers, 0] += rng.uniform(20, 60, 30) * rng.choice([-1, 1], 30)
    sigma = np.ones(300)
    T_est, inl, _ = optimize_pose(np.eye(4), xyz, meas, sigma, g, 7.815, 5.991)
    err = inv_T(T_true) @ T_est
    assert np.linalg.norm(err[:3, 3]) < 0.01
    assert np.degrees(rotation_angle(err[:3, :3])) < 0.2
    assert not inl[outliers].any()
    assert inl.sum() >= 0.9 * (300 - 30)


def test_pnp_ransac_recovers_pose(rectifier: StereoRectifier) -> None:
    g = rectifier.geometry
    rng = np.random.default_rng(7)
    xyz = _scene(rng, 200)
    T_true = make_T(so3_exp(np.array([0.1, 0.2, -0.1])), np.array([0.3, 0.1, -0.2]))
    uv = project_rect(xyz @ T_true[:3, :3].T + T_true[:3, 3], g)[:, [0, 2]]
    uv[:40] = rng.uniform([0, 0], [752, 480], (40, 2))  # 20 % gross outliers
    T_est, inl = pnp_ransac(xyz, uv, g, None, 2.0, 200)
    assert T_est is not None
    assert np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) < 1e-3
    assert inl[40:].mean() > 0.95 and inl[:40].mean() < 0.1


def test_local_map_ids_are_persistent_and_unique() -> None:
    m = LocalMap(first_id=100)
    d = np.zeros((5, 32), np.uint8)
    ids1 = m.add(np.zeros((5, 3)), d, np.zeros(5, np.int32), np.zeros((5, 2)), 0)
    keep = np.array([True, False, True, False, True])
    m.keep(keep)
    ids2 = m.add(np.ones((3, 3)), d[:3], np.zeros(3, np.int32), np.zeros((3, 2)), 1)
    assert ids1.tolist() == [100, 101, 102, 103, 104]
    assert ids2.tolist() == [105, 106, 107]  # never reused after culling
    np.testing.assert_array_equal(m.index_of(np.array([102, 101, 107, 999])), [1, -1, 5, -1])
    m.clear()
    assert len(m) == 0
    assert m.add(np.zeros((1, 3)), d[:1], np.zeros(1, np.int32), np.zeros((1, 2)), 2)[0] == 108


def test_archived_landmarks_come_back_under_their_ids() -> None:
    m = LocalMap(first_id=10, archive_capacity=2)
    d = np.arange(6 * 32, dtype=np.uint8).reshape(6, 32)
    ids = m.add(np.arange(18.0).reshape(6, 3), d, np.arange(6, dtype=np.int32), np.zeros((6, 2)), 0)
    m.n_found[:] = [5, 1, 5, 5, 2, 7]
    m.retire(np.array([True, False, True, False, False, True]))
    assert ids.tolist() == [10, 11, 12, 13, 14, 15]
    assert m.ids.tolist() == [11, 13, 14]
    a = m.archive
    # over the capacity the least found go (down to 90 %: here one row left)
    assert len(a) == 1 and a.ids[: a.n][a.live[: a.n]].tolist() == [15]
    m.retire(np.array([True, False, False]))  # id 11, found once
    assert len(a) == 2
    m.add(np.zeros((1, 3)), d[:1], np.zeros(1, np.int32), np.zeros((1, 2)), 1)  # id 16
    rows = np.array([int(np.nonzero(a.ids[: a.n] == i)[0][0]) for i in (15, 11)])
    now_desc = np.full((2, 32), 7, np.uint8)
    xyz = np.array([[1.0, 2, 3], [4, 5, 6]])
    back = m.revive(rows, xyz, now_desc, np.array([2, 3]), np.ones((2, 2)), t_ns=9)
    assert back.tolist() == [15, 11]
    assert m.ids.tolist() == [11, 13, 14, 15, 16]  # sorted again: index_of works
    assert len(a) == 0
    r = m.index_of(np.array([11, 15]))
    np.testing.assert_array_equal(m.xyz[r], [[4, 5, 6], [1, 2, 3]])  # positions seen now
    np.testing.assert_array_equal(m.desc[r], now_desc)  # as seen now: descriptor, octave
    np.testing.assert_array_equal(m.octave[r], [3, 2])
    assert m.last_seen[r].tolist() == [9, 9] and m.n_found[r].tolist() == [2, 8]
    m.clear()
    assert len(m) == 0 and len(a) == 0


def test_archive_grows_and_compacts() -> None:
    m = LocalMap(archive_capacity=10**6)
    d = np.zeros((1, 32), np.uint8)
    for i in range(3000):  # retire one at a time: amortised appends
        m.add(np.full((1, 3), float(i)), d, np.zeros(1, np.int32), np.zeros((1, 2)), i)
        m.retire(np.ones(1, bool))
    a = m.archive
    assert len(a) == a.n == 3000 and a.live.size >= 3000
    np.testing.assert_array_equal(a.xyz[: a.n, 0], np.arange(3000.0))
    for rows in (np.arange(0, 3000, 2), np.arange(1, 2000, 2)):
        n = rows.size
        z = np.zeros(n)
        m.revive(rows, np.zeros((n, 3)), np.zeros((n, 32), np.uint8), z, np.zeros((n, 2)), 0)
    assert len(a) == 500 and len(m) == 2500
    size = a.live.size
    for _ in range(size - a.n + 1):  # full: compacts (most rows dead) instead of growing
        m.add(np.zeros((1, 3)), d, np.zeros(1, np.int32), np.zeros((1, 2)), 0)
    m.retire(np.arange(len(m)) >= 2500)
    assert a.live.size == size and len(a) == a.n == 500 + size - 3000 + 1
    assert sorted(a.ids[: a.n][:500].tolist()) == list(range(2001, 3000, 2))


def test_features_empty() -> None:
    e = Features.empty()
    assert len(e) == 0 and e.desc.shape == (0, 32)
