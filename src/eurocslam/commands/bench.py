"""`eurocslam bench`: run + eval over many sequences, N runs each, one results table."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from eurocslam.commands._args import add_alignment_arguments, positive_float

NAME = "bench"
HELP = "run + eval over many sequences (folders or a YAML list), N runs each, median table"

EPILOG = """\
examples:
  eurocslam bench MH_01_easy V1_01_easy -o bench_out --runs 3
  eurocslam bench sequences.yaml -o bench_out --jobs 2 --no-imu

sequences.yaml:
  runs: 3
  run_args: [--no-mcap]
  sequences:
    - /data/euroc/MH_01_easy
    - {name: V101, path: /data/euroc/V1_01_easy}
    - {name: synth_a, synth: {duration_s: 20, seed: 3}}

Writes OUT/bench.md and OUT/bench.json; each run's outputs and log under OUT/runs/NAME/run_K.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = EPILOG
    p.add_argument(
        "sequences", nargs="+", type=Path, help="sequence folders, or one YAML file listing them"
    )
    p.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT", help="output folder (created)"
    )
    p.add_argument(
        "--runs",
        type=int,
        metavar="N",
        help="runs per sequence, median reported (default: YAML 'runs' or 1)",
    )
    p.add_argument(
        "--jobs", type=int, metavar="J", help="runs in parallel processes (default: CPU count)"
    )
    p.add_argument("--no-imu", action="store_true", help="pass --no-imu to every run")
    add_alignment_arguments(p, "alignment for the table (default se3; see eval --help)")
    p.add_argument("--timeout", type=positive_float, metavar="S", help="kill a run after S seconds")
    p.add_argument(
        "--run-cmd",
        metavar="CMD",
        help="run command template with {seq}, {out} and optionally {no_imu} "
        "(default: eurocslam run {seq} -o {out} --no-progress {no_imu})",
    )
    p.add_argument(
        "--no-mcap", action="store_true", help="pass --no-mcap to every run (faster, smaller)"
    )


def run(args: argparse.Namespace) -> int:
    from eurocslam.errors import ConfigError
    from eurocslam.eval.bench import (
        BenchInterrupted,
        parse_run_cmd,
        plan_from_args,
        run_bench,
        write_results,
    )
    from eurocslam.eval.evaluate import EvalConfig

    plan = plan_from_args(args.sequences)
    runs = args.runs if args.runs is not None else (plan.runs or 1)
    if runs < 1:
        raise ConfigError(f"--runs must be >= 1, got {runs}")
    if args.jobs is not None and args.jobs < 1:
        raise ConfigError(f"--jobs must be >= 1, got {args.jobs}")
    if args.no_mcap and "--no-mcap" not in plan.run_args:
        plan = type(plan)(plan.sequences, plan.runs, [*plan.run_args, "--no-mcap"])
    cfg = EvalConfig(align=args.align, max_diff_s=args.max_diff)
    cmd = parse_run_cmd(args.run_cmd) if args.run_cmd else None
    try:
        records = run_bench(plan, args.output, runs, args.jobs, cmd, args.no_imu, cfg, args.timeout)
    except BenchInterrupted as e:  # keep what finished: a long bench is not lost to Ctrl-C
        if e.records:
            write_results(args.output, plan, e.records, cfg, runs)
            print(
                f"eurocslam bench: interrupted after {len(e.records)} of {e.planned} runs; "
                f"their results: {args.output / 'bench.md'}, {args.output / 'bench.json'}",
                file=sys.stderr,
            )
        raise
    md, _ = write_results(args.output, plan, records, cfg, runs)
    print(md)
    print(f"results: {args.output / 'bench.md'}, {args.output / 'bench.json'}")
    return 0 if all(r.ok for r in records) else 1
