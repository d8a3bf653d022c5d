#!/usr/bin/env python3
"""How well a loop recognised by appearance measures the drift it would correct, and what the
gate makes of it.

Each replica (`bench_slam.py`'s, rendered from the real EuRoC motion, exact ground truth) is run
in this process with the pipeline's place stage watched: for every loop the recognizer verifies
online (`PlaceStage.loop`), the *measured* correction D (the world-frame move that puts the
query keyframe's current estimate where the verified match says it is, relative to the
candidate keyframe's current estimate) is compared with the *true* one (the same move computed
from the ground-truth relative pose of the two keyframes). Sizes are the rotation angle and the
displacement of the query's position. Printed: per bucket of verified inliers, how many loops,
the median and 90th percentile of |measured - true|, and the median true drift; then every loop
that reached the gate (large enough to correct, consistent over keyframes) with its measured and
true drift, the gate's chi-square and whether it was applied or refused; then the final and
online ATE (one SE(3) alignment).

    .venv/bin/python benchmarks/bench_loops.py --sequences MH_04 --no-imu
    .venv/bin/python benchmarks/bench_loops.py --sequences V1_03 --seeds 0 1 --duration 40 --blur
    .venv/bin/python benchmarks/bench_loops.py --sequences MH_04 V2_02 --no-imu --config FILE
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from eurocslam.config import config_from_dict
from eurocslam.dataset import open_sequence
from eurocslam.eval.align import align
from eurocslam.geometry import F64, inv_T, so3_log
from eurocslam.pipeline import places as place_stage
from eurocslam.pipeline.slam import SlamPipeline

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_slam  # the replicas are shared

BUCKETS = [(40, 60), (60, 100), (100, 150), (150, 10**6)]


def _size(D: F64, p: F64) -> tuple[float, float]:
    """(degrees, metres) of a world-frame move D at the point p."""
    return (
        float(np.degrees(np.linalg.norm(so3_log(D[:3, :3])))),
        float(np.linalg.norm(D[:3, :3] @ p + D[:3, 3] - p)),
    )


def run(seq_path: Path, cfg: dict[str, object]) -> tuple[list[dict[str, Any]], dict[str, float]]:
    seq = open_sequence(seq_path, quiet=True)
    gt = seq.groundtruth
    assert gt is not None
    T_gt = gt.T_world_body()

    def gt_pose(t_ns: int) -> F64:
        return T_gt[int(np.clip(np.searchsorted(gt.t_ns, t_ns), 0, len(gt) - 1))]

    loops: list[dict[str, Any]] = []
    loop = place_stage.PlaceStage.loop
    find = place_stage.PlaceStage._find

    def watched_loop(self, view, segment, T_seg_query, *args, **kwargs):  # type: ignore[no-untyped-def]
        seen = []

        def watched_find(v, accept, *a, **kw):  # type: ignore[no-untyped-def]
            m = find(self, v, accept, *a, **kw)
            seen.append(m)
            return m

        self._find = watched_find
        try:
            answer = loop(self, view, segment, T_seg_query, *args, **kwargs)
        finally:
            del self._find
        gated = [e for e in answer.events if e.gate_chi2 == e.gate_chi2]
        m = seen[-1] if seen else None
        if m is not None and self._keyframes[m.key].segment == segment:
            ref = self._keyframes[m.key]
            T_cand = self._in_frame(m.key)
            measured = m.T_world_query @ inv_T(T_seg_query)
            true = T_cand @ inv_T(gt_pose(ref.t_ns)) @ gt_pose(view.t_ns) @ inv_T(T_seg_query)
            p = T_seg_query[:3, 3]
            err_deg, err_m = _size(measured @ inv_T(true), p)
            true_deg, true_m = _size(true, p)
            meas_deg, meas_m = _size(measured, p)
            loops.append(
                {
                    "t_s": (view.t_ns - seq.frame_times[0]) * 1e-9,
                    "inliers": m.n_inliers,
                    "err_deg": err_deg,
                    "err_m": err_m,
                    "true_deg": true_deg,
                    "true_m": true_m,
                    "meas_deg": meas_deg,
                    "meas_m": meas_m,
                    "gate_chi2": gated[0].gate_chi2 if gated else None,
                    "corrected": answer.loop is not None,
                }
            )
        return answer

    place_stage.PlaceStage.loop = watched_loop  # type: ignore[method-assign]
    try:
        res = SlamPipeline(seq, config_from_dict(cfg)).run()
    finally:
        place_stage.PlaceStage.loop = loop  # type: ignore[method-assign]
    ate = {}
    for name, t, P in (
        ("online", res.online.t_ns, res.online.p),
        ("final", res.final.t_ns, res.final.p),
    ):
        G = gt.p[np.clip(np.searchsorted(gt.t_ns, t), 0, len(gt) - 1)]
        a = align("se3", G, P)
        e = np.linalg.norm(G - (P @ a.R.T + a.t), axis=1)
        ate[name] = float(np.sqrt(np.mean(e**2)))
    return loops, ate


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequences", nargs="+", default=["MH_04"], choices=list(bench_slam.SEQUENCES))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="worlds (worlds.py)")
    ap.add_argument("--no-imu", action="store_true", help="visual-only runs")
    ap.add_argument("--config", type=Path, help="YAML config (e.g. places.correct_loops_online)")
    ap.add_argument("--duration", type=float, default=0.0, help="first S seconds (0: full)")
    ap.add_argument("--blur", action="store_true", help="replicas with motion blur")
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "eurocslam_replicas"
    )
    args = ap.parse_args()
    cfg = yaml.safe_load(args.config.read_text()) if args.config else {}
    cfg = cfg or {}
    if args.no_imu:
        cfg["mode"] = "visual-only"
    mode = cfg.get("mode", "auto")
    print(
        f"# loops measured against ground truth (mode {mode}, config {args.config}, worlds "
        f"{' '.join(map(str, args.seeds))}{', motion blur' if args.blur else ''})"
    )
    print(
        "\n| sequence | inliers | loops | error median [deg / cm] | error p90 [deg / cm] "
        "| true drift median [deg / cm] |\n|---|---|---|---|---|---|"
    )
    tails, gated_rows = [], []
    for name in args.sequences:
        for seed in args.seeds:
            duration = args.duration if args.duration > 0 else None
            path = bench_slam.make_replica(name, args.cache, duration, seed, args.blur)
            loops, ate = run(path, cfg)
            label_seq = f"{name} w{seed}"
            for lo, hi in BUCKETS:
                b = [r for r in loops if lo <= r["inliers"] < hi]
                if not b:
                    continue
                e_deg = np.array([r["err_deg"] for r in b])
                e_cm = 100 * np.array([r["err_m"] for r in b])
                t_deg = np.array([r["true_deg"] for r in b])
                t_cm = 100 * np.array([r["true_m"] for r in b])
                label = f"{lo}-{hi - 1}" if hi < 10**6 else f">= {lo}"
                print(
                    f"| {label_seq} | {label} | {len(b)} | {np.median(e_deg):.2f} / "
                    f"{np.median(e_cm):.1f} | {np.percentile(e_deg, 90):.2f} / "
                    f"{np.percentile(e_cm, 90):.1f} | {np.median(t_deg):.2f} / "
                    f"{np.median(t_cm):.1f} |",
                    flush=True,
                )
            for r in loops:
                if r["gate_chi2"] is not None:
                    gated_rows.append(
                        f"| {label_seq} | {r['t_s']:.1f} | {r['inliers']} "
                        f"| {r['meas_deg']:.2f} / {100 * r['meas_m']:.1f} "
                        f"| {r['true_deg']:.2f} / {100 * r['true_m']:.1f} "
                        f"| {r['err_deg']:.2f} / {100 * r['err_m']:.1f} "
                        f"| {r['gate_chi2']:.1f} | {'applied' if r['corrected'] else 'refused'} |"
                    )
            n_fixed = sum(r["corrected"] for r in loops)
            tails.append(
                f"{label_seq}: {len(loops)} loops, {n_fixed} corrected online; ATE final "
                f"{1e3 * ate['final']:.1f} mm, online {1e3 * ate['online']:.1f} mm"
            )
    print(
        "\nLoops that reached the gate (consistent, large enough to correct): drift as the loop "
        "measured it and as the ground truth has it, the loop's error, the gate's chi-square "
        "(6 DoF, applied at or below places.loop_gate_chi2)\n\n"
        "| sequence | t [s] | inliers | measured drift [deg / cm] | true drift [deg / cm] "
        "| error [deg / cm] | chi-square | verdict |\n|---|---|---|---|---|---|---|---|"
    )
    print("\n".join(gated_rows) if gated_rows else "| (none) | | | | | | | |")
    print("\n" + "\n".join(tails))
    return 0


if __name__ == "__main__":
    sys.exit(main())
