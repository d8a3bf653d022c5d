#!/usr/bin/env python3
"""A/B speed of `eurocslam run`: code revisions or settings, run for run interleaved.

The machines here are shared and their speed swings by 20-30 % within minutes, so two
variants measured one after the other compare the machine's phases as much as the code. This
runs every variant once per round, round after round, on the same semi-real replica (rendered
as `bench_slam.py` does), and prints the medians and, per round, each variant's real-time
factor over the first variant's.

A variant is NAME=REV[:ARGS]: REV a git revision, checked out into a temporary worktree (`.` is
the working tree as it is), run with this checkout's virtual environment; ARGS are extra `eurocslam
run` arguments (quote them), e.g. `base=HEAD~1 new=.` or `mcap=. nomcap=.:--no-mcap`.

usage: .venv/bin/python benchmarks/bench_ab.py --sequence V2_03 [--duration 60] [--runs 3]
       [--cache /tmp/eurocslam_replicas] NAME=REV[:ARGS] NAME=REV[:ARGS] ...
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench_slam import EXE, REPO, SEQUENCES, machine_speed, make_replica, run_one


@dataclass
class Variant:
    name: str
    rev: str
    args: list[str]
    src: Path = REPO / "src"
    runs: list[dict[str, float]] = field(default_factory=list)


def parse_variant(text: str) -> Variant:
    name, sep, rest = text.partition("=")
    if not sep or not name or not rest:
        raise SystemExit(f"variant {text!r}: expected NAME=REV[:ARGS]")
    rev, _, args = rest.partition(":")
    return Variant(name, rev, shlex.split(args))


def checkout(rev: str, into: Path) -> Path:
    """The `src` folder of `rev` (a temporary worktree), or of the working tree for '.'."""
    if rev == ".":
        return REPO / "src"
    r = subprocess.run(
        ["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(into), rev],
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        raise SystemExit(f"git revision {rev!r}: {r.stderr.strip()}")
    return into / "src"


@contextlib.contextmanager
def checked_out(variants: list[Variant], tmp: Path) -> Iterator[None]:
    """Every variant's `src` checked out (temporary worktrees, removed on the way out)."""
    worktrees = []
    try:
        for v in variants:
            v.src = checkout(v.rev, tmp / f"tree_{v.name}")
            if v.rev != ".":
                worktrees.append(v.src.parent)
        yield
    finally:
        for w in worktrees:
            subprocess.run(
                ["git", "-C", str(REPO), "worktree", "remove", "--force", str(w)],
                capture_output=True,
            )


def run_once(
    v: Variant, seq: Path, out: Path, end: float | None, mcap: bool = True
) -> dict[str, float]:
    """One `eurocslam run` of variant `v`: speed, CPU, the final batch's time and both ATEs."""
    args = [*v.args, *(["--end", f"{end:g}"] if end is not None else [])]
    env = dict(os.environ, PYTHONPATH=str(v.src))
    r = run_one(seq, out, no_imu=False, mcap=mcap, extra_args=args, env=env)
    if r["rc"] != 0:
        raise SystemExit(f"{v.name}: eurocslam run {seq.name} failed: {' '.join(r['error'])}")
    s: dict[str, Any] = r["summary"]  # type: ignore[assignment]
    cpu = float(r["cpu_s"])  # type: ignore[arg-type]
    return {
        "rtf": s["realtime_factor"],
        "wall": float(r["wall_s"]),  # type: ignore[arg-type]
        "cpu": cpu,
        "cpu_per_s": cpu / s["duration_s"],
        "final_batch": s["timings"].get("final_batch", {}).get("total_s", 0.0),
        "ate_mm": 1e3 * float(r["ate_final"]),  # type: ignore[arg-type]
        "online_mm": 1e3 * float(r["ate_online"]),  # type: ignore[arg-type]
        # loops that moved the online estimate (0 for code without place recognition)
        "loops_corrected": sum(
            1 for e in s.get("places", {}).get("loops", []) if e["correction_m"] > 0
        ),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="+", help="NAME=REV[:ARGS], at least two")
    ap.add_argument("--sequence", choices=list(SEQUENCES), default="V2_03")
    ap.add_argument("--duration", type=float, default=60.0, help="first S seconds (0: all)")
    ap.add_argument("--runs", type=int, default=3, help="rounds (every variant once each)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "eurocslam_replicas"
    )
    args = ap.parse_args()
    variants = [parse_variant(t) for t in args.variants]
    if len(variants) < 2 or len({v.name for v in variants}) != len(variants):
        raise SystemExit("give at least two variants with distinct names")
    if args.runs < 1:
        raise SystemExit("--runs: at least 1")
    if not EXE.exists():
        raise SystemExit(f"no {EXE} (set up the virtual environment: see README)")
    duration = args.duration or None
    args.cache.mkdir(parents=True, exist_ok=True)
    seq = make_replica(args.sequence, args.cache, duration, args.seed)

    with tempfile.TemporaryDirectory(prefix="bench_ab_") as tmp, checked_out(variants, Path(tmp)):
        probes = [machine_speed(seq)]
        for k in range(args.runs):
            for v in variants:
                r = run_once(v, seq, Path(tmp) / f"out_{v.name}", duration)
                v.runs.append(r)
                print(
                    f"  round {k + 1}/{args.runs} {v.name:<12} RTF {r['rtf']:.2f}  "
                    f"wall {r['wall']:.1f} s  CPU {r['cpu']:.1f} s  "
                    f"final ATE {r['ate_mm']:.2f} mm",
                    file=sys.stderr,
                    flush=True,
                )
            probes.append(machine_speed(seq))

    span = "full length" if duration is None else f"first {duration:g} s"
    print(
        f"# eurocslam run, {args.sequence} replica ({span}, seed {args.seed}), "
        f"{args.runs} rounds interleaved; medians (min-max)"
    )
    print(
        "| variant | revision | args | RTF | RTF / first: median (per round) | wall s "
        "| CPU s per data s | final batch s | final ATE mm |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    first = variants[0]
    for v in variants:

        def med(key: str, runs: list[dict[str, float]] = v.runs, spec: str = ".2f") -> str:
            xs = [r[key] for r in runs]
            return (
                f"{statistics.median(xs):{spec}} ({min(xs):{spec}}-{max(xs):{spec}})"
                if len(xs) > 1
                else f"{xs[0]:{spec}}"
            )

        ratios = [a["rtf"] / b["rtf"] for a, b in zip(v.runs, first.runs, strict=True)]
        print(
            f"| {v.name} | {v.rev} | {' '.join(v.args) or '-'} | {med('rtf')} "
            f"| {statistics.median(ratios):.3f} ({' '.join(f'{r:.3f}' for r in ratios)}) "
            f"| {med('wall', spec='.1f')} | {med('cpu_per_s')} "
            f"| {med('final_batch', spec='.1f')} | {med('ate_mm')} |"
        )
    print(
        "RTF: data seconds per wall second (MCAP included unless --no-mcap); CPU includes the "
        "extraction workers. Machine speed (ORB ms per image, one thread; before the first "
        "round and after each): " + " ".join(f"{p:.1f}" for p in probes)
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
