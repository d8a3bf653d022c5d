"""Evaluator speed: ATE + RPE of a 4,000-pose estimate against a 40,000-pose ground truth,
side by side with evo on the same input (same process, interleaved, median of repeats).

    .venv/bin/python benchmarks/bench_eval.py [--repeats 7]

Rows:
  eurocslam evaluate : association + SE(3) alignment + ATE (trans, rot) + RPE 1 frame
                       (trans, rot) + RPE over 5 distances (rpg style, all start poses)
  evo                : associate_trajectories + align + APE trans + APE rot + RPE trans +
                       RPE rot (delta 1 frame) -- evo has no rpg-style distance RPE
  read 40k-line file : our TUM reader (exact ns) vs evo's file_interface
The machine is shared: compare the ratio within one run, not absolute numbers across runs.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import tempfile
import time
from pathlib import Path

from eurocslam.eval.evaluate import EvalConfig, evaluate
from eurocslam.eval.synthetic import perturb, random_similarity, smooth_trajectory
from eurocslam.trajectory_io import read_tum, write_tum


def _to_evo(tr):
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(
        positions_xyz=tr.p.copy(),
        orientations_quat_wxyz=tr.q_wxyz.copy(),
        timestamps=tr.t_ns / 1e9,
    )


def run_evo(ref_e, est_e) -> float:
    from evo.core import metrics, sync

    r, e = sync.associate_trajectories(ref_e, est_e, max_diff=0.01)
    e = copy.deepcopy(e)
    e.align(r)
    P = metrics.PoseRelation
    out = 0.0
    for m in (
        metrics.APE(P.translation_part),
        metrics.APE(P.rotation_angle_deg),
        metrics.RPE(P.translation_part),
        metrics.RPE(P.rotation_angle_deg),
    ):
        m.process_data((r, e))
        out = m.get_statistic(metrics.StatisticsType.rmse)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--gt", type=int, default=40_000)
    ap.add_argument("--est", type=int, default=4_000)
    args = ap.parse_args()

    gt = smooth_trajectory(args.gt, 200.0, seed=1, name="gt")
    est = perturb(
        gt,
        random_similarity(2),
        step=args.gt // args.est,
        noise_m=0.02,
        noise_rad=0.01,
        drift_m=0.002,
        jitter_ns=2_000_000,
        seed=3,
        name="est",
    )
    ref_e, est_e = _to_evo(gt), _to_evo(est)
    cfg = EvalConfig(align="se3")

    tmp = Path(tempfile.mkdtemp(prefix="bench_eval_"))
    write_tum(tmp / "gt.tum", gt)

    def read_ours() -> None:
        read_tum(tmp / "gt.tum")

    def read_evo() -> None:
        from evo.tools import file_interface

        file_interface.read_tum_trajectory_file(str(tmp / "gt.tum"))

    jobs = {
        "eurocslam evaluate": lambda: evaluate(gt, est, cfg),
        "evo (APE+RPE, 1 frame)": lambda: run_evo(ref_e, est_e),
        "read 40k-line TUM: eurocslam": read_ours,
        "read 40k-line TUM: evo": read_evo,
    }
    times: dict[str, list[float]] = {k: [] for k in jobs}
    for f in jobs.values():  # warm-up (imports, caches)
        f()
    for _ in range(args.repeats):  # interleaved so load changes hit every row alike
        for k, f in jobs.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)

    r = evaluate(gt, est, cfg)
    print(
        f"ground truth {len(gt)} poses, estimate {len(est)} poses, matched {r.matched}, "
        f"RPE pairs: 1 frame {r.rpe_delta_trans.n}, distance "
        f"{sum(L.trans.n for L in r.lengths)}; {args.repeats} repeats"
    )
    print(
        f"ATE rmse ours {r.ate_trans.rmse:.6f} m; RPE(1 frame) rot rmse ours "
        f"{r.rpe_delta_rot.rmse:.6f} deg, evo {run_evo(ref_e, est_e):.6f} deg"
    )
    print()
    print("| task | median [ms] | min [ms] | max [ms] |")
    print("|---|---|---|---|")
    for k, v in times.items():
        print(
            f"| {k} | {1e3 * statistics.median(v):.1f} | {1e3 * min(v):.1f} | {1e3 * max(v):.1f} |"
        )
    ours = statistics.median(times["eurocslam evaluate"])
    evo = statistics.median(times["evo (APE+RPE, 1 frame)"])
    print()
    print(f"evo / eurocslam evaluate: {evo / ours:.1f}x (eurocslam also computes 5 distance RPEs)")
    print(f"under 1 s: {'yes' if ours < 1.0 else 'NO'} ({ours:.3f} s)")


if __name__ == "__main__":
    main()
