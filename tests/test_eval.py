"""Evaluator core: association, alignment recovery, ATE/RPE against evo, segments, coverage."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from eurocslam.errors import EvalError
from eurocslam.eval.align import align, posyaw, umeyama
from eurocslam.eval.associate import associate
from eurocslam.eval.evaluate import EvalConfig, coverage, evaluate
from eurocslam.eval.metrics import cumulative_distance, distance_pairs
from eurocslam.eval.synthetic import (
    T0_NS,
    perturb,
    random_similarity,
    smooth_trajectory,
    straight_road,
)
from eurocslam.geometry import rot_z, so3_exp, so3_log
from eurocslam.trajectory import Trajectory


@pytest.fixture(scope="module")
def gt() -> Trajectory:
    return smooth_trajectory(3000, 200.0, seed=3, name="gt")


def _to_evo(tr: Trajectory):
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(
        positions_xyz=tr.p.copy(),
        orientations_quat_wxyz=tr.q_wxyz.copy(),
        timestamps=tr.t_ns / 1e9,
    )


# ---------------------------------------------------------------------------- association


def test_association_matches_evo_indices() -> None:
    from evo.core.sync import matching_time_indices

    rng = np.random.default_rng(0)
    ref = np.sort(T0_NS + rng.integers(0, 20 * 10**9, size=4000)).astype(np.int64)
    est = np.sort(T0_NS + rng.integers(-(10**9), 21 * 10**9, size=700)).astype(np.int64)
    for max_diff, offset in [(0.01, 0.0), (0.003, 0.0), (0.05, 0.2), (0.01, -0.5)]:
        a = associate(ref, est, round(max_diff * 1e9), round(offset * 1e9))
        # evo: stamps_1 = shorter (estimate), offset applied to the longer one with a minus
        i_est, i_ref = matching_time_indices(est / 1e9, ref / 1e9, max_diff, -offset)
        assert np.array_equal(a.idx_est, i_est)
        assert np.array_equal(a.idx_ref, i_ref)
        assert np.all(np.abs(a.dt_ns) <= round(max_diff * 1e9))
        assert a.possible >= a.matched


def test_association_counts_and_common_span() -> None:
    ref = T0_NS + np.arange(0, 1000, dtype=np.int64) * 5_000_000  # 200 Hz, 5 s
    est = T0_NS + 2 * 10**9 + np.arange(0, 100, dtype=np.int64) * 50_000_000  # 20 Hz from 2 s
    a = associate(ref, est)
    assert a.span_ns == (int(est[0]), int(ref[-1]))
    assert a.possible == np.count_nonzero(est <= ref[-1] + 10_000_000)
    assert a.matched == a.possible == 61  # 2.0 .. 5.0 s; 5.0 matches 4.995 (5 ms)


def test_association_errors_name_both_inputs() -> None:
    ref = T0_NS + np.arange(100, dtype=np.int64) * 10**8
    with pytest.raises(EvalError, match=r"no time overlap.*GT\.csv.*EST\.tum"):
        associate(ref, ref + 10**11, ref_name="GT.csv", est_name="EST.tum")
    with pytest.raises(EvalError, match=r"zero timestamp matches.*GT\.csv.*EST\.tum"):
        associate(ref, ref + 5 * 10**7, 10**6, ref_name="GT.csv", est_name="EST.tum")
    # seconds read as ns (relative to epoch) vs ns: factor 1e9
    with pytest.raises(EvalError, match="seconds"):
        associate(ref, ref // 10**9 + np.arange(100), ref_name="GT.csv", est_name="EST.tum")


# ---------------------------------------------------------------------------- alignment


def test_se3_and_sim3_recovered_exactly(gt: Trajectory) -> None:
    for seed, scale in [(1, 1.0), (2, 1.0), (3, 0.37), (4, 2.5)]:
        M = random_similarity(seed, scale)
        est = perturb(gt, M, step=5)
        mode = "sim3" if scale != 1.0 else "se3"
        r = evaluate(gt, est, EvalConfig(align=mode))
        al = r.segments[0].alignment
        Minv = np.linalg.inv(M)
        assert np.allclose(al.matrix(), Minv, atol=1e-9)
        assert r.ate_trans.max < 1e-9
        assert r.ate_rot.max < 1e-5
        assert r.rpe_delta_trans.max < 1e-9


def test_posyaw_recovers_known_yaw_and_offset(gt: Trajectory) -> None:
    yaw = np.deg2rad(37.0)
    M = np.eye(4)
    M[:3, :3] = rot_z(yaw)
    M[:3, 3] = [1.5, -2.0, 0.7]
    est = perturb(gt, M, step=4)
    r = evaluate(gt, est, EvalConfig(align="posyaw"))
    al = r.segments[0].alignment
    assert al.yaw_deg == pytest.approx(-37.0, abs=1e-9)
    assert np.allclose(al.R[2], [0, 0, 1]) and np.allclose(al.R[:, 2], [0, 0, 1])
    assert np.allclose(al.matrix(), np.linalg.inv(M), atol=1e-9)
    assert r.ate_trans.max < 1e-9


def test_posyaw_does_not_absorb_roll_pitch(gt: Trajectory) -> None:
    # a tilted frame: SE(3) absorbs the tilt, 4-DoF must not
    M = np.eye(4)
    M[:3, :3] = so3_exp(np.array([0.05, 0.0, 0.4]))
    est = perturb(gt, M, step=4)
    se3 = evaluate(gt, est, EvalConfig(align="se3"))
    py = evaluate(gt, est, EvalConfig(align="posyaw"))
    assert se3.ate_trans.rmse < 1e-9
    assert py.ate_trans.rmse > 0.01
    # and the closed form is the least-squares optimum: small yaw changes only make it worse
    s = py.segments[0]
    x = est.p[s.association.idx_est]
    R, t = posyaw(x, s.p_ref)
    base = np.sum((x @ R.T + t - s.p_ref) ** 2)
    for d in (-1e-3, 1e-3):
        R2 = rot_z(d) @ R
        t2 = s.p_ref.mean(0) - R2 @ x.mean(0)
        assert np.sum((x @ R2.T + t2 - s.p_ref) ** 2) > base


def test_origin_alignment_maps_first_pose(gt: Trajectory) -> None:
    est = perturb(gt, random_similarity(7), step=10, noise_m=0.01, noise_rad=0.01, seed=4)
    r = evaluate(gt, est, EvalConfig(align="origin"))
    s = r.segments[0]
    assert np.allclose(s.p_est[0], s.p_ref[0], atol=1e-12)
    assert np.allclose(s.R_est[0], s.R_ref[0], atol=1e-12)


def test_alignment_needs_three_pairs_and_motion() -> None:
    p = np.random.default_rng(0).normal(size=(2, 3))
    with pytest.raises(EvalError, match="at least 3"):
        align("se3", p, p)
    with pytest.raises(EvalError, match="at least 3"):
        align("posyaw", np.zeros((10, 3)), np.zeros((10, 3)), first_n=2)
    with pytest.raises(EvalError, match=r"degenerate.*do not move"):
        umeyama(np.zeros((10, 3)), np.zeros((10, 3)), False)
    moving = np.random.default_rng(1).normal(size=(10, 3))
    with pytest.raises(EvalError, match="do not move"):  # the estimate stands still
        align("se3", moving, np.tile([1.0, 2.0, 3.0], (10, 1)))
    # a line is no error (evo aligns one where its absolute rank test lets it): the line is
    # mapped onto itself whatever the turn about it
    line = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    a = align("se3", line, line)
    assert np.abs(a.apply_positions(line) - line).max() < 1e-12
    assert a.basis == "positions" and a.extent_sigmas is not None and a.extent_sigmas > 1e6


# ---------------------------------------------------------------------------- against evo


@pytest.mark.parametrize("mode", ["se3", "sim3", "origin", "none"])
def test_metrics_match_evo(gt: Trajectory, mode: str) -> None:
    from evo.core import metrics, sync

    est = perturb(
        gt,
        random_similarity(11, 0.8 if mode == "sim3" else 1.0),
        step=10,
        noise_m=0.02,
        noise_rad=0.01,
        drift_m=0.003,
        jitter_ns=3_000_000,
        seed=5,
    )
    r = evaluate(gt, est, EvalConfig(align=mode, max_diff_s=0.01))
    ref_e, est_e = sync.associate_trajectories(_to_evo(gt), _to_evo(est), max_diff=0.01)
    est_e = copy.deepcopy(est_e)
    if mode in ("se3", "sim3"):
        est_e.align(ref_e, correct_scale=(mode == "sim3"))
    elif mode == "origin":
        est_e.align_origin(ref_e)
    assert r.matched == ref_e.num_poses

    def evo_stats(metric):
        metric.process_data((ref_e, est_e))
        return metric.get_all_statistics()

    P = metrics.PoseRelation
    checks = [
        (r.ate_trans, evo_stats(metrics.APE(P.translation_part))),
        (r.ate_rot, evo_stats(metrics.APE(P.rotation_angle_deg))),
        (r.rpe_delta_trans, evo_stats(metrics.RPE(P.translation_part))),
        (r.rpe_delta_rot, evo_stats(metrics.RPE(P.rotation_angle_deg))),
    ]
    for ours, theirs in checks:
        for k in ("rmse", "mean", "median", "std", "min", "max"):
            assert getattr(ours, k) == pytest.approx(theirs[k], rel=1e-9, abs=1e-9), k


def test_align_first_n_matches_evo(gt: Trajectory) -> None:
    from evo.core import metrics, sync

    est = perturb(gt, random_similarity(12), step=10, noise_m=0.02, drift_m=0.005, seed=6)
    r = evaluate(gt, est, EvalConfig(align="se3", align_first=40))
    ref_e, est_e = sync.associate_trajectories(_to_evo(gt), _to_evo(est))
    est_e.align(ref_e, n=40)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    assert r.ate_trans.rmse == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse), 1e-9)
    assert r.segments[0].alignment.n_used == 40


def test_rpe_delta_frames_matches_evo(gt: Trajectory) -> None:
    from evo.core import metrics, sync

    est = perturb(gt, None, step=10, noise_m=0.01, noise_rad=0.01, seed=8)
    r = evaluate(gt, est, EvalConfig(align="none", rpe_delta=7))
    ref_e, est_e = sync.associate_trajectories(_to_evo(gt), _to_evo(est))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=7)
    rpe.process_data((ref_e, est_e))
    assert r.rpe_delta_trans.n == len(rpe.error)
    assert r.rpe_delta_trans.rmse == pytest.approx(
        rpe.get_statistic(metrics.StatisticsType.rmse), rel=1e-9
    )


# ---------------------------------------------------------------------------- distance RPE


def test_distance_pairs_match_brute_force() -> None:
    rng = np.random.default_rng(2)
    p = np.cumsum(rng.normal(size=(400, 3)) * 0.1, axis=0)
    d = cumulative_distance(p)
    for L in (0.5, 3.0, 10.0):
        i, j = distance_pairs(d, L, 0.1)
        exp = []
        for a in range(len(d)):
            errs = np.abs(d[a + 1 :] - (d[a] + L))
            if errs.size == 0:
                continue
            b = int(np.argmin(errs)) + a + 1
            if errs[b - a - 1] <= 0.1 * L:
                exp.append((a, b))
        got = list(zip(i.tolist(), j.tolist(), strict=True))
        # ties in argmin (equal distances) may pick either; compare the travelled distances
        assert len(got) == len(exp)
        for (a, b), (a2, b2) in zip(got, exp, strict=True):
            assert a == a2
            assert abs(d[b] - d[b2]) < 1e-12


def test_distance_rpe_is_zero_for_a_perfect_estimate_and_scales_with_drift(
    gt: Trajectory,
) -> None:
    perfect = evaluate(gt, perturb(gt, random_similarity(3), step=10))
    assert all(L.trans.max < 1e-9 for L in perfect.lengths)
    assert [L.fraction for L in perfect.lengths] == [0.1, 0.2, 0.3, 0.4, 0.5]
    total = perfect.segments[0].gt_length_m
    assert perfect.lengths[2].length_m == pytest.approx(0.3 * total)
    drifty = evaluate(gt, perturb(gt, None, step=10, drift_m=0.01, seed=2))
    means = [L.trans.mean for L in drifty.lengths]
    assert means[-1] > means[0] > 0  # a random walk grows with length
    assert drifty.drift_pct is not None and drifty.drift_pct > 0
    custom = evaluate(gt, perturb(gt, None, step=10), EvalConfig(rpe_lengths_m=(1.0, 2.0)))
    assert [L.length_m for L in custom.lengths] == [1.0, 2.0]


# ---------------------------------------------------------------------------- segments


def test_segments_aligned_separately_and_pooled(gt: Trajectory) -> None:
    a = perturb(gt.take(slice(0, 1200)), random_similarity(1), step=10)
    b = perturb(gt.take(slice(1500, 3000)), random_similarity(2), step=10)
    seg = np.concatenate([np.zeros(len(a), np.int64), np.ones(len(b), np.int64)])
    est = Trajectory(
        np.concatenate([a.t_ns, b.t_ns]),
        np.vstack([a.p, b.p]),
        np.vstack([a.q_wxyz, b.q_wxyz]),
        seg,
        "est",
    )
    r = evaluate(gt, est)
    assert [s.segment for s in r.segments] == [0, 1]
    assert r.ate_trans.max < 1e-9  # each segment's own frame recovered
    assert r.matched == len(a) + len(b)
    # coverage: 1195 + 1490 steps of 5 ms out of 2999 (gap between segments not covered)
    assert r.coverage == pytest.approx(
        (a.t_ns[-1] - a.t_ns[0] + b.t_ns[-1] - b.t_ns[0]) / (gt.t_ns[-1] - gt.t_ns[0])
    )
    d = r.to_dict()
    assert len(d["segments"]) == 2 and d["skipped_segments"] == []


def test_unusable_segment_is_skipped_with_reason(gt: Trajectory) -> None:
    a = perturb(gt.take(slice(0, 1500)), random_similarity(1), step=10)
    b = perturb(gt.take(slice(2000, 2010)), None, step=5)  # 2 poses: cannot align
    seg = np.concatenate([np.zeros(len(a), np.int64), np.full(len(b), 5, np.int64)])
    est = Trajectory(
        np.concatenate([a.t_ns, b.t_ns]),
        np.vstack([a.p, b.p]),
        np.vstack([a.q_wxyz, b.q_wxyz]),
        seg,
        "est",
    )
    r = evaluate(gt, est)
    assert [s.segment for s in r.segments] == [0]
    assert r.skipped and r.skipped[0][0] == 5 and "at least 3" in r.skipped[0][1]


def test_coverage_excludes_gaps() -> None:
    ref = T0_NS + np.arange(1001, dtype=np.int64) * 10_000_000  # 10 s
    t = np.concatenate([ref[:251], ref[500:751]])  # 0-2.5 s and 5-7.5 s
    p = np.zeros((len(t), 3))
    q = np.tile([1.0, 0, 0, 0], (len(t), 1))
    est = Trajectory(t, p, q)
    assert coverage(ref, est, 0, 10**9) == pytest.approx(0.5)
    assert coverage(ref, est, 0, 3 * 10**9) == pytest.approx(0.75)


def test_rotation_angles_accurate_small_and_large() -> None:
    from eurocslam.eval.metrics import rotation_angles_deg

    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for deg in (1e-7, 1e-3, 1.0, 90.0, 179.0, 179.9999):
        R = so3_exp(axis * np.deg2rad(deg))[None]
        assert rotation_angles_deg(R)[0] == pytest.approx(deg, rel=1e-6)


def test_a_platform_at_rest_is_aligned_by_its_orientations_and_shows_no_drift() -> None:
    """A drone standing still (the real V1_01 excerpt): millimetres of position noise cannot fix
    an SE(3) fit's rotation, which then turns the estimate anywhere (ATE rotation read 79 deg
    there), and RPE over fractions of a 2 cm path measures noise ("drift" 44 %). The rotation
    comes from the orientations instead, and no drift is reported."""
    rng = np.random.default_rng(1)
    n = 100
    t = T0_NS + np.arange(n, dtype=np.int64) * 50_000_000
    R_true = rot_z(0.7) @ so3_exp(np.array([0.02, -0.01, 0.0]))
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    ref = Trajectory(t, np.array([1.0, 2.0, 0.8]) + rng.normal(0, 0.0005, (n, 3)), q, name="gt")
    est_T = np.tile(np.eye(4), (n, 1, 1))
    est_T[:, :3, :3] = R_true.T  # the estimate's world is turned by R_true^T
    est_T[:, :3, 3] = rng.normal(0, 0.001, (n, 3))
    est = Trajectory.from_poses(t, est_T, name="est")
    r = evaluate(ref, est, EvalConfig(align="se3"))
    al = r.segments[0].alignment
    assert "rotation from the orientations" in al.note
    np.testing.assert_allclose(al.R, R_true, atol=1e-9)
    assert r.ate_rot.max < 1e-6
    assert r.ate_trans.rmse < 0.003
    assert r.drift_pct is None and r.lengths == []


# ------------------------------------------- straight roads and platforms at rest, against evo


def _evo_ate(ref: Trajectory, est: Trajectory, mode: str):
    """evo's APE translation after its Umeyama fit of positions (`-a`, `-as`): per-pose errors,
    statistics, and APE rotation statistics."""
    from evo.core import metrics, sync

    ref_e, est_e = sync.associate_trajectories(_to_evo(ref), _to_evo(est), max_diff=0.01)
    est_e = copy.deepcopy(est_e)
    est_e.align(ref_e, correct_scale=(mode == "sim3"))
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    ape_r = metrics.APE(metrics.PoseRelation.rotation_angle_deg)
    ape_r.process_data((ref_e, est_e))
    return ape.error, ape.get_all_statistics(), ape_r.get_all_statistics()


@pytest.mark.parametrize("mode", ["se3", "sim3"])
def test_a_straight_road_equals_evo(mode: str) -> None:
    """Issue #35: a straight 60 m road with millimetres of lateral wiggle. The positions fix the
    road's direction and a turn about the road moves the aligned positions only within the
    wiggle, so evo's fit of positions is the ATE; eval had taken the rotation from the
    orientations there (the old rule: the positions 'pin it down' only to tens of degrees about
    the road) and read 0.128 m where evo reads 0.033."""
    from eurocslam.eval.align import DETERMINED_EXTENT_SIGMAS, rotation_fit_sigma_deg

    gt = straight_road(60.0, 0.003)
    est = perturb(
        gt,
        random_similarity(3, 0.9 if mode == "sim3" else 1.0),
        noise_m=0.03,
        noise_rad=0.01,
        drift_m=0.002,
        seed=2,
    )
    r = evaluate(gt, est, EvalConfig(align=mode))
    al = r.segments[0].alignment
    err, stats, stats_r = _evo_ate(gt, est, mode)
    assert al.basis == "positions" and not al.note and r.ate_trans_position_fit is None
    assert al.extent_sigmas is not None and al.extent_sigmas > 100 * DETERMINED_EXTENT_SIGMAS
    assert rotation_fit_sigma_deg(gt.p, r.ate_trans.rmse) > 10.0  # what the old rule read
    assert np.abs(r.segments[0].ate_t - err).max() < 1e-9
    for k in ("rmse", "mean", "median", "std", "min", "max"):
        assert getattr(r.ate_trans, k) == pytest.approx(stats[k], abs=1e-5), k
        assert getattr(r.ate_rot, k) == pytest.approx(stats_r[k], abs=1e-6), k


def test_an_exactly_straight_road_matches_evo_where_evo_gives_a_number() -> None:
    """Exactly collinear reference positions: Umeyama's cross-covariance has rank 1. evo aligns
    when rounding leaves its second singular value above its absolute epsilon (a 60 m road) and
    raises on a 1 m one; either way every position error is the same for any turn about the
    line. eval aligns both, taking the turn about the line from the orientations."""
    from evo.core.geometry import GeometryException

    M = random_similarity(4)
    for length_m in (60.0, 1.0):
        gt = straight_road(length_m, 0.0, direction=(0.6, -0.3, 0.2))
        est = perturb(gt, M, noise_m=0.002 * length_m, noise_rad=0.01, seed=3)
        r = evaluate(gt, est, EvalConfig(align="se3"))
        al = r.segments[0].alignment
        assert al.basis == "positions" and "positions on a line" in al.note
        if length_m == 60.0:
            err, _, _ = _evo_ate(gt, est, "se3")
        else:
            with pytest.raises(GeometryException, match="Degenerate"):
                _evo_ate(gt, est, "se3")
            # the same road 100x longer: every error 100x, and evo gives its number
            big = [Trajectory(x.t_ns, 100.0 * x.p, x.q_wxyz, name=x.name) for x in (gt, est)]
            err = _evo_ate(big[0], big[1], "se3")[0] / 100.0
        assert np.abs(r.segments[0].ate_t - err).max() < 1e-9 * length_m
        # the turn about the road from the orientations: ATE rotation is their noise (0.01 rad
        # per axis, ~1 deg), where evo's turn is whatever its SVD returned
        assert r.ate_rot.rmse < 2.0
    # without noise the turn is the estimate frame's own, exactly
    exact = perturb(gt, M)
    al = evaluate(gt, exact, EvalConfig(align="se3")).segments[0].alignment
    np.testing.assert_allclose(al.R, M[:3, :3].T, atol=1e-9)


@pytest.mark.parametrize("mode", ["se3", "sim3"])
def test_at_rest_the_report_gives_both_figures(mode: str) -> None:
    """A platform at rest (reference noise 0.5 mm, estimate 1 mm): the headline takes the
    rotation from the orientations; the position-only fit is evo's, and the report gives it
    beside the headline, saying which is which."""
    from eurocslam.eval.align import DETERMINED_EXTENT_SIGMAS
    from eurocslam.eval.report import markdown, markdown_summary

    rng = np.random.default_rng(7)
    n = 100
    t = T0_NS + np.arange(n, dtype=np.int64) * 50_000_000
    R_true = rot_z(-1.1) @ so3_exp(np.array([0.01, 0.03, 0.0]))
    ref = Trajectory(t, rng.normal(0, 0.0005, (n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), name="gt")
    est_T = np.tile(np.eye(4), (n, 1, 1))
    est_T[:, :3, :3] = R_true.T @ np.stack([so3_exp(w) for w in rng.normal(0, 0.001, (n, 3))])
    est_T[:, :3, 3] = rng.normal(0, 0.001, (n, 3)) + 4.0
    est = Trajectory.from_poses(t, est_T, name="est")
    r = evaluate(ref, est, EvalConfig(align=mode))
    al = r.segments[0].alignment
    assert al.basis == "orientations" and al.s == 1.0 and al.position_fit is not None
    assert al.extent_sigmas is not None and al.extent_sigmas < DETERMINED_EXTENT_SIGMAS
    assert np.degrees(np.linalg.norm(so3_log(al.R.T @ R_true))) < 0.05
    err, stats, _ = _evo_ate(ref, est, mode)
    pos = r.ate_trans_position_fit
    assert pos is not None and r.segments[0].ate_t_position_fit is not None
    assert np.abs(r.segments[0].ate_t_position_fit - err).max() < 1e-12
    for k in ("rmse", "mean", "median", "std", "min", "max"):
        assert getattr(pos, k) == pytest.approx(stats[k], abs=1e-12), k
    assert r.ate_rot.rmse < 0.2  # the orientations' own noise
    md = markdown(r)
    assert "rotation from the orientations" in md
    assert f"ATE headline {r.ate_trans.rmse:.4f} m RMSE, with the rotation from the" in md
    scale = f", scale {al.position_fit.s:.4f}" if mode == "sim3" else ""
    assert f"the position-only fit (evo's definition{scale}) gives {pos.rmse:.4f} m RMSE" in md
    assert "| ATE translation, position-only fit (evo) [m] |" in md
    assert "\\* rotation of the alignment from the orientations" in markdown_summary([r])
    d = r.to_dict()
    assert d["ate_basis"] == "orientations" and d["ate_trans_position_fit_m"]["rmse"] == pos.rmse
    seg_al = d["segments"][0]["alignment"]  # type: ignore[index]
    assert seg_al["basis"] == "orientations" and seg_al["position_fit"]["basis"] == "positions"
