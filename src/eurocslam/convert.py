"""`eurocslam convert`: an EuRoC sequence -> one ROS 2 MCAP, in a single streaming pass.

Stack: source frames -> (thread pool: read/decode PNG, build CDR) -> `SensorStreams` (merges
IMU / ground truth / leica in log-time order) -> `ThreadedSink` (chunk compression and disk writes
in a background thread) -> `McapSink` (`out.mcap.partial`, renamed when complete).
At most `2 * workers + 2` frames are in flight, so memory does not grow with sequence length.
On any exception or Ctrl-C the MCAP is still finished (readable) under its `.partial` name and
the user is told where it is (a logged warning).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from eurocslam.dataset.types import SequenceSource, SkipReport
from eurocslam.errors import EurocSlamError, OutputError
from eurocslam.io.mcap_writer import McapSink, WriteSummary
from eurocslam.io.sensor_streams import EncodedFrame, SensorStreams, StreamOptions
from eurocslam.io.sink import ThreadedSink
from eurocslam.progress import bar
from eurocslam.timebase import resolve_time

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ConvertOptions:
    compression: str = "zstd"
    images: str = "raw"
    topics: frozenset[str] | None = None
    start: float | None = None  # seconds from the sequence start, or absolute ns (>= 1e15)
    end: float | None = None
    workers: int = 2
    compress_threads: int = 0  # chunk compression threads besides the writer thread (0: in it)
    attach_calibration: bool = True
    progress: bool | None = None  # None: when stderr is a terminal


@dataclass
class ConvertResult:
    summary: WriteSummary
    skips: SkipReport
    frames: int
    elapsed_s: float
    notes: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        out = self.summary.lines()
        out.append(
            f"{self.frames} stereo frames in {self.elapsed_s:.2f} s "
            f"({self.frames / max(self.elapsed_s, 1e-9):.1f} frames/s)"
        )
        if self.skips.total:
            out.append(f"skipped ({self.skips.total}):")
            out += [f"  {ln}" for ln in self.skips.lines()]
        out += self.notes
        return out


def sequence_start_ns(source: SequenceSource) -> int:
    """Earliest timestamp of any stream (the reference for relative --start/--end)."""
    cands = [int(source.imu.t_ns[0])] if len(source.imu) else []
    ft = source.frame_times
    if len(ft):
        cands.append(int(ft[0]))
    if source.groundtruth is not None and len(source.groundtruth):
        cands.append(int(source.groundtruth.t_ns[0]))
    if source.leica is not None and len(source.leica.t_ns):
        cands.append(int(source.leica.t_ns[0]))
    if not cands:
        raise OutputError(f"{source.name}: the sequence holds no timestamps")
    return min(cands)


def _encoded_frames(
    source: SequenceSource,
    streams: SensorStreams,
    pool: ThreadPoolExecutor,
    window: int,
    t0: int | None,
    t1: int | None,
) -> Iterator[EncodedFrame]:
    """Frames in time order, decoded/encoded `window` ahead in the pool."""
    entries = getattr(source, "entries", None)
    if entries is None:  # generic source: decode in its own iterator, encode in the pool
        pending: deque[Future[EncodedFrame]] = deque()
        for fr in source.frames(include_incomplete=True, t_start_ns=t0, t_end_ns=t1):
            pending.append(pool.submit(streams.encode_frame, fr))
            if len(pending) >= window:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
        return
    sel = [e for e in entries if (t0 is None or e.t_ns >= t0) and (t1 is None or e.t_ns <= t1)]
    futs: deque[Future[tuple[EncodedFrame, list[Path]]]] = deque()
    it = iter(sel)
    for e in it:
        futs.append(pool.submit(streams.encode_files, e.t_ns, e.left, e.right))
        if len(futs) >= window:
            break
    while futs:
        enc, bad = futs.popleft().result()
        nxt = next(it, None)
        if nxt is not None:
            futs.append(pool.submit(streams.encode_files, nxt.t_ns, nxt.left, nxt.right))
        for p in bad:
            source.skips.add("unreadable image", str(p))
        yield enc


def convert(
    source: SequenceSource,
    out: Path | str,
    options: ConvertOptions | None = None,
    *,
    attachments: dict[str, bytes] | None = None,
) -> ConvertResult:
    """Convert `source` into the ROS 2 MCAP `out`. Raises `EurocSlamError` on bad input/output;
    whatever happens, a readable MCAP is left behind (`out` or `out.partial`)."""
    opt = options or ConvertOptions()
    out = Path(out)
    t_ref = sequence_start_ns(source)
    t0, t1 = resolve_time(opt.start, t_ref), resolve_time(opt.end, t_ref)
    if t0 is not None and t1 is not None and t1 < t0:
        raise OutputError(f"--end ({opt.end}) is before --start ({opt.start})")
    streams = SensorStreams(
        source, StreamOptions(topics=opt.topics, images=opt.images, t_start_ns=t0, t_end_ns=t1)
    )
    started = time.perf_counter()
    mcap = McapSink(
        out, compression=opt.compression, compress_threads=max(0, int(opt.compress_threads))
    )
    sink = ThreadedSink(mcap)
    frames = 0
    pb = bar(
        total=streams.n_frames, desc=f"convert {source.name}", unit="frame", enabled=opt.progress
    )
    try:
        if attachments is None:
            attachments = calibration_attachments(source) if opt.attach_calibration else {}
        for name, data in attachments.items():
            mcap.add_attachment(name, data, "text/yaml", streams.t0_ns)
        mcap.add_metadata(
            "eurocslam",
            {
                "source": str(getattr(source, "root", source.name)),
                "images": opt.images,
                "compression": opt.compression,
            },
        )
        streams.write_static(sink)
        workers = max(1, int(opt.workers))
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="eurocslam-img") as pool:
            for enc in _encoded_frames(source, streams, pool, 2 * workers + 2, t0, t1):
                streams.write_frame(sink, enc)
                frames += enc.cam0 is not None or enc.cam1 is not None
                pb.update(1)
        streams.finish(sink)
        sink.close()  # drains the queue, finishes the MCAP, renames .partial -> out
    except BaseException as e:
        pb.close()
        try:
            sink.join()  # write what was already produced: no lost output
        except BaseException:
            sink.abort()
        try:
            partial = mcap.abort()
            s = mcap.summary()
            msg = (
                f"stopped early ({type(e).__name__}); the messages written so far are in "
                f"{partial} ({s.message_count} messages, a readable MCAP)"
            )
        except Exception as e2:  # pragma: no cover - disk full etc.
            msg = f"stopped early; could not finish {mcap.partial}: {e2}"
        logger.warning("eurocslam convert: %s", msg)
        if isinstance(e, EurocSlamError | KeyboardInterrupt):
            raise
        raise OutputError(f"conversion failed: {type(e).__name__}: {e} ({msg})") from e
    pb.close()
    return ConvertResult(mcap.summary(), source.skips, frames, time.perf_counter() - started)


def calibration_attachments(source: SequenceSource) -> dict[str, bytes]:
    """The sequence's sensor.yaml files (and body.yaml), named like `cam0/sensor.yaml`. An ASL
    folder calibrated from elsewhere (TUM-VI's dso/, a Kalibr camchain, --calib) attaches the
    rig it runs with, as EuRoC-style sensor.yaml texts, for cam0, cam1 and imu0."""
    paths = getattr(source, "sensor_yaml_paths", None)
    texts = {f"{s}/sensor.yaml": t.encode() for s, t in source.rig.yaml_texts}
    if paths is None:
        return texts
    out = {}
    for sensor, p in paths().items():
        name = "body.yaml" if sensor == "body" else f"{sensor}/sensor.yaml"
        out[name] = Path(p).read_bytes()
    if not getattr(source, "calibration_is_own", True):
        out = {k: v for k, v in out.items() if k[:4] not in ("cam0", "cam1", "imu0")} | texts
    return out
