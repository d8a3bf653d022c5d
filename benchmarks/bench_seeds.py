#!/usr/bin/env python3
"""Accuracy of `eurocslam run` variants over several seeds of the same replicas.

A change that alters what the frontend extracts or tracks moves the final ATE of a single
replica by 10-50 % either way on one seed (RESULTS.md, "How far the final ATE moves by itself"),
so one seed cannot tell a cost from luck. This runs every variant on every seed of every replica
(each seed renders the same real motion with another world, image noise and IMU noise) and
prints, per replica, the final ATE of each seed, their mean and the mean's change against the
first variant, and over all replicas the mean of those changes and how many runs got worse.

A variant is NAME=REV[:ARGS] as in `bench_ab.py` (`base=HEAD new=.`, `te2=.:"--config
te2.yaml"`). Runs write no MCAP (accuracy only; `bench_ab.py` measures speed). Replicas are
rendered once into --cache (`<SEQ>_full_s<SEED>`, as `bench_slam.py` names them).

usage: .venv/bin/python benchmarks/bench_seeds.py [--sequences MH_04,MH_05,V1_03]
       [--seeds 0,1,2] [--duration 0] [--json out.json] NAME=REV[:ARGS] [NAME=REV[:ARGS] ...]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

from bench_ab import Variant, checked_out, parse_variant, run_once
from bench_slam import EXE, SEQUENCES, make_replica


def int_list(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: comma-separated integers") from None


def sequence_list(text: str) -> list[str]:
    names = [x.strip() for x in text.split(",") if x.strip()]
    bad = [n for n in names if n not in SEQUENCES]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"{text!r}: choose from {','.join(SEQUENCES)}")
    return names


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="+", help="NAME=REV[:ARGS]; the first is the reference")
    ap.add_argument("--sequences", type=sequence_list, default=["MH_04", "MH_05", "V1_03"])
    ap.add_argument("--seeds", type=int_list, default=[0, 1, 2])
    ap.add_argument("--duration", type=float, default=0.0, help="first S seconds (0: all)")
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "eurocslam_replicas"
    )
    ap.add_argument("--json", type=Path, help="also write every run's figures here")
    args = ap.parse_args()
    variants = [parse_variant(t) for t in args.variants]
    if len({v.name for v in variants}) != len(variants):
        raise SystemExit("variant names must differ")
    if not args.seeds:
        raise SystemExit("--seeds: at least one")
    if not EXE.exists():
        raise SystemExit(f"no {EXE} (set up the virtual environment: see README)")
    duration = args.duration or None
    args.cache.mkdir(parents=True, exist_ok=True)
    # results[variant][sequence] = one dict per seed, in --seeds order
    results: dict[str, dict[str, list[dict[str, float]]]] = {v.name: {} for v in variants}
    with (
        tempfile.TemporaryDirectory(prefix="bench_seeds_") as tmp,
        checked_out(variants, Path(tmp)),
    ):
        n, total = 0, len(args.sequences) * len(args.seeds) * len(variants)
        for s, seed in ((s, seed) for s in args.sequences for seed in args.seeds):
            # rendered when its turn comes (1.6-2.6 GB each), not all of them first
            seq = make_replica(s, args.cache, duration, seed)
            for v in variants:
                r = run_once(v, seq, Path(tmp) / f"out_{v.name}", duration, mcap=False)
                results[v.name].setdefault(s, []).append(r)
                n += 1
                print(
                    f"  [{n}/{total}] {s} seed {seed} {v.name:<12} final ATE "
                    f"{r['ate_mm']:.2f} mm, online {r['online_mm']:.2f} mm",
                    file=sys.stderr,
                    flush=True,
                )
    report(args, variants, results)
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "sequences": args.sequences,
                    "seeds": args.seeds,
                    "duration_s": duration,
                    "variants": {v.name: {"rev": v.rev, "args": v.args} for v in variants},
                    "results": results,
                },
                indent=1,
            )
        )
    return 0


def report(
    args: argparse.Namespace,
    variants: list[Variant],
    results: dict[str, dict[str, list[dict[str, float]]]],
) -> None:
    span = "full length" if not args.duration else f"first {args.duration:g} s"
    seeds = "/".join(str(s) for s in args.seeds)
    print(f"# eurocslam run, final ATE (mm) over seeds {seeds} ({span}, no MCAP)")
    print("| replica | variant | per seed | mean | change of the mean | online mean |")
    print("|---|---|---|---|---|---|")
    first = variants[0].name
    changes: dict[str, list[float]] = {v.name: [] for v in variants}
    worse: dict[str, int] = {v.name: 0 for v in variants}
    for s in args.sequences:
        ref = statistics.mean(r["ate_mm"] for r in results[first][s])
        for v in variants:
            runs = results[v.name][s]
            mean = statistics.mean(r["ate_mm"] for r in runs)
            change = mean / ref - 1.0
            changes[v.name].append(change)
            worse[v.name] += sum(
                r["ate_mm"] > b["ate_mm"] for r, b in zip(runs, results[first][s], strict=True)
            )
            online = statistics.mean(r["online_mm"] for r in runs)
            per_seed = " / ".join(f"{r['ate_mm']:.2f}" for r in runs)
            print(
                f"| {s} | {v.name} | {per_seed} | {mean:.2f} | {100 * change:+.1f} % "
                f"| {online:.2f} |"
            )
    n_runs = len(args.sequences) * len(args.seeds)
    for v in variants[1:]:
        print(
            f"{v.name} against {first}: the replicas' mean final ATE "
            f"{100 * statistics.mean(changes[v.name]):+.1f} % on average "
            f"({min(changes[v.name]) * 100:+.1f} to {max(changes[v.name]) * 100:+.1f} %), "
            f"{worse[v.name]} of {n_runs} runs worse"
        )


if __name__ == "__main__":
    sys.exit(main())
