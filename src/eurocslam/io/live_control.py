"""Playback control of the live view (`eurocslam play --live`), for viewers that support it
(today's Foxglove; Foxglove Studio 1.48 and Lichtblick have no such controls for WebSocket
sources, and `--rate` sets the speed there).

The server advertises the file's time range; pause, resume and speed requests act on the
pacing clock, a seek request is queued for the reader (`pop_seek`), and the playback state
(playing, paused, ended, the current time, whether a seek happened) is broadcast to the
viewers. Without a time range nothing is broadcast: `run --live` streams as it computes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from eurocslam.io.pacing import PacingClock


class PlaybackControl:
    """What a ranged-playback viewer asks of the paced stream, and what it is told back."""

    def __init__(
        self,
        clock: PacingClock,
        range_ns: tuple[int, int] | None,
        broadcast: Callable[[Any], None],
    ) -> None:
        """`broadcast(state)`: send a foxglove `PlaybackState` to every viewer."""
        self.clock = clock
        self.range_ns = range_ns
        self._broadcast = broadcast
        self._lock = threading.Lock()
        self._seek_ns: int | None = None

    def request_seek(self, t_ns: int) -> None:
        with self._lock:
            self._seek_ns = int(t_ns)
        self.clock.reanchor()

    def pop_seek(self) -> int | None:
        """The seek a viewer asked for since the last call (None: none): the reader's to do."""
        with self._lock:
            s, self._seek_ns = self._seek_ns, None
            return s

    def status(self) -> Any:
        from foxglove.websocket import PlaybackStatus

        return PlaybackStatus.Paused if self.clock.paused else PlaybackStatus.Playing

    def broadcast_state(self, status: Any, t_ns: int, *, did_seek: bool = False) -> None:
        from foxglove.websocket import PlaybackState

        if self.range_ns is None:
            return
        self._broadcast(
            PlaybackState(
                status=status,
                current_time=int(t_ns),
                playback_speed=float(self.clock.rate or 1.0),
                did_seek=did_seek,
                request_id=None,
            )
        )

    def broadcast_ended(self) -> None:
        from foxglove.websocket import PlaybackStatus

        if self.range_ns is not None:
            end = self.clock.last_ns or self.range_ns[1]
            self.broadcast_state(PlaybackStatus.Ended, int(end))

    def on_request(self, request: Any) -> Any:
        """Answer a viewer's playback control request (foxglove `PlaybackControlRequest`)."""
        from foxglove.websocket import PlaybackCommand, PlaybackState, PlaybackStatus

        clock = self.clock
        if request.playback_speed and request.playback_speed > 0:
            clock.set_rate(float(request.playback_speed))
        if request.seek_time is not None:
            self.request_seek(int(request.seek_time))
        if request.playback_command == PlaybackCommand.Pause:
            clock.pause()
        elif request.playback_command == PlaybackCommand.Play:
            clock.resume()
        current = request.seek_time if request.seek_time is not None else clock.last_ns
        if current is None:
            current = self.range_ns[0] if self.range_ns else 0
        return PlaybackState(
            status=PlaybackStatus.Paused if clock.paused else PlaybackStatus.Playing,
            current_time=int(current),
            playback_speed=float(clock.rate or 1.0),
            did_seek=request.seek_time is not None,
            request_id=request.request_id,
        )
