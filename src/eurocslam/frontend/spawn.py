"""Starting the extraction worker processes, early if the caller wants.

A worker process spends its first 0.3-1.8 s importing numpy, OpenCV and the extraction code
before it can take its setup (`frontend/workers.py`). `eurocslam run` starts them as soon as it
has read its configuration (`start_early`), so that those imports run beside the main process's
own (GTSAM, scipy, the MCAP writer: 0.7-2.7 s) instead of after them; `ExtractionWorkers` then
`take`s them, or starts its own. This module imports nothing heavy, so starting them early costs
the caller nothing.

A worker is a `python -c` that ignores SIGINT before anything else, runs
`workers._worker_main` on its end of a socket pair (its setup first), and leaves without the
interpreter's teardown once it has sent its last message. Workers never taken end when their
socket closes (`discard_early`, or this process's exit).
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path

# a worker's whole program: SIGINT ignored before the imports (a Ctrl-C right at the start would
# print their tracebacks), then the loop on the socket whose descriptor is the argument, then
# out without the interpreter's teardown (freeing numpy's and OpenCV's modules one by one: 0.2 s
# of the parent's wait at the end of every run, loaded machine), which has nothing to write: the
# shared memory is closed and the last message sent (an exception still ends it with its trace)
_WORKER_COMMAND = (
    "import signal; signal.signal(signal.SIGINT, signal.SIG_IGN); import sys, os; "
    "from multiprocessing.connection import Connection; "
    "from eurocslam.frontend.workers import _worker_main; "
    "_worker_main(Connection(int(sys.argv[1]))); "
    "sys.stdout.flush(); sys.stderr.flush(); os._exit(0)"
)


@dataclass
class Spawned:
    """Worker processes started and the parent's end of each one's socket."""

    procs: list[subprocess.Popen[bytes]]
    conns: list[Connection]

    def close(self) -> None:
        """Close the sockets (a worker waiting for its setup then ends) and reap the workers."""
        for conn in self.conns:
            conn.close()
        for p in self.procs:
            try:
                p.wait(timeout=2)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.procs, self.conns = [], []


def package_dir() -> str:
    import eurocslam

    return str(Path(eurocslam.__file__).resolve().parent)


def worker_env() -> dict[str, str]:
    """The environment of a worker: this process's, with the folder holding the eurocslam it
    runs first on PYTHONPATH, so that a worker never imports another copy (an installed one
    while this process runs a source tree)."""
    env = dict(os.environ)
    paths = [str(Path(package_dir()).parent)]
    if env.get("PYTHONPATH"):
        paths.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(paths)
    return env


def spawn(n_workers: int) -> Spawned:
    """Start `n_workers` worker processes (OSError where processes cannot start)."""
    started = Spawned([], [])
    env = worker_env()
    try:
        for _ in range(n_workers):
            mine, theirs = socket.socketpair()
            with theirs:
                fd = theirs.fileno()
                started.procs.append(
                    subprocess.Popen(
                        [sys.executable, "-c", _WORKER_COMMAND, str(fd)],
                        pass_fds=(fd,),
                        stdin=subprocess.DEVNULL,
                        env=env,
                    )
                )
            started.conns.append(Connection(mine.detach()))
    except BaseException:
        started.close()
        raise
    return started


_early: Spawned | None = None


def start_early(n_workers: int) -> None:
    """Start the workers of the next `ExtractionWorkers` now (nothing if they cannot start:
    `ExtractionWorkers` then says why when it tries)."""
    global _early
    discard_early()
    with contextlib.suppress(OSError, ValueError):
        _early = spawn(n_workers)


def take(n_workers: int) -> Spawned | None:
    """The workers `start_early` started, if they are `n_workers` (others are stopped)."""
    global _early
    early, _early = _early, None
    if early is not None and len(early.procs) != n_workers:
        early.close()
        early = None
    return early


def discard_early() -> None:
    """Stop workers started early and never taken (a run that ended before extracting)."""
    global _early
    early, _early = _early, None
    if early is not None:
        early.close()
