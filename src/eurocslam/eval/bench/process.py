"""The one way benchmarks start `eurocslam run`: a subprocess, its output in a log file, its own
resource usage.

The run's output goes to a file, not a pipe: a pipe read only after the run ends blocks a run
with a long output. The process is reaped with `os.wait4`, which gives its CPU time and peak
memory (those of its reaped extraction workers included) without a sampling thread. Waiting is a
short polling loop, so a timeout, a Ctrl-C or a cancelled Ray task (an exception raised between
two polls) stops the run: it is terminated, killed if it does not end, and reaped.

Used by `eurocslam bench` (local processes and Ray workers) and by `benchmarks/bench_slam.py`
(and through it `benchmarks/bench_ab.py`).
"""

from __future__ import annotations

import os
import resource
import shlex
import signal
import subprocess
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

_POLL_S = 0.05
_TERM_GRACE_S = 5.0
_OWN_SIGINT_S = 1.0


@dataclass(frozen=True)
class ProcessResult:
    """How a run process ended. `returncode` is None when it was killed on a timeout."""

    pid: int
    returncode: int | None
    wall_s: float
    cpu_s: float  # user + system, the process and the children it reaped
    max_rss_mb: float  # its peak resident memory (the largest of it and its reaped children)
    timed_out: bool = False


_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def _unblock_stop_signals() -> None:  # pragma: no cover - runs in the child, before exec
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)


def _reap(pid: int, block: bool) -> tuple[int, resource.struct_rusage] | None:
    """(wait status, usage) once `pid` has ended; None while it runs (non-blocking)."""
    wpid, status, usage = os.wait4(pid, 0 if block else os.WNOHANG)
    return (status, usage) if wpid == pid else None


def _wait(p: subprocess.Popen[bytes], seconds: float) -> tuple[int, resource.struct_rusage] | None:
    t_end = time.monotonic() + seconds
    while True:
        done = _reap(p.pid, block=False)
        if done is not None or time.monotonic() >= t_end:
            return done
        time.sleep(_POLL_S)


def _stop(
    p: subprocess.Popen[bytes], own_sigint: bool = False
) -> tuple[int, resource.struct_rusage]:
    """Interrupt (what a Ctrl-C does: the run cleans up), wait a little, kill; reap.
    `own_sigint`: the run may have had the terminal's Ctrl-C already; give it a moment first."""
    if own_sigint:
        done = _wait(p, _OWN_SIGINT_S)
        if done is not None:
            return done
    try:
        p.send_signal(signal.SIGINT)
        done = _wait(p, _TERM_GRACE_S)
        if done is not None:
            return done
        p.kill()
    except ProcessLookupError:  # pragma: no cover - ended and reaped meanwhile
        pass
    done = _reap(p.pid, block=True)
    assert done is not None
    return done


def run_process(
    cmd: Sequence[str],
    log: Path,
    *,
    env: Mapping[str, str] | None = None,
    timeout_s: float | None = None,
    header: bool = True,
    cancel: threading.Event | None = None,
) -> ProcessResult:
    """Run `cmd` with stdout and stderr into `log` (created; with a `$ cmd` first line when
    `header`). Raises OSError when the command cannot be started. Any exception while waiting
    (KeyboardInterrupt, a Ray cancel) stops the process before it propagates; so does `cancel`
    being set (from another thread), with a KeyboardInterrupt."""
    with open(log, "w") as f:
        if header:
            f.write("$ " + shlex.join(cmd) + "\n")
            f.flush()
        # a Ray worker runs tasks with SIGINT blocked, and a child inherits the mask: the run
        # would never see the SIGINT that stops it cleanly; unblock it in the child
        blocked = _STOP_SIGNALS & signal.pthread_sigmask(signal.SIG_BLOCK, [])
        t0 = time.perf_counter()
        p = subprocess.Popen(
            list(cmd),
            stdout=f,
            stderr=subprocess.STDOUT,
            env=dict(env) if env else None,
            preexec_fn=_unblock_stop_signals if blocked else None,
        )
        timed_out = False
        try:
            while True:
                done = _reap(p.pid, block=False)
                if done is not None:
                    break
                if cancel is not None and cancel.is_set():
                    raise KeyboardInterrupt("cancelled")
                if timeout_s is not None and time.perf_counter() - t0 > timeout_s:
                    timed_out = True
                    done = _stop(p)
                    break
                time.sleep(_POLL_S)
        except BaseException as e:
            _stop(p, own_sigint=isinstance(e, KeyboardInterrupt))
            p.returncode = -1
            raise
        status, usage = done
        wall = time.perf_counter() - t0
    rc = os.waitstatus_to_exitcode(status)
    p.returncode = rc  # reaped here: Popen must not wait for it again
    return ProcessResult(
        pid=p.pid,
        returncode=None if timed_out else rc,
        wall_s=wall,
        cpu_s=usage.ru_utime + usage.ru_stime,
        max_rss_mb=usage.ru_maxrss / 1024,
        timed_out=timed_out,
    )


def last_line(log: Path) -> str:
    """The last non-blank line of a log ('' when there is none): the error of a failed run."""
    try:
        lines = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1].strip() if lines else ""
