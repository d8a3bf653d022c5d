"""Feature extraction in worker processes, beside tracking.

`FeatureStream` (frontend/stream.py) runs the extraction of the next frames here while the caller
tracks the current one. A reader thread takes frames from the source (decoding them: OpenCV
releases the GIL), copies each frame's images into a slot of shared memory and hands the slot to a
worker process, round-robin; the worker rectifies, extracts ORB on both images and matches them
(`Extractor.extract`) and sends the features back over a socket; the caller receives them in
frame order. Frames that fail the image check (missing, blank, wrong size) and frames left out by
`frontend.track_every` skip the workers.

A worker is a `python -c` (`frontend/spawn.py`, which starts them, early for `eurocslam run`)
that ignores SIGINT before anything else and runs `_worker_main` on the socket FD (subprocess,
not multiprocessing: a spawned multiprocessing child imports the caller's main module, which
re-runs a script that lacks an `if __name__ == "__main__"` guard).
Ctrl-C is the parent's to handle; a worker ends when its socket closes. The workers stay in the
parent's session: in a session of their own, the kernel's autogroup scheduling would give them
a share of the CPU equal to the whole main process's (measured: 3-10 % slower end to end).

Processes rather than threads: the workers' numpy and Python (stereo matching, keypoint
bucketing) run under their own interpreter lock, not the tracking thread's. With extraction in
threads, stereo matching had to stay on the tracking thread (in the extraction threads it cost
as much as it saved) and the threads' Python still competed with tracking for the lock. The
features are the same either way.
"""

from __future__ import annotations

import contextlib
import pickle
import queue
import subprocess
import threading
import time
import traceback
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from multiprocessing import shared_memory
from multiprocessing.connection import Connection
from typing import cast

import numpy as np

from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.types import StereoFrame
from eurocslam.errors import SlamError
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor, FrameFeatures
from eurocslam.frontend.spawn import package_dir, spawn, take
from eurocslam.memory import peak_rss_mb

SLOTS_PER_WORKER = 3  # frames in flight per worker: one being extracted, two waiting
_POLL_S = 0.5  # how often a blocked wait checks that the other side is still there
_START_TIMEOUT_S = 60.0  # a worker not ready by then (imports, shared memory) did not start


@dataclass(frozen=True)
class _WorkerFailure:
    """An exception inside a worker (a bug: the images were checked before), with its trace."""

    trace: str


@dataclass(frozen=True)
class _Job:
    """One frame on its way to the caller: extracted by `worker` from `slot`, or, for a frame
    that failed the image check, `local` (its features, made by the reader)."""

    frame: StereoFrame
    decode_ms: float
    worker: int = -1
    slot: int = -1
    local: FrameFeatures | None = None


@dataclass(frozen=True)
class _End:
    error: BaseException | None = None  # what the source raised, re-raised in the caller


@dataclass(frozen=True)
class _Ready:
    """A worker's first message: set up and attached to the shared memory, running the code
    of `package` (the eurocslam folder it imported)."""

    package: str


@dataclass(frozen=True)
class _Done:
    """A worker's last message, after the None that ends it: what the worker cost."""

    peak_rss_mb: float
    cpu_s: float  # the worker process's CPU time (user + system) since it took its setup


@dataclass(frozen=True)
class _Setup:
    """The first message to a worker."""

    rig: StereoRig
    config: FrontendConfig
    shm_name: str
    n_slots: int
    shape: tuple[int, int]


def _worker_main(conn: Connection) -> None:
    """A worker process: `_Setup` in, `_Ready` out; then (slot, t_ns) in, `FrameFeatures` (or
    `_WorkerFailure`) out; None in, `_Done` out ends it. A socket closed before the setup
    (workers started early for a run that ended first) ends it quietly."""
    try:
        setup: _Setup = conn.recv()
    except (EOFError, OSError):
        return
    # the run's work only: not the imports before the setup (a worker started early imports
    # while the parent starts, outside the run's wall clock)
    cpu0 = time.process_time()
    n_slots, shape = setup.n_slots, setup.shape
    extractor = Extractor.for_rig(setup.rig, setup.config)
    shm = _attach(setup.shm_name)
    images = np.ndarray((n_slots, 2, *shape), np.uint8, buffer=shm.buf)
    try:
        conn.send(_Ready(package_dir()))
        while (task := conn.recv()) is not None:
            slot, t_ns = task
            try:
                # the reader sends only frames that passed `without_extraction`
                frame = StereoFrame(t_ns, images[slot, 0], images[slot, 1])
                ff = extractor.extract(frame, checked=True)
            except Exception:
                conn.send(_WorkerFailure(traceback.format_exc()))
                return
            conn.send(ff)
        conn.send(_Done(peak_rss_mb(), time.process_time() - cpu0))
    except (EOFError, OSError):
        pass  # the parent went away
    finally:
        del images
        shm.close()


