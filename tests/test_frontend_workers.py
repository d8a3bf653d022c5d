"""Extraction in worker processes (`frontend.workers`): the same features as inline, bad frames,
errors from the source, early close, a worker that dies."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from eurocslam.dataset.types import StereoFrame
from eurocslam.errors import DatasetError, SlamError
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor, FrameFeatures, FrameProblem
from eurocslam.frontend.stream import FeatureStream
from eurocslam.frontend.workers import ExtractionWorkers
from eurocslam.synth import Scene, SynthSpec


@pytest.fixture(scope="module")
def scene() -> Scene:
    return Scene.build(SynthSpec.tiny(seed=2))


@pytest.fixture(scope="module")
def frames(scene: Scene) -> list[StereoFrame]:
    out = []
    for k in range(12):
        left, _ = scene.image(k, 0)
        right, _ = scene.image(k, 1)
        out.append(StereoFrame(int(scene.cam_t_ns[k]), left, right))
    return out


@pytest.fixture
def made_shm(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the shared memory blocks the test's workers create (other processes on the
    machine create and remove their own meanwhile)."""
    from multiprocessing import shared_memory

    names: list[str] = []

    class Recorded(shared_memory.SharedMemory):
        def __init__(self, name: str | None = None, create: bool = False, size: int = 0) -> None:
            super().__init__(name, create, size)
            if create:
                names.append(self.name)

    monkeypatch.setattr(shared_memory, "SharedMemory", Recorded)
    return names


def _left(names: list[str]) -> list[str]:
    """Those of `names` still in /dev/shm (where POSIX shared memory has its names)."""
    assert names, "no shared memory was made"
    return [n for n in names if (Path("/dev/shm") / n.lstrip("/")).exists()]


def _same(a: FrameFeatures, b: FrameFeatures) -> None:
    assert a.t_ns == b.t_ns and a.problem == b.problem
    np.testing.assert_array_equal(a.left.uv, b.left.uv)
    np.testing.assert_array_equal(a.left.desc, b.left.desc)
    np.testing.assert_array_equal(a.right.desc, b.right.desc)
    np.testing.assert_array_equal(a.stereo.uR, b.stereo.uR)


def test_workers_extract_what_inline_extraction_does(scene: Scene, frames, made_shm) -> None:
    """Round-robin over two workers, in frame order; missing, blank and wrong-size images are
    reported as inline; the decode time is the reader's."""
    bad = list(frames)
    bad[3] = replace(bad[3], left=None)
    bad[5] = replace(bad[5], right=np.full_like(frames[5].right, 128))
    bad[7] = replace(bad[7], left=frames[7].left[:-8], right=frames[7].right[:-8])
    fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig(prefetch_workers=2)))
    got = list(fe(bad))
    assert [fr for fr, _ in got] == bad
    for (_, ff), fr in zip(got, bad, strict=True):
        _same(ff, fe.extractor.extract(fr))
        assert "decode" in ff.timings_ms
    assert [ff.problem for _, ff in got][3:8] == ["missing", None, "blank", None, "size"]
    cost = fe.cost
    assert len(cost.worker_peak_rss_mb) == 2 and all(m > 10 for m in cost.worker_peak_rss_mb)
    assert len(cost.worker_cpu_s) == 2 and all(c > 0 for c in cost.worker_cpu_s)
    assert cost.reader_cpu_s > 0
    assert not _left(made_shm)  # the shared memory is gone


def test_one_frame_in_n_is_extracted(scene: Scene, frames) -> None:
    """`track_every: 3`: frames 0, 3, 6, ... of the stream are extracted (as inline, also when
    one fails the image check), the others come back SKIPPED without features, in workers and
    inline alike."""
    bad = list(frames)
    bad[3] = replace(bad[3], left=None)
    for cfg in (FrontendConfig(track_every=3), FrontendConfig(track_every=3, prefetch=False)):
        fe = FeatureStream(Extractor.for_rig(scene.rig, cfg))
        got = list(fe(bad))
        assert [fr for fr, _ in got] == bad
        for k, ((_, ff), fr) in enumerate(zip(got, bad, strict=True)):
            if k % 3:
                assert ff.problem == FrameProblem.SKIPPED and ff.t_ns == fr.t_ns
                assert len(ff.left) == len(ff.right) == len(ff.stereo.uR) == 0
            else:
                _same(ff, fe.extractor.extract(fr))
        assert got[3][1].problem == "missing" and len(got[6][1].left) > 100


