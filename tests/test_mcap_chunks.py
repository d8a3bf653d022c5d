"""`mcap_chunks.ChunkedWriter`: the same file as mcap's `Writer` for the same records, whatever
the compression threads, with a bounded number of chunks waiting."""

from __future__ import annotations

import io
import threading
import time
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from eurocslam.io import mcap_chunks
from eurocslam.io.mcap_chunks import ChunkedWriter


def _records(rng: np.random.Generator) -> list[tuple[str, Any]]:
    """A mixed script: schemas/channels registered between messages (also while a chunk is
    open), attachments and metadata between chunks, out-of-order log times, empty payloads."""
    ops: list[tuple[str, Any]] = [
        ("schema", ("pkg/msg/A", "ros2msg", b"int32 a")),
        ("channel", ("/a", "cdr", 1, {"k": "v"})),
        ("attachment", (7, 8, "calib.yaml", "text/yaml", b"x: 1\n")),
    ]
    t = 1_000
    for k in range(400):
        t += int(rng.integers(0, 3_000))
        n = int(rng.choice([0, 5, 300, 9_000, 70_000]))
        ch = 1 if k < 50 else int(rng.integers(1, 4))
        ops.append(("message", (ch, t - int(rng.integers(0, 50)), rng.bytes(n), t, k % 7)))
        if k == 30:
            ops.append(("schema", ("pkg/msg/B", "ros2msg", b"float64 b")))
        if k == 49:
            ops.append(("channel", ("/b", "cdr", 2, {})))
            ops.append(("channel", ("/c", "cdr", 1, {"q": "1"})))
        if k == 200:
            ops.append(("metadata", ("mid", {"a": "b"})))
    ops.append(("metadata", ("end", {"x": "y"})))
    return ops


def _play(w: Any, ops: list[tuple[str, Any]]) -> None:
    w.start(profile="ros2", library="test")
    for kind, args in ops:
        if kind == "schema":
            w.register_schema(*args)
        elif kind == "channel":
            w.register_channel(*args)
        elif kind == "message":
            ch, log, data, pub, seq = args
            w.add_message(channel_id=ch, log_time=log, data=data, publish_time=pub, sequence=seq)
        elif kind == "attachment":
            w.add_attachment(*args)
        else:
            w.add_metadata(*args)
    w.finish()


class _ZstdAs:
    """mcap's `Writer` calls `zstandard.compress(data)`: compress as ChunkedWriter does."""

    def __init__(self, module: Any) -> None:
        self._module = module
        self.compress = mcap_chunks._compressor("zstd", mcap_chunks.ZSTD_LEVEL)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module, name)


def _mcap_writer_bytes(
    ops: list[tuple[str, Any]], compression: str, chunk_size: int, monkeypatch: Any
) -> bytes:
    import mcap.writer as mw

    if compression == "zstd":
        monkeypatch.setattr(mw, "zstandard", _ZstdAs(mw.zstandard))
    ctype = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}.get(
        compression, CompressionType.NONE
    )
    buf = io.BytesIO()
    _play(Writer(buf, chunk_size=chunk_size, compression=ctype, enable_crcs=True), ops)
    return buf.getvalue()


def _chunked_bytes(
    ops: list[tuple[str, Any]], compression: str, chunk_size: int, threads: int
) -> bytes:
    buf = io.BytesIO()
    _play(
        ChunkedWriter(
            buf, chunk_size=chunk_size, compression=compression, compress_threads=threads
        ),
        ops,
    )
    return buf.getvalue()


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
@pytest.mark.parametrize("chunk_size", [1 << 20, 50_000])
def test_same_bytes_as_mcap_writer(compression: str, chunk_size: int, monkeypatch: Any) -> None:
    ops = _records(np.random.default_rng(3))
    ref = _mcap_writer_bytes(ops, compression, chunk_size, monkeypatch)
    ours = _chunked_bytes(ops, compression, chunk_size, 0)
    assert ours == ref
    # and it reads back: every message, in order, with its CRCs checked
    r = make_reader(io.BytesIO(ours), validate_crcs=True)
    n = sum(1 for _ in r.iter_messages(log_time_order=False))
    assert n == sum(k == "message" for k, _ in ops)
    assert r.get_summary().statistics.chunk_count > (2 if chunk_size < 1 << 20 else 0)


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_compression_threads_write_the_same_file(threads: int) -> None:
    ops = _records(np.random.default_rng(5))
    assert _chunked_bytes(ops, "zstd", 60_000, threads) == _chunked_bytes(ops, "zstd", 60_000, 0)


def test_pending_chunks_are_bounded(monkeypatch: Any) -> None:
    """With slow compression the writer waits: never more than threads + 1 full chunks held."""
    gate = threading.Semaphore(0)
    real = mcap_chunks._compressor("zstd", 1)

    def slow(data: bytes) -> bytes:
        gate.acquire()
        return real(data)

    monkeypatch.setattr(mcap_chunks, "_compressor", lambda *_: slow)
    w = ChunkedWriter(io.BytesIO(), chunk_size=1_000, compression="zstd", compress_threads=2)
    w.start()
    sid = w.register_schema("s", "ros2msg", b"")
    cid = w.register_channel("/t", "cdr", sid, {})
    seen: list[int] = []
    done = threading.Event()

    def produce() -> None:
        for k in range(20):
            w.add_message(cid, k, b"x" * 2_000, k)  # every message fills a chunk
            seen.append(len(w._pending))
        done.set()

    th = threading.Thread(target=produce)
    th.start()
    time.sleep(0.3)
    assert not done.is_set()  # blocked on the bound, not buffering everything
    assert max(seen) <= 3
    for _ in range(100):
        gate.release()
    th.join(10)
    assert done.is_set() and max(seen) <= 3
    w.finish()


def test_unknown_compression() -> None:
    with pytest.raises(ValueError, match="compression"):
        ChunkedWriter(io.BytesIO(), compression="bz2")
