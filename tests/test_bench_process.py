"""The one subprocess runner of the benchmarks (`eurocslam bench`, benchmarks/bench_slam.py)."""

from __future__ import annotations

import signal
import sys
import threading
import time
from pathlib import Path

import pytest

from eurocslam.eval.bench.process import last_line, run_process

BURN = "import sys, time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass\n"


def test_output_exit_code_and_usage(tmp_path: Path) -> None:
    log = tmp_path / "run.log"
    # stdout flushed before stderr is written: without PYTHONUNBUFFERED a redirected stdout is
    # block-buffered and would reach the log after stderr's line, at exit
    code = BURN + (
        "print('to stdout', flush=True); print('last words', file=sys.stderr); sys.exit(3)"
    )
    r = run_process([sys.executable, "-c", code], log)
    assert r.returncode == 3 and not r.timed_out
    text = log.read_text()
    assert text.startswith("$ ") and "to stdout" in text
    assert last_line(log) == "last words"
    assert r.cpu_s >= 0.25  # the child's own CPU time, from wait4
    assert r.max_rss_mb > 1 and r.wall_s >= r.cpu_s * 0.5


def test_long_output_does_not_block(tmp_path: Path) -> None:
    """Output goes to a file: a run that writes a lot is not stalled on a full pipe."""
    log = tmp_path / "run.log"
    code = "[print('y' * 1000) for _ in range(2000)]"
    r = run_process([sys.executable, "-c", code], log, header=False)
    assert r.returncode == 0
    assert log.stat().st_size > 2_000_000


def test_timeout_stops_the_run(tmp_path: Path) -> None:
    t = time.monotonic()
    r = run_process(
        [sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "l", timeout_s=0.5
    )
    assert r.timed_out and r.returncode is None
    assert time.monotonic() - t < 10


def test_cancel_from_another_thread(tmp_path: Path) -> None:
    cancel = threading.Event()
    threading.Timer(0.5, cancel.set).start()
    t = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        run_process(
            [sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "l", cancel=cancel
        )
    assert time.monotonic() - t < 10


def test_a_run_that_ignores_sigint_is_killed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import eurocslam.eval.bench.process as process

    monkeypatch.setattr(process, "_TERM_GRACE_S", 0.5)
    code = "import signal, time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\ntime.sleep(60)"
    t = time.monotonic()
    r = run_process([sys.executable, "-c", code], tmp_path / "l", timeout_s=1.0)
    assert r.timed_out and time.monotonic() - t < 10  # SIGINT, a grace period, then SIGKILL


def test_the_run_does_not_inherit_a_blocked_sigint(tmp_path: Path) -> None:
    """Ray workers run tasks with SIGINT blocked; a run started there must still be stoppable
    by SIGINT (its clean stop), so the runner unblocks it in the child."""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        log = tmp_path / "l"
        r = run_process(["grep", "SigBlk", "/proc/self/status"], log, header=False)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
    assert r.returncode == 0
    mask = int(last_line(log).split()[1], 16)
    assert not mask & (1 << (signal.SIGINT - 1))


def test_command_that_cannot_start(tmp_path: Path) -> None:
    with pytest.raises(OSError):
        run_process([str(tmp_path / "no_such_program")], tmp_path / "l")
