"""A bench: every (sequence, configuration, run) of a plan, on an executor, resumable.

Runs go into `OUT/runs/CONFIG/SEQUENCE/run_K`. A run that finished (its `bench_run.json`) with
the same sequence, configuration, command and evaluation settings is not run again by a later
bench into the same OUT (unless `force`); failed runs and runs made with other settings are.
Runs are started interleaved (run 0 of every sequence and configuration first), so a sweep that
is stopped early has comparable results for every configuration.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from eurocslam.errors import ConfigError, OutputError
from eurocslam.eval.bench.plan import BenchPlan
from eurocslam.eval.bench.task import RunRecord, RunTask, default_run_cmd, read_record
from eurocslam.eval.evaluate import EvalConfig

logger = logging.getLogger(__name__)

EXECUTORS = ("local", "ray")


@dataclass(frozen=True)
class BenchOptions:
    runs: int = 1
    run_cmd: list[str] | None = None  # template; default: eurocslam run (task.default_run_cmd)
    no_imu: bool = False
    eval_cfg: EvalConfig = field(default_factory=EvalConfig)
    timeout_s: float | None = None
    progress: bool | None = None
    force: bool = False
    executor: str = "local"
    jobs: int | None = None  # local: runs at a time (default: CPU count)
    address: str = "auto"  # ray: the cluster
    cpus_per_run: float = 2.0  # ray: CPUs reserved per run
    ray_outputs: str = "auto"  # ray: shared | fetch | auto
    worker_cache: str | None = None  # ray: synth renderings and outputs on the workers


class BenchInterrupted(KeyboardInterrupt):
    """Ctrl-C during `run_bench`: carries the runs that had finished (in plan order)."""

    def __init__(self, records: list[RunRecord], planned: int) -> None:
        super().__init__(f"{len(records)} of {planned} runs finished")
        self.records = records
        self.planned = planned


def run_dir(out: Path, config: str, sequence: str, k: int) -> Path:
    return out / "runs" / config / sequence / f"run_{k}"


def plan_tasks(plan: BenchPlan, out: Path, opts: BenchOptions) -> list[RunTask]:
    """Every run of the plan, interleaved: run k of each sequence and configuration together."""
    template = tuple(opts.run_cmd or default_run_cmd())
    tasks = []
    for k in range(opts.runs):
        for s in plan.sequences:
            for c in plan.resolved_configs():
                tasks.append(
                    RunTask(
                        sequence=s.name,
                        config=c.name,
                        index=k,
                        out_dir=run_dir(out, c.name, s.name, k),
                        seq_path=s.path,
                        synth=s.synth,
                        config_text=c.text,
                        cmd_template=template,
                        run_args=tuple(plan.run_args),
                        no_imu=opts.no_imu,
                        eval_cfg=opts.eval_cfg,
                        timeout_s=opts.timeout_s,
                    )
                )
    return tasks


def finished_runs(tasks: list[RunTask], force: bool) -> dict[tuple[str, str, int], RunRecord]:
    """Runs of `tasks` that a previous bench in the same OUT finished with the same settings."""
    if force:
        return {}
    done: dict[tuple[str, str, int], RunRecord] = {}
    stale = 0
    for t in tasks:
        rec = read_record(t.out_dir)
        if rec is None or not rec.ok:
            continue
        if rec.fingerprint != t.fingerprint():
            stale += 1
            continue
        rec.out_dir, rec.resumed = t.out_dir, True
        done[t.key] = rec
    if done:
        logger.info(
            f"eurocslam bench: resuming: {len(done)} of {len(tasks)} runs already finished in "
            "this folder are kept (--force runs them again)"
        )
    if stale:
        logger.info(
            f"eurocslam bench: {stale} finished run(s) in this folder were made with other "
            "settings (sequence, configuration, command or alignment): running them again"
        )
    return done


def in_plan_order(plan: BenchPlan, records: list[RunRecord]) -> list[RunRecord]:
    seq = {s.name: i for i, s in enumerate(plan.sequences)}
    cfg = {c: i for i, c in enumerate(plan.config_names)}
    return sorted(records, key=lambda r: (seq[r.sequence], cfg[r.config], r.index))


@contextlib.contextmanager
def _progress(total: int, enabled: bool | None) -> Iterator[Any]:
    """The overall bar; log lines go above it while it is shown."""
    from tqdm.contrib.logging import logging_redirect_tqdm

    from eurocslam.progress import bar

    with bar(total=total, desc="bench runs", unit="run", enabled=enabled) as b:
        if b.disable:
            yield b
        else:
            with logging_redirect_tqdm([logging.getLogger("eurocslam")]):
                yield b


def _status_line(rec: RunRecord, many_configs: bool, i: int, n: int) -> str:
    label = f"{rec.sequence} {rec.config}" if many_configs else rec.sequence
    status = f"ATE {rec.final['ate_trans_rmse_m']:.3f} m" if rec.ok and rec.final else rec.error
    where = ""
    if rec.worker.get("executor") == "ray" and rec.worker.get("node_ip"):
        where = f", Ray node {rec.worker['node_ip']}"
    return (
        f"eurocslam bench: {label} run {rec.index}: {status} ({rec.wall_s:.1f} s{where}) [{i}/{n}]"
    )


def run_bench(plan: BenchPlan, out_dir: Path | str, opts: BenchOptions) -> list[RunRecord]:
    """Run (or resume) the bench; the records of every planned run, in plan order."""
    if opts.executor not in EXECUTORS:
        raise ConfigError(f"--executor must be one of {', '.join(EXECUTORS)}")
    out = Path(out_dir).absolute()  # the same path for Ray workers, whatever their folder
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder (the output folder of bench)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{out}: cannot create the output folder: {e.strerror or e}") from None
    from eurocslam.eval.bench.sequences import check_synth_spec

    for s in plan.sequences:
        if s.synth is not None:
            check_synth_spec(s.name, s.synth)
    tasks = plan_tasks(plan, out, opts)
    kept = finished_runs(tasks, opts.force)
    todo = [t for t in tasks if t.key not in kept]
    done: list[RunRecord] = list(kept.values())
    many = len(plan.config_names) > 1

    with _progress(len(todo), opts.progress) as b:

        def on_done(rec: RunRecord) -> None:
            done.append(rec)
            b.update(1)
            logger.info(_status_line(rec, many, len(done) - len(kept), len(todo)))

        try:
            if opts.executor == "ray":
                from eurocslam.eval.bench.ray_executor import run_ray

                run_ray(
                    todo,
                    out,
                    on_done,
                    address=opts.address,
                    cpus_per_run=opts.cpus_per_run,
                    outputs=opts.ray_outputs,
                    worker_cache=opts.worker_cache,
                )
            else:
                from eurocslam.eval.bench.local import run_local
                from eurocslam.eval.bench.sequences import prepare_local

                needed = {t.sequence for t in todo}
                sub = BenchPlan([s for s in plan.sequences if s.name in needed])
                paths = prepare_local(sub, out, opts.progress) if todo else {}
                jobs = opts.jobs or os.cpu_count() or 1
                run_local([(t, paths[t.sequence]) for t in todo], jobs, on_done)
        except KeyboardInterrupt:
            raise BenchInterrupted(in_plan_order(plan, done), len(tasks)) from None
    return in_plan_order(plan, done)
