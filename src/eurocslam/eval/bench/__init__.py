"""`eurocslam bench`: `run` + `eval` over sequences x configurations x runs, one results table.

Each run is a separate `eurocslam run SEQ -o OUT [--config FILE] [--no-imu]` process, so runs go
in parallel and a crash in one run is recorded, not fatal. Each run's `trajectory_final.tum`
(and `trajectory_online.tum`) is evaluated against the sequence's ground truth; the table gives,
per sequence and configuration, the medians over the successful runs beside the published
stereo-inertial numbers (GUIDE section 4).

Modules: `plan` (the YAML list, configurations), `task` (one run: the process and its
evaluation), `process` (the subprocess runner, shared with `benchmarks/`), `sequences` (folders
and synth renderings), `local` and `ray_executor` (where runs execute), `sweep` (the whole
bench, resume, progress, Ctrl-C), `table` (bench.md, bench.json).

Run command: a template list with `{seq}`, `{out}`, `{python}` (the interpreter where the run
executes) and `{no_imu}` (expands to `--no-imu` or to nothing); the default is `[{python}, -m,
eurocslam.cli, run, {seq}, -o, {out}, --no-progress, {no_imu}]`. Tests inject a fake one.
"""

from eurocslam.eval.bench.plan import (
    BenchConfig,
    BenchPlan,
    BenchSequence,
    add_configs,
    load_plan,
    parse_config_arg,
    plan_from_args,
)
from eurocslam.eval.bench.sweep import BenchInterrupted, BenchOptions, run_bench
from eurocslam.eval.bench.table import PUBLISHED, published_key, summarize, write_results
from eurocslam.eval.bench.task import RunRecord, RunTask, parse_run_cmd

__all__ = [
    "PUBLISHED",
    "BenchConfig",
    "BenchInterrupted",
    "BenchOptions",
    "BenchPlan",
    "BenchSequence",
    "RunRecord",
    "RunTask",
    "add_configs",
    "load_plan",
    "parse_config_arg",
    "parse_run_cmd",
    "plan_from_args",
    "published_key",
    "run_bench",
    "summarize",
    "write_results",
]
