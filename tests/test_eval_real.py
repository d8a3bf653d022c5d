"""Evaluator on real EuRoC data against evo's saved results (skips when the data is absent)."""

from __future__ import annotations

import copy
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from eurocslam.eval.evaluate import EvalConfig, evaluate
from eurocslam.eval.loaders import load_estimates, load_groundtruth


def _evo_zip(path: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    with zipfile.ZipFile(path) as z:
        stats = json.loads(z.read("stats.json"))
        err = np.load(io.BytesIO(z.read("error_array.npy")))
        stamps = np.load(io.BytesIO(z.read("timestamps.npy")))
    return stats, err, stamps


@pytest.fixture(scope="module")
def vins(euroc_dir: Path):
    d = euroc_dir / "eval_reference/vins_mono_MH_01"
    gt = load_groundtruth(d / "ground_truth.tum").traj
    est = load_estimates(d / "vins_tum.txt")[0].traj
    return d, evaluate(gt, est, EvalConfig(align="se3", max_diff_s=0.1))


def test_vins_mono_mh01_ate_equals_evo(vins) -> None:
    d, r = vins
    assert r.ate_trans.rmse == pytest.approx(0.140305, abs=1e-5)
    stats, err, stamps = _evo_zip(d / "ate_results.zip")
    for k in ("rmse", "mean", "median", "std", "min", "max"):
        assert getattr(r.ate_trans, k) == pytest.approx(stats[k], abs=1e-9), k
    # per-pose: same poses, same errors
    s = r.segments[0]
    assert len(err) == len(s.ate_t)
    assert np.abs(s.ate_t - err).max() < 1e-9
    # evo stores the estimate's stamps of the matched pairs
    est_t = load_estimates(d / "vins_tum.txt")[0].traj.t_ns[s.association.idx_est]
    assert np.abs(est_t / 1e9 - stamps).max() < 1e-6


def test_vins_mono_mh01_rpe_equals_evo(vins) -> None:
    d, r = vins
    assert r.rpe_delta_trans.rmse == pytest.approx(0.230288, abs=1e-5)
    stats, err, _ = _evo_zip(d / "rpe_results.zip")
    for k in ("rmse", "mean", "median", "std", "min", "max"):
        assert getattr(r.rpe_delta_trans, k) == pytest.approx(stats[k], abs=1e-9), k
    assert np.abs(r.segments[0].rpe_t - err).max() < 1e-9
    assert (r.matched, r.possible) == (771, 773)


@pytest.fixture(scope="module")
def v102(euroc_dir: Path):
    from evo.core import sync
    from evo.tools import file_interface

    gt_path = euroc_dir / "groundtruth/V1_02_medium.csv"
    est_path = euroc_dir / "eval_reference/V1_02_estimate/estimate_tum.txt"
    ours = (load_groundtruth(gt_path).traj, load_estimates(est_path)[0].traj)
    evo_pair = sync.associate_trajectories(
        file_interface.read_euroc_csv_trajectory(str(gt_path)),
        file_interface.read_tum_trajectory_file(str(est_path)),
    )
    return ours, evo_pair


@pytest.mark.parametrize("mode", ["se3", "sim3", "origin"])
def test_v102_estimate_matches_evo(v102, mode: str) -> None:
    from evo.core import metrics

    (gt, est), (ref_e, est_e) = v102
    r = evaluate(gt, est, EvalConfig(align=mode))
    est_e = copy.deepcopy(est_e)
    if mode == "origin":
        est_e.align_origin(ref_e)
    else:
        est_e.align(ref_e, correct_scale=mode == "sim3")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part)
    rpe.process_data((ref_e, est_e))
    rmse = metrics.StatisticsType.rmse
    assert r.matched == ref_e.num_poses == 798
    assert r.ate_trans.rmse == pytest.approx(ape.get_statistic(rmse), abs=1e-9)
    assert r.rpe_delta_trans.rmse == pytest.approx(rpe.get_statistic(rmse), abs=1e-9)
    if mode == "se3":
        assert r.ate_trans.rmse == pytest.approx(0.0917271, abs=1e-6)


def test_groundtruth_from_sequence_folder(mh01_first5: Path) -> None:
    gt = load_groundtruth(mh01_first5)
    assert gt.source.endswith("state_groundtruth_estimate0/data.csv")
    assert len(gt.traj) == 5


# ---- where evo's fit of positions is the ATE, and where it is not (issue #35) -------------------


def _evo_ate_errors(ref, est, mode: str) -> np.ndarray:
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D

    def to_evo(tr):
        return PoseTrajectory3D(
            positions_xyz=tr.p.copy(),
            orientations_quat_wxyz=tr.q_wxyz.copy(),
            timestamps=tr.t_ns / 1e9,
        )

    ref_e, est_e = sync.associate_trajectories(to_evo(ref), to_evo(est), max_diff=0.01)
    est_e.align(ref_e, correct_scale=mode == "sim3")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    return np.asarray(ape.error)


@pytest.mark.parametrize("mode", ["se3", "sim3"])
def test_kitti_excerpt_equals_evo(kitti_excerpt: Path, mode: str) -> None:
    """A real road (KITTI 01, a highway: 45 m net, a gentle curve) against a perturbed copy of
    its own ground truth (3 cm noise, 2 mm/frame random walk, another frame): evo's fit of
    positions, every error equal."""
    from eurocslam.eval.synthetic import perturb, random_similarity

    gt = load_groundtruth(kitti_excerpt / "poses" / "k2.txt").traj
    est = perturb(
        gt,
        random_similarity(8, 0.95 if mode == "sim3" else 1.0),
        noise_m=0.03,
        noise_rad=0.002,
        drift_m=0.002,
        seed=9,
    )
    r = evaluate(gt, est, EvalConfig(align=mode))
    al = r.segments[0].alignment
    assert al.basis == "positions" and r.ate_trans_position_fit is None
    assert np.abs(r.segments[0].ate_t - _evo_ate_errors(gt, est, mode)).max() < 1e-9


@pytest.mark.parametrize("mode", ["se3", "sim3"])
def test_v101_excerpt_at_rest_reports_both_figures(v101_micro: Path, mode: str) -> None:
    """The real V1_01 excerpt, the drone on the floor (99 ground-truth poses over the 4.9 s of
    images, 3 mm of extent), against a perturbed copy of its ground truth (1 mm noise, 0.1 deg,
    another frame): the positions do not decide the fit, the headline takes the rotation from
    the orientations and recovers the copy's frame; the position-only figure is evo's."""
    from eurocslam.dataset import open_sequence
    from eurocslam.eval.synthetic import perturb, random_similarity

    frames = open_sequence(v101_micro).frame_times
    full = load_groundtruth(v101_micro).traj
    keep = np.flatnonzero((full.t_ns >= frames[0]) & (full.t_ns <= frames[-1]))
    gt = full.take(keep)
    M = random_similarity(21)
    est = perturb(gt, M, noise_m=0.001, noise_rad=0.002, seed=22)
    r = evaluate(gt, est, EvalConfig(align=mode))
    al = r.segments[0].alignment
    assert len(gt) == 99 and al.basis == "orientations" and al.s == 1.0
    R_err = al.R @ M[:3, :3]  # identity when the copy's frame is recovered
    assert np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1))) < 0.1
    assert r.ate_rot.rmse < 0.3 and r.ate_trans.rmse < 0.003
    pos = r.segments[0].ate_t_position_fit
    assert pos is not None
    assert np.abs(pos - _evo_ate_errors(gt, est, mode)).max() < 1e-12