def _attach(name: str) -> shared_memory.SharedMemory:
    """Attach to the parent's shared memory without registering it with a resource tracker:
    the parent owns and unlinks it (before Python 3.13 every attach registers, which starts a
    tracker process per worker that would unlink it, and warn of a leak, when the worker
    exits)."""
    try:
        return shared_memory.SharedMemory(name=name, track=False)  # type: ignore[call-arg]
    except TypeError:  # Python < 3.13
        pass
    from multiprocessing import resource_tracker

    register = resource_tracker.register
    resource_tracker.register = lambda *args, **kwargs: None
    try:
        return shared_memory.SharedMemory(name=name)
    finally:
        resource_tracker.register = register


class ExtractionWorkers:
    """`n_workers` worker processes extracting the frames of one stream like `extractor`."""

    def __init__(self, extractor: Extractor, n_workers: int) -> None:
        self.extractor = extractor
        c0 = extractor.rig.cam0  # the raw images' size (a fisheye's rectified ones may differ)
        self.shape = (c0.height, c0.width)
        n_slots = SLOTS_PER_WORKER * max(1, int(n_workers))
        self._shm: shared_memory.SharedMemory | None = shared_memory.SharedMemory(
            create=True, size=n_slots * 2 * c0.height * c0.width
        )
        self._images = np.ndarray((n_slots, 2, *self.shape), np.uint8, buffer=self._shm.buf)
        self._free: queue.Queue[int] = queue.Queue()
        for s in range(n_slots):
            self._free.put(s)
        self._stop = threading.Event()
        # what the stream cost, known once it has ended: per worker, and the reader thread's CPU
        self.peak_rss_mb: list[float] = []
        self.cpu_s: list[float] = []
        self.reader_cpu_s = 0.0
        self._procs: list[subprocess.Popen[bytes]] = []
        # one socket pair per worker: tasks go out from the reader thread, features come back
        # to the caller (a socket buffers a frame's features, so a worker can work ahead)
        self._conns: list[Connection] = []
        setup = _Setup(extractor.rig, extractor.config, self._shm.name, n_slots, self.shape)
        try:
            n = max(1, int(n_workers))
            started = take(n) or spawn(n)  # started early by `run`, or now
            self._procs, self._conns = started.procs, started.conns
            for conn, proc in zip(self._conns, self._procs, strict=True):
                try:
                    conn.send(setup)
                except OSError:  # it exited at once
                    raise _not_started(proc) from None
            self._wait_ready()
        except BaseException:
            self.close()
            raise
        # every worker has it mapped: the name can go, so that nothing is left behind even if
        # this process is killed
        self._shm.unlink()

    def _wait_ready(self) -> None:
        """Wait for every worker's `_Ready`; OSError if one does not start (its Python cannot
        import eurocslam, no shared memory, ...), so that the caller can extract inline."""
        deadline = time.monotonic() + _START_TIMEOUT_S
        package = package_dir()
        for conn, proc in zip(self._conns, self._procs, strict=True):
            try:
                while not conn.poll(_POLL_S):
                    if proc.poll() is not None or time.monotonic() > deadline:
                        raise EOFError
                msg = conn.recv()
            except (EOFError, OSError, pickle.UnpicklingError):
                msg = None
            if not isinstance(msg, _Ready):
                raise _not_started(proc)
            if msg.package != package:
                raise OSError(
                    f"feature extraction process {proc.pid} runs eurocslam from {msg.package}, "
                    f"this process from {package}"
                )

    # ---- the caller's side -------------------------------------------------------------------
    def stream(self, frames: Iterable[StereoFrame]) -> Iterator[tuple[StereoFrame, FrameFeatures]]:
        """(frame, features) in frame order; the workers stop when the stream ends or closes."""
        jobs: queue.Queue[_Job | _End] = queue.Queue(maxsize=2 * len(self._images))
        reader = threading.Thread(
            target=self._read, args=(iter(frames), jobs), name="eurocslam-reader", daemon=True
        )
        reader.start()
        try:
            while True:
                job = jobs.get()
                if isinstance(job, _End):
                    if job.error is not None:
                        raise job.error
                    return
                if job.local is not None:
                    ff = job.local
                else:
                    ff = self._receive(job.worker)
                    self._free.put(job.slot)
                ff.timings_ms["decode"] = job.decode_ms
                yield job.frame, ff
        finally:
            self._stop.set()
            reader.join()
            self.close()

    def _receive(self, worker: int) -> FrameFeatures:
        conn, proc = self._conns[worker], self._procs[worker]
        try:
            while not conn.poll(_POLL_S):
                if proc.poll() is not None:
                    raise EOFError
            out = conn.recv()
        except (EOFError, OSError, pickle.UnpicklingError):
            raise self._stopped(worker) from None
        if isinstance(out, _WorkerFailure):
            raise RuntimeError(f"feature extraction failed in process {proc.pid}:\n{out.trace}")
        return cast(FrameFeatures, out)

    def _stopped(self, worker: int) -> SlamError:
        proc = self._procs[worker]
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=_POLL_S)
        return SlamError(
            f"feature extraction process {proc.pid} stopped (exit code {proc.returncode})"
        )

    # ---- the reader thread -------------------------------------------------------------------
    def _read(self, frames: Iterator[StereoFrame], jobs: queue.Queue[_Job | _End]) -> None:
        ex = self.extractor
        k = n = 0  # frames sent to workers; frames read
        try:
            while not self._stop.is_set():
                t0 = time.perf_counter()
                try:
                    frame = next(frames)
                except StopIteration:
                    break
                decode_ms = (time.perf_counter() - t0) * 1e3
                local = ex.without_extraction(frame, n)
                n += 1
                if local is not None:
                    job = _Job(frame, decode_ms, local=local)
                else:
                    slot = self._take_slot()
                    if slot is None:
                        return
                    self._images[slot, 0] = frame.left
                    self._images[slot, 1] = frame.right
                    worker = k % len(self._conns)
                    k += 1
                    try:
                        self._conns[worker].send((slot, frame.t_ns))
                    except OSError:
                        raise self._stopped(worker) from None
                    job = _Job(frame, decode_ms, worker=worker, slot=slot)
                if not self._put(jobs, job):
                    return
            self._put(jobs, _End())
        except BaseException as e:  # the source's errors (bad files, ...) reach the caller
            self._put(jobs, _End(e))
        finally:
            self.reader_cpu_s = time.thread_time()

    def _take_slot(self) -> int | None:
        """A free image slot, or None once the stream is stopping."""
        while not self._stop.is_set():
            try:
                return self._free.get(timeout=_POLL_S)
            except queue.Empty:
                continue
        return None

    def _put(self, jobs: queue.Queue[_Job | _End], item: _Job | _End) -> bool:
        """Queue `item` for the caller; False once the stream is stopping."""
        while not self._stop.is_set():
            try:
                jobs.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def close(self) -> None:
        """Stop the workers and release the shared memory (idempotent)."""
        for conn in self._conns:
            with contextlib.suppress(OSError, ValueError):
                conn.send(None)
        for conn in self._conns:
            done = _last_word(conn)
            self.peak_rss_mb.append(done.peak_rss_mb)
            self.cpu_s.append(done.cpu_s)
        for p in self._procs:
            try:
                p.wait(timeout=2)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for conn in self._conns:
            conn.close()
        self._procs, self._conns = [], []
        if self._shm is not None:
            del self._images
            self._shm.close()
            with contextlib.suppress(FileNotFoundError):  # unlinked once the workers started
                self._shm.unlink()
            self._shm = None


def _not_started(proc: subprocess.Popen[bytes]) -> OSError:
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=_POLL_S)
    return OSError(
        f"feature extraction process {proc.pid} did not start (exit code {proc.returncode})"
    )


def _last_word(conn: Connection) -> _Done:
    """A worker's `_Done`, skipping features nobody asked for (a stream closed early); NaNs if
    it does not answer."""
    try:
        while conn.poll(2.0):
            msg = conn.recv()
            if isinstance(msg, _Done):
                return msg
    except (EOFError, OSError, pickle.UnpicklingError):
        pass
    return _Done(float("nan"), float("nan"))
