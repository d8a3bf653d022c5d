"""`eurocslam bench`: run + eval over sequences x configurations x runs, one median table."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from eurocslam.commands._args import add_alignment_arguments, positive_float

if TYPE_CHECKING:  # the library is imported when the command runs, not for --help
    from eurocslam.eval.bench import BenchOptions

NAME = "bench"
HELP = "run + eval over many sequences and configurations, N runs each, median table"

EPILOG = """\
examples:
  eurocslam bench MH_01_easy V1_01_easy -o bench_out --runs 3
  eurocslam bench sequences.yaml -o bench_out --jobs 2 --no-imu
  eurocslam bench sequences.yaml -o sweep --config base=euroc.yaml --config fast=fast.yaml
  eurocslam bench sequences.yaml -o sweep --runs 3 --executor ray --address head:6379

sequences.yaml:
  runs: 3
  run_args: [--no-mcap]
  configs:                                  # optional: a sweep, one column group each
    base: ~                                 #   the built-in defaults
    mine: my_config.yaml                    #   a config file
    n800: {frontend: {n_features: 800}}     #   these keys over the defaults
  sequences:
    - /data/euroc/MH_01_easy
    - {name: V101, path: /data/euroc/V1_01_easy}
    - {name: synth_a, synth: {duration_s: 20, seed: 3}}

Writes OUT/bench.md and OUT/bench.json (every run); each run's outputs, log and evaluation under
OUT/runs/CONFIG/SEQUENCE/run_K. Running again into the same OUT keeps the runs that finished
(with the same settings) and runs the rest; --force runs everything again.

Ray: every run is a task on the cluster's workers. Sequence folders must be readable at the same
path on every node (a shared filesystem); synth sequences are rendered on the workers. Outputs go
straight into OUT when the workers see it, else they are brought back. Install: pip install
'eurocslam[ray]' on this machine and every node.
"""

RAY_ONLY = ("address", "cpus_per_run", "ray_outputs", "worker_cache")


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
        help="runs per sequence and configuration, median reported (default: YAML 'runs' or 1)",
    )
    p.add_argument(
        "--config",
        action="append",
        default=[],
        metavar="NAME=FILE",
        help="a configuration to sweep (repeat for several; with the YAML's 'configs'); "
        "default: the built-in one",
    )
    p.add_argument("--no-imu", action="store_true", help="pass --no-imu to every run")
    p.add_argument(
        "--no-mcap", action="store_true", help="pass --no-mcap to every run (faster, smaller)"
    )
    add_alignment_arguments(p, "alignment for the table (default se3; see eval --help)")
    p.add_argument("--timeout", type=positive_float, metavar="S", help="stop a run after S seconds")
    p.add_argument(
        "--force", action="store_true", help="run everything again, also runs finished in OUT"
    )
    p.add_argument(
        "--run-cmd",
        metavar="CMD",
        help="run command template with {seq}, {out} and optionally {no_imu}, {python} "
        "(default: {python} -m eurocslam.cli run {seq} -o {out} --no-progress {no_imu})",
    )
    ex = p.add_argument_group("where runs execute")
    ex.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="local: processes on this machine (default); ray: tasks on a Ray cluster",
    )
    ex.add_argument(
        "--jobs", type=int, metavar="J", help="local: runs in parallel (default: CPU count)"
    )
    ex.add_argument(
        "--address",
        metavar="HOST:PORT",
        help="ray: the cluster's head (default: auto, the cluster this machine belongs to)",
    )
    ex.add_argument(
        "--cpus-per-run",
        type=positive_float,
        metavar="N",
        help="ray: CPUs each run reserves on its node (default 2: a run and its extraction "
        "workers)",
    )
    ex.add_argument(
        "--ray-outputs",
        choices=("auto", "shared", "fetch"),
        help="ray: shared = workers write into OUT (a shared filesystem); fetch = outputs are "
        "brought back into OUT; auto (default): shared when every node sees OUT",
    )
    ex.add_argument(
        "--worker-cache",
        metavar="DIR",
        help="ray: folder on the workers for synth sequences rendered there and outputs before "
        "they are brought back (default: the worker's temp folder)",
    )


def _options(args: argparse.Namespace, runs: int) -> BenchOptions:
    from eurocslam.errors import ConfigError
    from eurocslam.eval.bench import BenchOptions, parse_run_cmd
    from eurocslam.eval.evaluate import EvalConfig

    if runs < 1:
        raise ConfigError(f"--runs must be >= 1, got {runs}")
    if args.jobs is not None and args.jobs < 1:
        raise ConfigError(f"--jobs must be >= 1, got {args.jobs}")
    if args.executor == "local":
        given = [a for a in RAY_ONLY if getattr(args, a) is not None]
        if given:
            flag = "--" + given[0].replace("_", "-")
            raise ConfigError(f"{flag} is an option of --executor ray")
    elif args.jobs is not None:
        raise ConfigError("--jobs is an option of --executor local (Ray places runs by CPUs)")
    return BenchOptions(
        runs=runs,
        run_cmd=parse_run_cmd(args.run_cmd) if args.run_cmd else None,
        no_imu=args.no_imu,
        eval_cfg=EvalConfig(align=args.align, max_diff_s=args.max_diff),
        timeout_s=args.timeout,
        force=args.force,
        executor=args.executor,
        jobs=args.jobs,
        address=args.address or "auto",
        cpus_per_run=args.cpus_per_run or 2.0,
        ray_outputs=args.ray_outputs or "auto",
        worker_cache=args.worker_cache,
    )


def run(args: argparse.Namespace) -> int:
    from eurocslam.eval.bench import (
        BenchInterrupted,
        add_configs,
        parse_config_arg,
        plan_from_args,
        run_bench,
        write_results,
    )

    plan = plan_from_args(args.sequences)
    plan = add_configs(plan, [parse_config_arg(a) for a in args.config], args.no_mcap)
    runs = args.runs if args.runs is not None else (plan.runs or 1)
    opts = _options(args, runs)
    executor: dict[str, object] = {"name": opts.executor}
    if opts.executor == "ray":
        executor.update(address=opts.address, cpus_per_run=opts.cpus_per_run)
    try:
        records = run_bench(plan, args.output, opts)
    except BenchInterrupted as e:  # keep what finished: a long bench is not lost to Ctrl-C
        if e.records:
            write_results(args.output, plan, e.records, opts.eval_cfg, runs, executor)
            print(
                f"eurocslam bench: interrupted after {len(e.records)} of {e.planned} runs; "
                f"their results: {args.output / 'bench.md'}, {args.output / 'bench.json'}",
                file=sys.stderr,
            )
        raise
    md, _ = write_results(args.output, plan, records, opts.eval_cfg, runs, executor)
    print(md)
    print(f"results: {args.output / 'bench.md'}, {args.output / 'bench.json'}")
    return 0 if all(r.ok for r in records) else 1
