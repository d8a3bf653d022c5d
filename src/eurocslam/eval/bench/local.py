"""`--executor local`: every run a process on this machine, `jobs` at a time."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, as_completed
from pathlib import Path

from eurocslam.eval.bench.task import RunRecord, RunTask, execute, worker_identity


def run_local(
    items: list[tuple[RunTask, Path]], jobs: int, on_done: Callable[[RunRecord], None]
) -> None:
    """Run each (task, sequence folder) into the task's folder; `on_done` as each finishes.
    Ctrl-C: runs not started never start, running ones are stopped; KeyboardInterrupt."""
    if not items:
        return
    cancel = threading.Event()
    pool = ThreadPoolExecutor(max_workers=max(1, min(jobs, len(items))))
    futs: list[Future[RunRecord]] = []
    try:
        for task, seq in items:
            futs.append(
                pool.submit(execute, task, seq, task.out_dir, worker_identity("local"), cancel)
            )
        for fut in as_completed(futs):
            on_done(fut.result())
    except BaseException:
        cancel.set()
        for fut in futs:
            fut.cancel()
        raise
    finally:
        pool.shutdown(wait=True)