def test_an_error_of_the_source_reaches_the_caller(scene: Scene, frames) -> None:
    def source() -> Iterator[StereoFrame]:
        yield from frames[:4]
        raise DatasetError("cam0/data/x.png: truncated PNG")

    fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig()))
    seen = []
    with pytest.raises(DatasetError, match="truncated PNG"):
        for fr, _ in fe(source()):
            seen.append(fr)
    assert seen == frames[:4]  # every frame before the error arrived


def test_closing_the_stream_early_stops_the_workers(scene: Scene, frames, made_shm) -> None:
    fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig()))
    stream = fe(iter(frames * 10))
    next(stream)
    t0 = time.perf_counter()
    stream.close()
    assert time.perf_counter() - t0 < 4.0
    assert not _left(made_shm)


@pytest.mark.parametrize("idle", [False, True], ids=["extracting", "idle"])
def test_a_worker_that_dies_is_an_error(scene: Scene, frames, idle: bool) -> None:
    """Killed while it has frames to extract, or while the reader waits on a slow source (the
    next task cannot be sent)."""

    def source() -> Iterator[StereoFrame]:
        for fr in frames * 10:
            if idle:
                time.sleep(0.05)
            yield fr

    fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig()))
    workers = ExtractionWorkers(fe.extractor, 2)
    stream = workers.stream(source())
    next(stream)
    os.kill(workers._procs[1].pid, signal.SIGKILL)
    with pytest.raises(SlamError, match=r"feature extraction process .* stopped"):
        for _ in stream:
            pass


def test_the_shared_memory_has_no_name_once_the_workers_run(scene: Scene, frames, made_shm) -> None:
    """Nothing is left in /dev/shm even if the process is killed mid-run."""
    fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig()))
    stream = fe(iter(frames))
    next(stream)
    assert not _left(made_shm)
    stream.close()


def test_workers_that_do_not_start_leave_extraction_inline(
    scene: Scene, frames, monkeypatch, caplog
) -> None:
    """A Python that is not one (a frozen app) or cannot import eurocslam: a note, then the
    same features extracted in the caller."""
    monkeypatch.setattr(sys, "executable", "/bin/false")
    fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig()))
    got = list(fe(frames[:3]))
    for (_, ff), fr in zip(got, frames[:3], strict=True):
        _same(ff, fe.extractor.extract(fr))
    assert "did not start" in caplog.text


def _workers_of(pid: int) -> list[int]:
    out = subprocess.run(
        ["ps", "-ww", "-o", "pid=,args=", "--ppid", str(pid)], capture_output=True, text=True
    ).stdout
    return [int(ln.split()[0]) for ln in out.splitlines() if "eurocslam.frontend.workers" in ln]


def _gone(pid: int) -> bool:
    status = Path(f"/proc/{pid}/status")
    return not status.exists() or "zombie" in status.read_text()


@pytest.mark.skipif(sys.platform != "linux", reason="ps --ppid")
def test_ctrl_c_during_a_run_stops_the_workers(v101_micro: Path, tmp_path: Path) -> None:
    """`eurocslam run` interrupted while its workers extract (SIGINT to its process group, as
    a terminal sends it): exit 130, no traceback from the run or its workers, the MCAP kept as
    a readable .partial beside the outputs, no worker left behind."""
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "eurocslam.cli", "run", str(v101_micro), "-o", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a child inherits an ignored SIGINT from a pytest started in the background
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        start_new_session=True,  # a process group of its own, for the test to signal
    )
    try:
        deadline = time.monotonic() + 30
        workers: list[int] = []
        while time.monotonic() < deadline and len(workers) < 2:
            time.sleep(0.1)
            workers = _workers_of(proc.pid)
        assert len(workers) == 2, "the extraction workers did not start"
        # frames written (an image is 360 kB): a run stopped before its first frame leaves
        # nothing behind
        partial = out / ".staging" / "run.mcap.partial"
        while time.monotonic() < deadline + 30 and proc.poll() is None:
            if partial.exists() and partial.stat().st_size > 2_000_000:
                break
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    from mcap.reader import make_reader

    with open(out / "run.mcap.partial", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    assert all(_gone(pid) for pid in workers)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="VmHWM is Linux's")
