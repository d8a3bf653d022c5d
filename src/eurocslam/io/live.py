"""Live view: serve messages over the Foxglove WebSocket protocol while they are produced.

`LiveSink` is a `Sink` (see `io/sink.py`): `write(topic, msgtype, log_time_ns, cdr_bytes)` logs
the message on a channel of a foxglove-sdk WebSocket server, paced so that data time advances at
`rate` x wall time (`rate=None` or `0`: as fast as possible; `io.pacing.PacingClock`).
`eurocslam run SEQ --live` tees it with the MCAP sink; `eurocslam play RUN.mcap --live` feeds it
from a recorded file (`io.playback.play_mcap`). A user opens Foxglove, connects to
`ws://localhost:8765` and imports the layout `run --live` prints (this run's panels, framed on its
ground truth's reach) or, for `play`, the shipped one (`layouts/eurocslam.json`).

- Two protocol names, one protocol: the SDK server listens on an ephemeral loopback port behind
  `io.live_relay.Relay`, which listens on the user's port and accepts both subprotocol names, so
  today's Foxglove and the open-source viewers connect.
- Latched topics (`io.qos.LATCHED_TOPICS`, and channels whose MCAP QoS says transient-local):
  the newest message is kept and re-sent whenever a client subscribes, so a viewer that connects
  late still gets the static transforms. Any topic's newest message that reached no viewer (the
  first message of a topic advertised a moment before, like `/slam/path_final` at the end of a
  run) is sent to the next subscriber. Re-sent messages carry the current log time (viewers stamp
  what they receive with the server clock and warn when data goes back in time).
- foxglove-sdk 0.30 quirks handled here: it may call `on_subscribe` before the new subscriber
  can receive on that channel (latched messages are sent again 0.3 s and 1.5 s later), and it
  may refuse a viewer's subscription to a channel created while the viewer connected ("Unknown
  channel ID"; the relay sees that status, the channel is re-created under a new id and the
  viewer subscribes to it; the error is not passed on).
- Time: the server has the `time` capability and broadcasts the data time, so the viewer's clock
  follows the data (EuRoC stamps), not the wall clock.
- Playback control (`play` only, where the viewer supports it): `live_control.PlaybackControl`.
  A seek or a loop moves the viewer's clock (back), which Foxglove treats as a seek: it drops
  what it holds (`restart_at`).
- Clients: `n_clients` counts connected viewers (at the relay); `wait_for_client(timeout)`
  blocks until one is connected and subscribed.
- Everything binds to 127.0.0.1 unless another host is given; `close()` stops the relay and the
  server (also after Ctrl-C: call it in a `finally`).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from eurocslam.errors import OutputError
from eurocslam.io.live_control import PlaybackControl
from eurocslam.io.live_relay import Relay
from eurocslam.io.pacing import PacingClock
from eurocslam.io.qos import LATCHED_TOPICS

if TYPE_CHECKING:
    import foxglove

DEFAULT_PORT = 8765
_LATCH_RESEND_S = (0.3, 1.5)  # latched messages go again this long after a subscription


def _require_live_deps() -> None:
    try:
        import foxglove  # noqa: F401
        import websockets  # noqa: F401
    except ImportError as e:
        raise OutputError(
            f"the live view needs the packages foxglove-sdk and websockets ({e.name} is "
            "missing): pip install 'foxglove-sdk>=0.16' 'websockets>=13'"
        ) from None


@dataclass
class _Topic:
    channel: foxglove.Channel
    msgtype: str
    latched: bool
    schema: bytes
    schema_encoding: str
    message_encoding: str
    last: tuple[int, bytes] | None = None  # newest (log time, data)
    undelivered: bool = False  # `last` was logged while no viewer subscribed to the topic


@dataclass
class LiveStats:
    messages: int = 0
    bytes: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)


class LiveSink:
    """A foxglove-sdk WebSocket server behind the `Sink` interface, paced at `rate`."""

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        rate: float | None = 1.0,
        name: str = "eurocslam",
        latched_topics: frozenset[str] = LATCHED_TOPICS,
        playback_range_ns: tuple[int, int] | None = None,
    ) -> None:
        _require_live_deps()
        import foxglove
        from foxglove.websocket import Capability

        self.clock = PacingClock(rate)
        self.latched_topics = latched_topics
        self.stats = LiveStats()
        self._topics: dict[str, _Topic] = {}
        self._lock = threading.RLock()
        self._subscribed: dict[int, set[int]] = {}  # client id -> channel ids
        self._sub_cond = threading.Condition()
        self._last_sub_change = time.monotonic()
        self._last_time_broadcast = -(1 << 62)
        self._closed = False
        self.recreated_channels = 0  # channels re-created after a refused subscription
        self._ctx = foxglove.Context()
        self.playback = PlaybackControl(self.clock, playback_range_ns, self._broadcast_playback)
        try:
            self._server = foxglove.start_server(
                name=name,
                host="127.0.0.1",
                port=0,
                capabilities=[Capability.Time],
                server_listener=_Listener(self),  # type: ignore[arg-type]
                context=self._ctx,
                playback_time_range=playback_range_ns,
            )
        except Exception as e:  # the SDK raises its own error types
            raise OutputError(f"live view: the Foxglove server did not start: {e}") from None
        try:
            self._relay = Relay(host, port, self._server.port, self._recreate_channel)
        except BaseException:
            self._server.stop()
            raise
        self.host = host

    # ---- info
    @property
    def port(self) -> int:
        return self._relay.port

    @property
    def url(self) -> str:
        host = "localhost" if self.host in ("127.0.0.1", "0.0.0.0", "::", "") else self.host
        return f"ws://{host}:{self.port}"

    @property
    def n_clients(self) -> int:
        """Viewers connected right now."""
        return self._relay.n_clients

    def wait_for_client(self, timeout: float | None = None) -> bool:
        """Block until a viewer is connected and has subscribed to a topic (True), or until
        `timeout` seconds have passed (False)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._sub_cond:
            while not any(self._subscribed.values()):
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._sub_cond.wait(0.1 if left is None else min(left, 0.1))
        return True

    def wait_subscriptions_settled(self, quiet_s: float = 3.0, timeout: float = 30.0) -> None:
        """Wait until no viewer has (un)subscribed for `quiet_s` (or `timeout` passed): a viewer
        subscribes panel by panel, and a 3D panel can take seconds longer than the others."""
        deadline = time.monotonic() + timeout
        with self._sub_cond:
            while True:
                now = time.monotonic()
                quiet_until = self._last_sub_change + quiet_s
                if now >= quiet_until or now >= deadline:
                    return
                self._sub_cond.wait(min(quiet_until, deadline) - now)

    def wait_all_disconnected(self, timeout: float | None = None) -> bool:
        return self._relay.wait_clients(lambda n: n == 0, timeout)

    # ---- channels
    def advertise(
        self,
        topic: str,
        msgtype: str,
        *,
        schema: bytes | None = None,
        schema_encoding: str = "ros2msg",
        message_encoding: str = "cdr",
        latched: bool | None = None,
    ) -> None:
        """Create the channel of `topic` now (so viewers see it before its first message).
        `schema` defaults to the ROS 2 humble definition of `msgtype` (`io.ros2.schema_text`)."""

        with self._lock:
            t = self._topics.get(topic)
            if t is not None:
                if t.msgtype != msgtype:
                    raise OutputError(
                        f"live view: topic {topic} already has type {t.msgtype}, "
                        f"cannot publish {msgtype}"
                    )
                return
            if schema is None:
                from eurocslam.io import ros2

                try:
                    schema = ros2.schema_text(msgtype).encode()
                except Exception as e:
                    raise OutputError(
                        f"no ROS 2 definition for message type {msgtype}: {e}"
                    ) from None
            channel = self._new_channel(topic, msgtype, schema, schema_encoding, message_encoding)
            is_latched = topic in self.latched_topics if latched is None else latched
            self._topics[topic] = _Topic(
                channel, msgtype, is_latched, schema, schema_encoding, message_encoding
            )

    def _new_channel(
        self, topic: str, msgtype: str, schema: bytes, schema_encoding: str, message_encoding: str
    ) -> foxglove.Channel:
        import foxglove

        return foxglove.Channel(
            topic,
            schema=foxglove.Schema(name=msgtype, encoding=schema_encoding, data=schema),
            message_encoding=message_encoding,
            context=self._ctx,
        )

    def _recreate_channel(self, channel_id: int) -> None:
        """Replace a channel the server refused a subscription to (see `Relay._server_status`):
        viewers get an unadvertise and a new advertise for the topic and subscribe again."""
        with self._lock:
            if self._closed:
                return
            for t in self._topics.values():
                if t.channel.id() == channel_id:
                    t.undelivered = t.last is not None
                    topic = t.channel.topic()
                    t.channel.close()  # first: the context holds one channel per topic
                    t.channel = self._new_channel(
                        topic, t.msgtype, t.schema, t.schema_encoding, t.message_encoding
                    )
                    self.recreated_channels += 1
                    return

    def set_latched(self, topic: str, log_time_ns: int, msg: bytes) -> None:
        """Store the message a latched topic re-sends to every new subscriber (without sending
        it now), e.g. the file's `/tf_static` before playback reaches it."""
        with self._lock:
            t = self._topics[topic]
            t.latched = True
            t.last = (int(log_time_ns), msg)

    def has_latched(self, topic: str) -> bool:
        with self._lock:
            t = self._topics.get(topic)
            return t is not None and t.last is not None

    # ---- Sink
    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
        if self._closed:
            raise OutputError("live view: write after close")
        t_ns = int(log_time_ns)
        if topic not in self._topics:
            self.advertise(topic, msgtype)
        if not self.clock.wait(t_ns):
            return  # stopped
        with self._lock:
            t = self._topics[topic]
            if t.msgtype != msgtype:
                raise OutputError(
                    f"live view: topic {topic} already has type {t.msgtype}, "
                    f"cannot publish {msgtype}"
                )
            t.last = (t_ns, msg)
            t.undelivered = not t.channel.has_sinks()
            # the viewer's clock first (<= 100 Hz): a viewer with the `time` capability stamps
            # what it receives with the last server time it got (0 before the first one)
            if abs(t_ns - self._last_time_broadcast) >= 10_000_000:
                self._broadcast_time(t_ns)
            t.channel.log(msg, log_time=t_ns)
        self.stats.messages += 1
        self.stats.bytes += len(msg)
        self.stats.per_topic[topic] = self.stats.per_topic.get(topic, 0) + 1

    def _broadcast_time(self, t_ns: int) -> None:
        self._server.broadcast_time(int(t_ns))
        self._last_time_broadcast = int(t_ns)

    def replay_latched(self, now_ns: int | None = None) -> None:
        """Send every latched topic's stored message again (after a seek or a loop: `now_ns` is
        the new playback time, sent first as the viewer's clock)."""
        with self._lock:
            if now_ns is not None:
                self._broadcast_time(now_ns)
            for t in self._topics.values():
                if t.latched and t.last is not None:
                    t.channel.log(t.last[1], log_time=self._resend_time(t.last[0]))

    def _on_subscribe(self, client_id: int, channel_id: int) -> None:
        with self._sub_cond:
            self._subscribed.setdefault(client_id, set()).add(channel_id)
            self._last_sub_change = time.monotonic()
            self._sub_cond.notify_all()
        self._resend_latched(channel_id)
        # foxglove-sdk may call on_subscribe before the client's sink is registered for the
        # channel (its issue "race where on_subscribe is called before the channel is
        # registered"), which drops a message logged right here; send it again shortly after.
        for delay in _LATCH_RESEND_S:
            timer = threading.Timer(delay, self._resend_latched, args=(channel_id,))
            timer.daemon = True
            timer.start()
        # A topic's newest message that reached nobody (e.g. the first message of a topic that
        # was just advertised, like the final path at the end of a run) goes to the new viewer.
        timer = threading.Timer(_LATCH_RESEND_S[0], self._resend_undelivered, args=(channel_id,))
        timer.daemon = True
        timer.start()

    def _topic_of(self, channel_id: int) -> _Topic | None:
        for t in self._topics.values():
            if t.channel.id() == channel_id:
                return t
        return None

    def _resend_latched(self, channel_id: int) -> None:
        with self._lock:
            t = self._topic_of(channel_id)
            if self._closed or t is None or not t.latched or t.last is None:
                return
            self._resend(t)

    def _resend(self, t: _Topic) -> None:
        """Log `t.last` again, at the viewer's current time, after a `time` frame (a new viewer
        needs one before its first message; see `Relay._pump_to_viewer`)."""
        assert t.last is not None
        now = self._resend_time(t.last[0])
        self._broadcast_time(now)
        t.channel.log(t.last[1], log_time=now)
        t.undelivered = False

    def _resend_undelivered(self, channel_id: int) -> None:
        with self._lock:
            t = self._topic_of(channel_id)
            if self._closed or t is None or t.latched or not t.undelivered or t.last is None:
                return
            self._resend(t)

    def _resend_time(self, t_ns: int) -> int:
        """Log time of a re-sent latched message: now on the viewer's clock, never older (viewers
        stamp messages with it and warn 'data went back in time')."""
        return max(int(t_ns), self._last_time_broadcast)

    def _on_unsubscribe(self, client_id: int, channel_id: int) -> None:
        with self._sub_cond:
            subs = self._subscribed.get(client_id)
            if subs is not None:
                subs.discard(channel_id)
                if not subs:
                    del self._subscribed[client_id]
            self._last_sub_change = time.monotonic()
            self._sub_cond.notify_all()

    # ---- playback control (`live_control.py`)
    def _broadcast_playback(self, state: Any) -> None:
        self._server.broadcast_playback_state(state)

    def restart_at(self, t_ns: int, *, announce: bool = True) -> None:
        """Playback jumps to `t_ns` (a seek, or the start again when looping): re-anchor the
        pacing clock, set the viewers' clock (a clock going back makes Foxglove drop what it
        holds, as on a seek), tell ranged-playback viewers that a seek happened (`announce`;
        a seek the viewer asked for is answered by the listener instead), and re-send the
        latched messages."""
        self.clock.reanchor()
        if announce:
            self.playback.broadcast_state(self.playback.status(), int(t_ns), did_seek=True)
        self.replay_latched(int(t_ns))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.clock.stop()
        try:
            self._relay.close()
        finally:
            self._server.stop()


class _Listener:
    """foxglove-sdk ServerListener: subscriptions (latched topics) and playback control."""

    def __init__(self, sink: LiveSink) -> None:
        self.sink = sink

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.sink._on_subscribe(int(client.id), int(channel.id))

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        self.sink._on_unsubscribe(int(client.id), int(channel.id))

    def on_playback_control_request(self, request: Any) -> Any:
        return self.sink.playback.on_request(request)
