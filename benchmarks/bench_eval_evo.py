#!/usr/bin/env python3
"""`eurocslam eval` against evo where their ATE must agree and where eval departs on purpose
(issue #35): straight roads, the real KITTI excerpt, the real V1_01 excerpt (a drone at rest).

For each case and alignment (se3 = `evo_ape -a`, sim3 = `-as`) it prints: the matched poses,
the alignment's `extent_sigmas` (the reference's RMS extent along its main direction over the
position fit's per-axis RMS residual; the positions decide the fit from 3 on), its basis
(positions = evo's fit; orientations = the rotation from the orientations, a platform at rest),
eval's headline ATE RMSE, eval's position-only ATE RMSE, evo's, the largest per-pose difference
between eval's position-only errors and evo's, and ATE rotation RMSE of both.

Cases: a straight 60 m road with 3 mm of wiggle and a 1 m one (synthetic, 3 cm noise); exactly
straight 60 m and 1 m roads (evo raises on the short one: its absolute rank test); the two real
excerpts' ground truths against perturbed copies of themselves; and, unless --no-runs, the final
and online trajectories of `eurocslam run` on both excerpts (a subprocess each, ~10 s).

usage: .venv/bin/python benchmarks/bench_eval_evo.py [--no-runs] [--out DIR]
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from eurocslam.eval.evaluate import EvalConfig, evaluate
from eurocslam.eval.loaders import load_estimates, load_groundtruth
from eurocslam.eval.synthetic import perturb, random_similarity, straight_road
from eurocslam.trajectory import Trajectory

REPO = Path(__file__).resolve().parents[1]
EUROC = Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))
KITTI = Path(os.environ.get("EUROCSLAM_SHARED_KITTI", REPO.parent / "shared/data/kitti_excerpt"))
EXE = REPO / ".venv" / "bin" / "eurocslam"


def evo_ate(ref: Trajectory, est: Trajectory, mode: str) -> tuple[np.ndarray, float] | None:
    """evo's per-pose APE translation and APE rotation RMSE, or None where evo raises."""
    from evo.core import metrics, sync
    from evo.core.geometry import GeometryException
    from evo.core.trajectory import PoseTrajectory3D

    def to_evo(t: Trajectory) -> PoseTrajectory3D:
        return PoseTrajectory3D(
            positions_xyz=t.p.copy(),
            orientations_quat_wxyz=t.q_wxyz.copy(),
            timestamps=t.t_ns / 1e9,
        )

    ref_e, est_e = sync.associate_trajectories(to_evo(ref), to_evo(est), max_diff=0.01)
    est_e = copy.deepcopy(est_e)
    try:
        est_e.align(ref_e, correct_scale=mode == "sim3")
    except GeometryException:
        return None
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    ape_r = metrics.APE(metrics.PoseRelation.rotation_angle_deg)
    ape_r.process_data((ref_e, est_e))
    return np.asarray(ape.error), float(ape_r.get_statistic(metrics.StatisticsType.rmse))


def row(case: str, ref: Trajectory, est: Trajectory, mode: str) -> str:
    r = evaluate(ref, est, EvalConfig(align=mode))
    (seg,) = r.segments
    al = seg.alignment
    mine = seg.ate_t_position_fit if al.from_orientations else seg.ate_t
    pos = float("nan") if mine is None else float(np.sqrt(np.mean(mine**2)))
    evo = evo_ate(ref, est, mode)
    if evo is None:
        evo_s, diff_s, evo_rot_s = f"{'raises':>10}", f"{'-':>10}", f"{'-':>8}"
    else:
        err, rot = evo
        diff = float(np.abs(mine - err).max()) if mine is not None else float("nan")
        evo_s = f"{float(np.sqrt(np.mean(err**2))):>10.6f}"
        diff_s, evo_rot_s = f"{diff:>10.1e}", f"{rot:>8.3f}"
    return (
        f"{case:<40}{mode:<6}{r.matched:>6}{al.extent_sigmas or float('nan'):>9.1f}"
        f"  {al.basis:<13}{r.ate_trans.rmse:>10.6f}{pos:>10.6f}{evo_s}{diff_s}"
        f"{r.ate_rot.rmse:>8.3f}{evo_rot_s}"
    )


def run_slam(seq: Path, out: Path) -> Path:
    from eurocslam.eval.bench.process import last_line, run_process

    out.parent.mkdir(parents=True, exist_ok=True)
    log = out.parent / f"{out.name}.log"
    cmd = [str(EXE), "run", str(seq), "-o", str(out), "--no-mcap", "--no-progress"]
    if run_process(cmd, log).returncode != 0:
        raise SystemExit(f"{seq}: eurocslam run failed: {last_line(log)} (log: {log})")
    return out


def cases(runs_dir: Path | None) -> list[tuple[str, Trajectory, Trajectory]]:
    out: list[tuple[str, Trajectory, Trajectory]] = []
    M = random_similarity(3)
    for length in (60.0, 1.0):
        gt = straight_road(length, 0.003)
        est = perturb(gt, M, noise_m=0.03, noise_rad=0.01, drift_m=0.002, seed=2)
        out.append((f"road {length:g} m, 3 mm wiggle", gt, est))
    for length in (60.0, 1.0):
        gt = straight_road(length, 0.0, direction=(0.6, -0.3, 0.2))
        est = perturb(gt, M, noise_m=0.002 * length, noise_rad=0.01, seed=3)
        out.append((f"road {length:g} m, exactly straight", gt, est))
    kitti_seq = KITTI / "sequences" / "k2"
    if kitti_seq.is_dir():
        gt = load_groundtruth(KITTI / "poses" / "k2.txt").traj
        est = perturb(gt, random_similarity(8), noise_m=0.03, noise_rad=0.002, drift_m=0.002)
        out.append(("KITTI excerpt, perturbed GT", gt, est))
        if runs_dir is not None:
            for e in load_estimates(run_slam(kitti_seq, runs_dir / "kitti")):
                out.append((f"KITTI excerpt, run {e.label.split()[0]}", gt, e.traj))
    v101 = EUROC / "V1_01_easy_micro"
    if v101.is_dir():
        from eurocslam.dataset import open_sequence

        frames = open_sequence(v101).frame_times
        full = load_groundtruth(v101).traj
        gt = full.take(np.flatnonzero((full.t_ns >= frames[0]) & (full.t_ns <= frames[-1])))
        est = perturb(gt, random_similarity(21), noise_m=0.001, noise_rad=0.002, seed=22)
        out.append(("V1_01 excerpt (at rest), perturbed", gt, est))
        if runs_dir is not None:
            for e in load_estimates(run_slam(v101, runs_dir / "v101")):
                out.append((f"V1_01 excerpt (at rest), run {e.label.split()[0]}", gt, e.traj))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--no-runs", action="store_true", help="skip eurocslam run on the excerpts")
    ap.add_argument("--out", type=Path, help="keep the runs here (default: a temporary folder)")
    args = ap.parse_args()
    tmp = tempfile.TemporaryDirectory(prefix="bench_eval_evo_")
    runs_dir = None if args.no_runs else (args.out or Path(tmp.name))
    print(f"# eurocslam eval vs evo, {time.strftime('%Y-%m-%d %H:%M')}")
    print(
        f"{'case':<40}{'align':<6}{'poses':>6}{'extent':>9}  {'basis':<13}{'ATE m':>10}"
        f"{'pos-only':>10}{'evo m':>10}{'max diff':>10}{'rot deg':>8}{'evo deg':>8}"
    )
    for case, ref, est in cases(runs_dir):
        for mode in ("se3", "sim3"):
            print(row(case, ref, est, mode), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
