"""A minimal Foxglove WebSocket protocol client for tests (the `websockets` package), so the live
view is checked by a client we control: subprotocol negotiation, advertise, subscribe, message
data (decoded with rosbags' own ROS 2 definitions), time and playback-state frames.

Only loopback addresses are used and every wait has a timeout."""

from __future__ import annotations

import asyncio
import json
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

OP_MESSAGE_DATA = 1
OP_TIME = 2
OP_PLAYBACK_STATE = 5
OP_CLIENT_PLAYBACK_CONTROL = 3


@dataclass
class Received:
    subprotocol: str | None = None
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # id -> advertise entry
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)  # topic -> data
    times: list[int] = field(default_factory=list)
    playback_states: list[bytes] = field(default_factory=list)

    def decoded(self, topic: str) -> list[Any]:
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS2_HUMBLE)
        ch = next(c for c in self.channels.values() if c["topic"] == topic)
        return [store.deserialize_cdr(d, ch["schemaName"]) for _, d in self.messages[topic]]


def playback_control(command: int, speed: float, seek_ns: int | None, request_id: str) -> bytes:
    """Client PlaybackControlRequest: command 0 play / 1 pause, speed, optional seek time."""
    rid = request_id.encode()
    return (
        bytes([OP_CLIENT_PLAYBACK_CONTROL, command])
        + struct.pack("<fBQI", speed, seek_ns is not None, seek_ns or 0, len(rid))
        + rid
    )


async def session(
    url: str,
    *,
    subprotocol: str = "foxglove.websocket.v1",
    topics: set[str] | None = None,
    until: Callable[[Received], bool] | None = None,
    timeout: float = 20.0,
    idle_timeout: float = 5.0,
    on_message: Callable[[Received, Any], Any] | None = None,
) -> Received:
    """Connect, subscribe to `topics` (all when None) as they are advertised, and collect
    frames until `until(received)` holds, `timeout` passes, or nothing arrives for
    `idle_timeout` s. `on_message(received, ws)` is called after every frame and every 0.2 s;
    it may return bytes/str to send."""
    import websockets

    got = Received()
    deadline = time.monotonic() + timeout
    sub_topic: dict[int, str] = {}
    async with websockets.connect(
        url, subprotocols=[subprotocol], max_size=None, open_timeout=10, close_timeout=2
    ) as ws:
        got.subprotocol = ws.subprotocol
        last_frame = time.monotonic()
        while time.monotonic() < deadline:
            if until is not None and until(got):
                break
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.2)  # short polls: ticks on_message
            except asyncio.TimeoutError:
                frame = None
                if time.monotonic() - last_frame > idle_timeout:
                    break
            if frame is not None:
                last_frame = time.monotonic()
                await _handle(frame, got, ws, topics, sub_topic)
            if on_message is not None:
                out = on_message(got, ws)
                if out is not None:
                    await ws.send(out)
    return got


async def _handle(
    frame: str | bytes, got: Received, ws: Any, topics: set[str] | None, sub_topic: dict[int, str]
) -> None:
    if isinstance(frame, str):
        msg = json.loads(frame)
        if msg["op"] == "serverInfo":
            got.server_info = msg
        elif msg["op"] == "advertise":
            subs = []
            for c in msg["channels"]:
                got.channels[c["id"]] = c
                if topics is None or c["topic"] in topics:
                    sid = len(sub_topic) + 1
                    subs.append({"id": sid, "channelId": c["id"]})
                    sub_topic[sid] = c["topic"]
            if subs:
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        return
    op = frame[0]
    if op == OP_MESSAGE_DATA:
        sid, log_time = struct.unpack_from("<IQ", frame, 1)
        got.messages.setdefault(sub_topic[sid], []).append((log_time, bytes(frame[13:])))
    elif op == OP_TIME:
        got.times.append(struct.unpack_from("<Q", frame, 1)[0])
    elif op == OP_PLAYBACK_STATE:
        got.playback_states.append(bytes(frame))


def run_session(url: str, **kw: Any) -> Received:
    return asyncio.run(session(url, **kw))
