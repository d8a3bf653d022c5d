"""The live view's WebSocket relay: one port that speaks both names of the Foxglove protocol.

foxglove-sdk (>= 0.1x) only accepts the WebSocket subprotocol `foxglove.sdk.v1`; Foxglove Studio
<= 1.8x, Lichtblick (before its late-2025 releases) and other ws-protocol clients ask for
`foxglove.websocket.v1`, the same protocol under its older name. So the SDK server listens on an
ephemeral loopback port and this relay (`websockets`) listens on the user's port, accepts either
name and passes frames through unchanged. Both today's Foxglove and the open-source viewers
connect. On the way it:

- holds message data that overtakes a viewer's first `time` frame (a viewer stamps messages
  with the last server time it got, 0 before the first);
- drops binary opcodes a viewer on the older name does not know (Foxglove Studio 1.x reconnects
  on them);
- intercepts the SDK's "Unknown channel ID" status (a subscription refused for a channel created
  while the viewer connected) and asks the sink to re-create that channel.

It counts connected viewers (`n_clients`, `wait_clients`).
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import threading
from collections.abc import Callable
from typing import Any

from eurocslam.errors import OutputError

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
_OP_MESSAGE_DATA, _OP_TIME = b"\x01", b"\x02"  # server binary opcodes (ws-protocol)
_MAX_HELD = 256  # message frames held per viewer until its clock starts
_LEGACY_BINARY_OPS = (b"\x01", b"\x02", b"\x03", b"\x04")  # data, time, service, asset


class Relay:
    """Accepts `foxglove.sdk.v1` and `foxglove.websocket.v1` on (host, port) and relays each
    connection, frame by frame, to the SDK server on 127.0.0.1:upstream_port."""

    def __init__(
        self,
        host: str,
        port: int,
        upstream_port: int,
        on_unknown_channel: Callable[[int], None] | None = None,
    ) -> None:
        self.host = host
        self.on_unknown_channel = on_unknown_channel
        self.upstream = f"ws://127.0.0.1:{upstream_port}"
        self.port = 0
        self._clients = 0
        self._lock = threading.Condition()
        self._loop = asyncio.new_event_loop()
        self._server: Any = None
        self._error: BaseException | None = None
        self._started = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(port,), daemon=True, name="eurocslam-live-relay"
        )
        self._thread.start()
        if not self._started.wait(10.0):
            raise OutputError(f"live view: the WebSocket relay on {host}:{port} did not start")
        if self._error is not None:
            err = self._error
            if isinstance(err, OSError):
                raise OutputError(
                    f"live view: cannot listen on {host}:{port}: {err.strerror or err} "
                    "(is another server using the port? choose one with --port)"
                ) from None
            raise OutputError(f"live view: relay failed to start: {err}") from None

    @property
    def n_clients(self) -> int:
        with self._lock:
            return self._clients

    def wait_clients(self, predicate: Callable[[int], bool], timeout: float | None) -> bool:
        with self._lock:
            return self._lock.wait_for(lambda: predicate(self._clients), timeout)

    def _run(self, port: int) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._start(port))
        except BaseException as e:
            self._error = e
            self._started.set()
            return
        self._started.set()
        self._loop.run_forever()
        # shutting down: close the listening socket and every open connection
        self._loop.run_until_complete(self._shutdown())
        self._loop.close()

    async def _start(self, port: int) -> None:
        from websockets.asyncio.server import serve

        self._server = await serve(
            self._handle,
            self.host,
            port,
            subprotocols=list(SUBPROTOCOLS),  # type: ignore[arg-type]
            compression=None,
            max_size=64 << 20,
            ping_interval=20,
            ping_timeout=60,
        )
        self.port = int(self._server.sockets[0].getsockname()[1])

    async def _shutdown(self) -> None:
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(TimeoutError, asyncio.TimeoutError):
                await asyncio.wait_for(self._server.wait_closed(), 3.0)
        tasks = [t for t in asyncio.all_tasks(self._loop) if t is not asyncio.current_task()]
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    async def _handle(self, client: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import WebSocketException

        with self._lock:
            self._clients += 1
            self._lock.notify_all()
        try:
            async with connect(
                self.upstream,
                subprotocols=list(SUBPROTOCOLS),  # type: ignore[arg-type]
                compression=None,
                max_size=None,
                open_timeout=10,
                ping_interval=None,
            ) as upstream:
                down = asyncio.ensure_future(self._pump(client, upstream))
                up = asyncio.ensure_future(self._pump_to_viewer(upstream, client))
                _, pending = await asyncio.wait({down, up}, return_when=asyncio.FIRST_COMPLETED)
                for t in pending:
                    t.cancel()
                await asyncio.gather(*pending, return_exceptions=True)
        except (OSError, WebSocketException, asyncio.TimeoutError, TimeoutError):
            pass  # the viewer went away or the server is stopping: nothing to report
        finally:
            with self._lock:
                self._clients -= 1
                self._lock.notify_all()

    def _server_status(self, frame: str) -> bool:
        """Look at a text frame from the server; False drops it. foxglove-sdk sometimes refuses
        a viewer's subscription to a channel it has just advertised ("Unknown channel ID: N",
        when the channel was created while the viewer connected); the sink then re-creates the
        channel, the viewer subscribes to the new one, and the error is not passed on."""
        if '"status"' not in frame or "Unknown channel ID" not in frame:
            return True
        m = re.search(r"Unknown channel ID: (\d+)", frame)
        if m is None or self.on_unknown_channel is None:
            return True
        threading.Thread(
            target=self.on_unknown_channel, args=(int(m.group(1)),), daemon=True
        ).start()
        return False

    @staticmethod
    async def _pump(src: Any, dst: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            async for frame in src:
                await dst.send(frame)
        except ConnectionClosed:
            pass
        finally:
            await dst.close()

    async def _pump_to_viewer(self, server: Any, viewer: Any) -> None:
        """Server -> viewer. Message data that overtakes the first `time` frame (the SDK queues
        them separately) is held until that frame has gone out: a viewer stamps messages with
        the last server time it got, 0 before the first, and would start its timeline at 1970."""
        from websockets.exceptions import ConnectionClosed

        held: list[bytes] = []
        clock_started = False
        # Viewers speaking the protocol's older name know the binary opcodes 1-4 only; Foxglove
        # Studio 1.x treats any other (5: playback state) as an error and reconnects.
        legacy = viewer.subprotocol == "foxglove.websocket.v1"
        try:
            async for frame in server:
                if isinstance(frame, str):
                    if not self._server_status(frame):
                        continue
                elif legacy and frame[:1] not in _LEGACY_BINARY_OPS:
                    continue
                elif not clock_started and frame[:1] == _OP_MESSAGE_DATA:
                    held.append(frame)
                    del held[:-_MAX_HELD]
                    continue
                elif frame[:1] == _OP_TIME:
                    clock_started = True
                    await viewer.send(frame)
                    for f in held:
                        await viewer.send(f)
                    held.clear()
                    continue
                await viewer.send(frame)
        except ConnectionClosed:
            pass
        finally:
            await viewer.close()

    def close(self) -> None:
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10.0)
