"""ROS 2 MCAP output (a `Sink`): what rosbag2's MCAP storage writes, so every reader accepts it.

- profile `ros2`, schemas `ros2msg` (root first, from `ros2.schema_text`), messages `cdr`;
- chunked with message indexes, chunk CRCs, Statistics and summary offsets: the records mcap's
  `Writer` writes, byte for byte, by `mcap_chunks.ChunkedWriter` (faster; chunks can be
  compressed in background threads, `compress_threads`);
- compression zstd (default, level 1 like rosbag2's `zstd_fast` preset, see
  `mcap_chunks.ZSTD_LEVEL`), lz4 or none;
- channel metadata `offered_qos_profiles` as rosbag2 (humble) writes it: reliable/volatile, and
  transient-local on `/tf_static` so `ros2 bag play` latches it;
- a `rosbag2` metadata record (`serialized_metadata`: the bag's metadata.yaml, humble v5 form);
- attachments (e.g. the sensor.yaml files);
- log times must be non-decreasing (put a `ReorderBuffer` in front when producers interleave);
- crash safety: everything goes to `NAME.mcap.partial`; `close()` finishes the file and renames it
  to `NAME.mcap`. `abort(reason)` (or leaving a `with` block by an exception) still finishes the
  MCAP (summary, indexes) so the `.partial` file is readable, and leaves it under that name.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from eurocslam import __version__
from eurocslam.errors import OutputError
from eurocslam.io import ros2
from eurocslam.io.mcap_chunks import COMPRESSIONS, ZSTD_LEVEL, ChunkedWriter
from eurocslam.io.qos import LATCHED_TOPICS, qos_profile_yaml
from eurocslam.timebase import NS_PER_S


@dataclass
class TopicStats:
    msgtype: str
    count: int = 0
    bytes: int = 0
    first_ns: int | None = None
    last_ns: int | None = None


@dataclass
class WriteSummary:
    """What was written: per-topic counts and bytes, time span, file size."""

    path: Path
    topics: dict[str, TopicStats] = field(default_factory=dict)
    file_bytes: int = 0
    complete: bool = True

    @property
    def message_count(self) -> int:
        return sum(s.count for s in self.topics.values())

    @property
    def start_ns(self) -> int | None:
        firsts = [s.first_ns for s in self.topics.values() if s.first_ns is not None]
        return min(firsts) if firsts else None

    @property
    def end_ns(self) -> int | None:
        lasts = [s.last_ns for s in self.topics.values() if s.last_ns is not None]
        return max(lasts) if lasts else None

    def lines(self) -> list[str]:
        wn = max([24, *(len(n) for n in self.topics)])
        wt = max([34, *(len(s.msgtype) for s in self.topics.values())])
        out = [f"{'topic':<{wn}} {'type':<{wt}} {'messages':>9} {'MB':>9}"]
        for name, s in sorted(self.topics.items()):
            out.append(f"{name:<{wn}} {s.msgtype:<{wt}} {s.count:>9} {s.bytes / 1e6:>9.2f}")
        span = 0.0
        if self.start_ns is not None and self.end_ns is not None:
            span = (self.end_ns - self.start_ns) / NS_PER_S
        out.append(
            f"{self.message_count} messages, {span:.3f} s "
            f"({self.start_ns} .. {self.end_ns} ns), file {self.file_bytes / 1e6:.2f} MB: "
            f"{self.path}"
        )
        return out


def partial_path(path: Path) -> Path:
    return path.with_name(path.name + ".partial")


class McapSink:
    """ROS 2 MCAP file writer implementing `Sink`. Use as a context manager or call `close()`
    (success) / `abort(reason)` (keeps a readable `.partial`). `compress_threads`: chunks are
    compressed in that many background threads (0: in the thread that writes; the file is the
    same either way)."""

    def __init__(
        self,
        path: Path | str,
        *,
        compression: str = "zstd",
        chunk_size: int = 4 << 20,
        latched_topics: frozenset[str] = LATCHED_TOPICS,
        ros_distro: str = "humble",
        compress_threads: int = 0,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise OutputError(
                f"compression '{compression}' unknown; choose one of {', '.join(COMPRESSIONS)}"
            )
        self.path = Path(path)
        self.partial = partial_path(self.path)
        self.compression = compression
        self.latched_topics = latched_topics
        self.ros_distro = ros_distro
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.partial, "wb")  # noqa: SIM115 (closed in close/abort)
        except OSError as e:
            raise OutputError(f"{self.partial}: cannot create: {e}") from None
        self._writer = ChunkedWriter(
            self._fh,
            chunk_size=chunk_size,
            compression=compression,
            compress_threads=compress_threads,
            zstd_level=ZSTD_LEVEL,
        )
        self._writer.start(profile="ros2", library=f"eurocslam {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._last_ns: int | None = None
        self.stats: dict[str, TopicStats] = {}
        self._closed = False

    # ---- Sink ---------------------------------------------------------------------------------
    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
        t = int(log_time_ns)
        if self._last_ns is not None and t < self._last_ns:
            raise OutputError(
                f"{self.partial}: message on {topic} at t={t} ns is older than the previous "
                f"message (t={self._last_ns} ns); MCAP messages must be in log-time order"
            )
        ch = self._channels.get(topic)
        if ch is None:
            ch = (self._register(topic, msgtype), msgtype)
            self._channels[topic] = ch
        elif ch[1] != msgtype:
            raise OutputError(f"topic {topic} already has type {ch[1]}, cannot write {msgtype}")
        self._last_ns = t
        try:
            self._writer.add_message(
                channel_id=ch[0], log_time=t, data=msg, publish_time=t, sequence=0
            )
        except OSError as e:
            raise OutputError(f"{self.partial}: write failed: {e}") from None
        s = self.stats[topic]
        s.count += 1
        s.bytes += len(msg)
        if s.first_ns is None:
            s.first_ns = t
        s.last_ns = t

    def _register(self, topic: str, msgtype: str) -> int:
        sid = self._schemas.get(msgtype)
        if sid is None:
            try:
                text = ros2.schema_text(msgtype)
            except Exception as e:
                raise OutputError(f"no ROS 2 definition for message type {msgtype}: {e}") from None
            sid = self._writer.register_schema(name=msgtype, encoding="ros2msg", data=text.encode())
            self._schemas[msgtype] = sid
        qos = qos_profile_yaml(transient_local=topic in self.latched_topics)
        cid = self._writer.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=sid,
            metadata={"offered_qos_profiles": qos},
        )
        self.stats[topic] = TopicStats(msgtype)
        return cid

    def add_attachment(
        self, name: str, data: bytes, media_type: str = "text/plain", log_time_ns: int = 0
    ) -> None:
        self._writer.add_attachment(
            create_time=time.time_ns(),
            log_time=int(log_time_ns),
            name=name,
            media_type=media_type,
            data=data,
        )

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, data)

    # ---- finishing ----------------------------------------------------------------------------
    def _rosbag2_metadata(self) -> str:
        starts = [s.first_ns for s in self.stats.values() if s.first_ns is not None]
        ends = [s.last_ns for s in self.stats.values() if s.last_ns is not None]
        start = min(starts) if starts else 0
        duration = (max(ends) - start) if ends else 0
        count = sum(s.count for s in self.stats.values())
        info: dict[str, Any] = {
            "version": 5,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": topic,
                        "type": s.msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": qos_profile_yaml(
                            transient_local=topic in self.latched_topics
                        ),
                    },
                    "message_count": s.count,
                }
                for topic, s in self.stats.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.path.name],
            "files": [
                {
                    "path": self.path.name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
            ],
        }
        return yaml.safe_dump(info, default_flow_style=False, sort_keys=False)

    def _finish(self) -> None:
        try:
            self._writer.add_metadata(
                "rosbag2",
                {"serialized_metadata": self._rosbag2_metadata(), "ros_distro": self.ros_distro},
            )
            self._writer.finish()
        finally:
            self._writer.shutdown()
            self._fh.close()
            self._closed = True

    def close(self) -> None:
        """Finish the file and rename `.partial` to the final name."""
        if self._closed:
            return
        try:
            self._finish()
        except OSError as e:
            raise OutputError(f"{self.partial}: finishing failed: {e}") from None
        try:
            os.replace(self.partial, self.path)
        except OSError as e:
            raise OutputError(f"cannot rename {self.partial} to {self.path}: {e}") from None

    def abort(self) -> Path:
        """Finish the MCAP (so it is readable) but keep the `.partial` name. Returns its path."""
        if not self._closed:
            self._finish()
        return self.partial

    def summary(self) -> WriteSummary:
        done = self._closed and self.path.exists() and not self.partial.exists()
        p = self.path if done else self.partial
        size = p.stat().st_size if p.exists() else 0
        return WriteSummary(p, dict(self.stats), size, complete=done)

    def __enter__(self) -> McapSink:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