def test_a_worker_reports_its_own_peak_memory_not_its_parents() -> None:
    """`ru_maxrss` survives exec: a worker started by a large process would report that
    process's peak. `peak_rss_mb` reads the worker's own high-water mark."""
    from eurocslam.memory import peak_rss_mb

    ballast = np.ones(256 * 2**20 // 8)  # 256 MB, touched
    child = subprocess.run(
        [sys.executable, "-c", "from eurocslam.memory import peak_rss_mb; print(peak_rss_mb())"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert peak_rss_mb() > 256
    assert 1 < float(child.stdout) < 100
    del ballast


def test_without_worker_processes_extraction_runs_inline(
    scene: Scene, frames, monkeypatch, caplog, made_shm
) -> None:
    """Where processes cannot start (a locked-down container, no shared memory), the stream
    says so and extracts in the caller, with the same features."""

    def refuse(*args, **kwargs):
        raise OSError("process creation not permitted")

    monkeypatch.setattr(subprocess, "Popen", refuse)
    fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig()))
    got = list(fe(frames[:4]))
    assert [fr for fr, _ in got] == frames[:4]
    for (_, ff), fr in zip(got, frames[:4], strict=True):
        _same(ff, fe.extractor.extract(fr))
    assert "extracting in this process" in caplog.text
    assert not _left(made_shm)


def test_workers_run_the_same_eurocslam_as_their_parent(tmp_path: Path) -> None:
    """A parent that imports a copy of eurocslam through sys.path (not PYTHONPATH): its
    workers import that copy too, not the installed one."""
    import shutil

    import eurocslam

    copy = tmp_path / "src"
    shutil.copytree(Path(eurocslam.__file__).parent, copy / "eurocslam")
    script = f"""
import sys
sys.path.insert(0, {str(copy)!r})
import eurocslam
assert eurocslam.__file__.startswith({str(copy)!r}), eurocslam.__file__
from eurocslam.synth import Scene, SynthSpec
from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor
from eurocslam.frontend.stream import FeatureStream
scene = Scene.build(SynthSpec.tiny(seed=2))
frames = [StereoFrame(int(scene.cam_t_ns[k]), scene.image(k, 0)[0], scene.image(k, 1)[0])
          for k in range(3)]
fe = FeatureStream(Extractor.for_rig(scene.rig, FrontendConfig()))
print(len(list(fe(frames))), len(fe.cost.worker_peak_rss_mb))
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["3", "2"]  # three frames, extracted by two workers
    assert "note:" not in r.stderr


def test_workers_started_early_are_the_ones_that_extract(scene: Scene, frames) -> None:
    """`run` starts the workers before its own imports (frontend/spawn.py); the extraction
    takes those processes, extracts as inline extraction does, and stops them."""
    from eurocslam.frontend import spawn
    from eurocslam.frontend.extraction import Extractor

    spawn.start_early(2)
    assert spawn._early is not None
    early = sorted(p.pid for p in spawn._early.procs)
    extractor = Extractor.for_rig(scene.rig, FrontendConfig())
    workers = ExtractionWorkers(extractor, 2)
    assert spawn._early is None
    assert sorted(p.pid for p in workers._procs) == early
    for fr, ff in workers.stream(iter(frames[:4])):
        _same(ff, extractor.extract(fr))
    assert all(_gone(pid) for pid in early)


@pytest.mark.skipif(sys.platform != "linux", reason="ps --ppid")
def test_a_run_that_ends_before_extracting_stops_the_early_workers(tmp_path: Path) -> None:
    """Workers started early for a run that fails first (no such sequence) end quietly: the
    one-line error only, no worker traceback, none left behind."""
    script = (
        "import os, subprocess, sys; from eurocslam.cli import main; "
        f"code = main(['run', {str(tmp_path / 'missing')!r}, '-o', {str(tmp_path / 'out')!r}]); "
        "ps = subprocess.run(['ps', '-o', 'args=', '--ppid', str(os.getpid())], "
        "capture_output=True, text=True).stdout; "
        "print('LEFT' if 'eurocslam.frontend.workers' in ps else 'NONE'); sys.exit(code)"
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "error" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert r.stdout.strip() == "NONE"
