"""Playing a recorded MCAP into the live view: its channels (with the file's own schemas, latched
where the file says so), its time span, and paced playback with seeks and loops.

`read_mcap_info(path)` reads the file's summary; `play_mcap(info, sink)` sends its messages to a
`LiveSink` in log-time order at the sink's pace and serves the viewer's seek requests;
`advertise_mcap(info, sink)` creates every channel up front and stores each latched channel's
first message, so a viewer gets `/tf_static` as soon as it subscribes.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from eurocslam.errors import DatasetError
from eurocslam.io.qos import LATCHED_TOPICS, is_transient_local

if TYPE_CHECKING:
    from eurocslam.io.live import LiveSink


@dataclass(frozen=True)
class ChannelInfo:
    topic: str
    schema_name: str
    schema: bytes
    schema_encoding: str
    message_encoding: str
    latched: bool


@dataclass(frozen=True)
class McapInfo:
    path: Path
    start_ns: int
    end_ns: int
    message_count: int
    channels: dict[int, ChannelInfo]  # by MCAP channel id


def read_mcap_info(path: Path | str) -> McapInfo:
    """Channels, schemas and time span of an MCAP (from its summary, else one scan)."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"{p}: no such file")
    try:
        with open(p, "rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise DatasetError(
                    f"{p}: the MCAP has no summary section (an interrupted write?); "
                    "re-run or repair it with `mcap recover`"
                )
            channels = {}
            for cid, ch in summary.channels.items():
                sch = summary.schemas.get(ch.schema_id)
                if sch is None:
                    raise DatasetError(f"{p}: channel {ch.topic} has no schema")
                channels[cid] = ChannelInfo(
                    ch.topic,
                    sch.name,
                    sch.data,
                    sch.encoding,
                    ch.message_encoding,
                    ch.topic in LATCHED_TOPICS or is_transient_local(dict(ch.metadata)),
                )
            st = summary.statistics
            return McapInfo(
                p,
                int(st.message_start_time),
                int(st.message_end_time),
                int(st.message_count),
                channels,
            )
    except DatasetError:
        raise
    except (McapError, OSError, ValueError, EOFError, struct.error) as e:
        raise DatasetError(f"{p}: not a readable MCAP file ({type(e).__name__}: {e})") from None


def _iter_messages(path: Path, start_ns: int | None) -> Iterator[tuple[Any, Any, Any]]:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        try:  # mcap >= 1.3 names it `starting_at`; older releases only know `start_time`
            it = reader.iter_messages(starting_at=start_ns, log_time_order=True)
        except TypeError:
            it = reader.iter_messages(start_time=start_ns, log_time_order=True)
        yield from it


@dataclass
class PlayResult:
    messages: int = 0
    loops: int = 0
    seeks: int = 0
    finished: bool = False  # reached the end of the file (last loop)
    stopped_because: str = ""


def play_mcap(
    info: McapInfo,
    sink: LiveSink,
    *,
    loop: bool = False,
    stop_when_no_clients: Callable[[], bool] | None = None,
    on_message: Callable[[int], None] | None = None,
) -> PlayResult:
    """Send the file's messages to `sink` in log-time order, paced by its clock. Handles seek
    requests from the viewer; with `loop`, starts again at the end (like a seek to the start).
    `stop_when_no_clients()` is polled between messages: when it returns True, playback stops.
    """
    res = PlayResult()
    advertise_mcap(info, sink)
    start: int | None = None
    while True:
        seek: int | None = None
        for _schema, channel, message in _iter_messages(info.path, start):
            s = sink.playback.pop_seek()
            if s is not None:
                seek = s
                break
            if sink.clock.stopped:
                res.stopped_because = "stopped"
                return res
            if stop_when_no_clients is not None and stop_when_no_clients():
                res.stopped_because = "the viewer disconnected"
                return res
            sink.write(
                channel.topic, info.channels[channel.id].schema_name, message.log_time, message.data
            )
            res.messages += 1
            if on_message is not None:
                on_message(int(message.log_time))
        if seek is not None:
            res.seeks += 1
            start = max(info.start_ns, min(seek, info.end_ns))
            sink.restart_at(start, announce=False)  # the listener answered the request
            continue
        if loop and not sink.clock.stopped:
            res.loops += 1
            start = None
            sink.restart_at(info.start_ns)
            continue
        res.finished = True
        sink.playback.broadcast_ended()
        return res


def advertise_mcap(info: McapInfo, sink: LiveSink) -> None:
    """Advertise every channel of the file (with the file's own schemas) and store the first
    message of each latched channel, so a viewer gets `/tf_static` as soon as it subscribes,
    even before (or after seeking past) the point where the file has it. Idempotent."""
    from mcap.reader import make_reader

    for c in info.channels.values():
        sink.advertise(
            c.topic,
            c.schema_name,
            schema=c.schema,
            schema_encoding=c.schema_encoding,
            message_encoding=c.message_encoding,
            latched=c.latched,
        )

    latched = {cid: c.topic for cid, c in info.channels.items() if c.latched}
    if not latched:
        return
    with open(info.path, "rb") as fh:
        reader = make_reader(fh)
        seen: set[int] = set()
        for _s, ch, msg in reader.iter_messages(topics=list(latched.values()), log_time_order=True):
            if ch.id not in seen and not sink.has_latched(ch.topic):
                sink.set_latched(ch.topic, msg.log_time, msg.data)
                seen.add(ch.id)
            if len(seen) == len(latched):
                break
