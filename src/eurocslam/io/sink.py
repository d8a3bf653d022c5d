"""Where encoded ROS 2 messages go: one small interface for MCAP files, the live view and tees.

A message is `(topic, msgtype, log_time_ns, data)` with `msgtype` the canonical ROS 2 name
('sensor_msgs/msg/Image') and `data` the CDR bytes from `eurocslam.io.ros2`. Sinks that need a
schema get it from `ros2.schema_text(msgtype)`.

- `Sink`: the protocol (`write`, `close`).
- `ReorderBuffer`: lets several producers (sensor streams, SLAM outputs) write slightly out of
  order; holds messages in a heap and forwards them in log-time order once a watermark passes
  (`advance(t_ns)`: "nothing older than t_ns will come"). Memory is bounded: past `max_bytes`
  the oldest messages are forwarded early, and a message older than anything already forwarded
  raises `OutputError` instead of silently breaking the order.
- `TeeSink`: one write, several sinks (MCAP + live view).
- `ThreadedSink`: runs a sink (compression, disk writes) in a background thread behind a bounded
  queue, so producing and writing overlap; errors surface on the next `write`/`close`.
"""

from __future__ import annotations

import heapq
import itertools
import queue
import threading
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

from eurocslam.errors import EurocSlamError, OutputError


@runtime_checkable
class Sink(Protocol):
    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None: ...

    def close(self) -> None: ...


class ReorderBuffer:
    """Bounded reorder buffer in front of a sink. Messages with equal log time keep their
    arrival order. `close()` flushes everything and closes the downstream sink."""

    def __init__(self, sink: Sink, *, max_bytes: int = 64 << 20) -> None:
        self.sink = sink
        self.max_bytes = max_bytes
        self._heap: list[tuple[int, int, str, str, bytes]] = []
        self._seq = itertools.count()
        self._bytes = 0
        self._flushed_ns: int | None = None  # log time of the newest forwarded message
        self.watermark_ns: int | None = None

    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
        t = int(log_time_ns)
        if self._flushed_ns is not None and t < self._flushed_ns:
            raise OutputError(
                f"message on {topic} at t={t} ns arrived after messages up to "
                f"t={self._flushed_ns} ns were written; the output must be in log-time order "
                "(advance() the watermark only past times no producer will write again)"
            )
        heapq.heappush(self._heap, (t, next(self._seq), topic, msgtype, msg))
        self._bytes += len(msg)
        while self._bytes > self.max_bytes and self._heap:
            self._pop()

    def advance(self, t_ns: int) -> None:
        """Forward every buffered message with log time <= t_ns."""
        t = int(t_ns)
        while self._heap and self._heap[0][0] <= t:
            self._pop()
        self.watermark_ns = t if self.watermark_ns is None else max(self.watermark_ns, t)

    def flush(self) -> None:
        while self._heap:
            self._pop()

    def _pop(self) -> None:
        t, _, topic, msgtype, msg = heapq.heappop(self._heap)
        self._bytes -= len(msg)
        self._flushed_ns = t
        self.sink.write(topic, msgtype, t, msg)

    @property
    def pending(self) -> int:
        return len(self._heap)

    def close(self) -> None:
        self.flush()
        self.sink.close()


class TeeSink:
    """Writes every message to each of `sinks`; closes all of them (even if one fails)."""

    def __init__(self, sinks: Sequence[Sink]) -> None:
        self.sinks = list(sinks)

    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
        for s in self.sinks:
            s.write(topic, msgtype, log_time_ns, msg)

    def close(self) -> None:
        errors: list[BaseException] = []
        for s in self.sinks:
            try:
                s.close()
            except BaseException as e:  # close the others, then re-raise the first
                errors.append(e)
        if errors:
            raise errors[0]


_STOP = object()


class ThreadedSink:
    """Runs `sink.write` in one background thread. Messages travel in batches (at most
    `batch_items` messages or `batch_bytes` bytes; a queue of at most `max_batches` batches, so
    memory stays bounded) to keep lock traffic low. A failure in the writer thread is re-raised
    in the caller on the next `write` or on `close`. `abort()` stops without draining."""

    def __init__(
        self,
        sink: Sink,
        *,
        max_batches: int = 8,
        batch_items: int = 512,
        batch_bytes: int = 4 << 20,
    ) -> None:
        self.sink = sink
        self._q: queue.Queue[object] = queue.Queue(maxsize=max_batches)
        self._batch: list[tuple[str, str, int, bytes]] = []
        self._batch_bytes = 0
        self._max_items = batch_items
        self._max_bytes = batch_bytes
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name="eurocslam-sink", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while True:
            item = self._q.get()
            if item is _STOP:
                return
            if self._error is not None:
                continue  # drain without writing after a failure
            try:
                for msg in item:  # type: ignore[attr-defined]
                    self.sink.write(*msg)
            except BaseException as e:
                self._error = e

    def _raise(self) -> None:
        if self._error is not None:
            e = self._error
            if isinstance(e, EurocSlamError):
                raise e
            raise OutputError(f"writing failed: {type(e).__name__}: {e}") from e

    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
        self._batch.append((topic, msgtype, log_time_ns, msg))
        self._batch_bytes += len(msg)
        if len(self._batch) >= self._max_items or self._batch_bytes >= self._max_bytes:
            self._send()

    def _send(self) -> None:
        self._raise()
        if self._batch:
            self._q.put(self._batch)
            self._batch = []
            self._batch_bytes = 0

    def join(self) -> None:
        """Write everything still batched or queued, then stop the thread."""
        if self._thread.is_alive():
            self._send()
            self._q.put(_STOP)
            self._thread.join()

    def close(self) -> None:
        self.join()
        self._raise()
        self.sink.close()

    def abort(self) -> None:
        """Drop what is still batched or queued and stop the thread (the wrapped sink is not
        closed)."""
        self._batch = []
        try:
            while True:
                self._q.get_nowait()
        except queue.Empty:
            pass
        if self._thread.is_alive():
            self._q.put(_STOP)
            self._thread.join()
