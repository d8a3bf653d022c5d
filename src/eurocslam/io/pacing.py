"""Pacing: data time (int64 ns) mapped to wall time at `rate` x real time, with pause, resume,
speed changes and re-anchoring after a seek. The live view waits on it before each message.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from eurocslam.timebase import NS_PER_S

_MAX_LAG_S = 0.5  # when the producer falls this far behind the pacing clock, re-anchor it


class PacingClock:
    """Maps data time (ns) to wall time at `rate` x real time, with pause and speed changes.

    `wait(t_ns)` blocks until the wall clock reaches the slot of `t_ns` (and while paused).
    `rate` None, 0 or inf means as fast as possible. If the producer is slower than the clock
    (more than 0.5 s behind), the clock is re-anchored instead of bursting later."""

    def __init__(
        self,
        rate: float | None = 1.0,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._cond = threading.Condition()
        self._clock = clock
        self._rate = self._check_rate(rate)
        self._paused = False
        self._stopped = False
        self._anchor: tuple[int, float] | None = None  # (data ns, wall s)
        self.last_ns: int | None = None

    @staticmethod
    def _check_rate(rate: float | None) -> float | None:
        if rate is None or rate == 0 or math.isinf(rate):
            return None
        if not (rate > 0 and math.isfinite(rate)):
            raise ValueError(f"rate must be > 0 (or 0 for as fast as possible), got {rate}")
        return float(rate)

    @property
    def rate(self) -> float | None:
        return self._rate

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def stopped(self) -> bool:
        return self._stopped

    def set_rate(self, rate: float | None) -> None:
        with self._cond:
            self._rate = self._check_rate(rate)
            self._anchor = None
            self._cond.notify_all()

    def pause(self) -> None:
        with self._cond:
            self._paused = True
            self._cond.notify_all()

    def resume(self) -> None:
        with self._cond:
            self._paused = False
            self._anchor = None
            self._cond.notify_all()

    def reanchor(self) -> None:
        """Forget the time mapping (after a seek or a loop): the next `wait` starts afresh."""
        with self._cond:
            self._anchor = None
            self._cond.notify_all()

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()

    def wait(self, t_ns: int) -> bool:
        """Block until `t_ns` is due. Returns False if the clock was stopped meanwhile."""
        t_ns = int(t_ns)
        with self._cond:
            while True:
                if self._stopped:
                    return False
                if self._paused:
                    self._cond.wait(0.1)
                    continue
                if self._rate is None:
                    break
                now = self._clock()
                if self._anchor is None:
                    self._anchor = (t_ns, now)
                    break
                t0, w0 = self._anchor
                due = w0 + (t_ns - t0) / NS_PER_S / self._rate
                if now >= due:
                    if now - due > _MAX_LAG_S:  # the producer is behind: do not burst later
                        self._anchor = (t_ns, now)
                    break
                self._cond.wait(min(due - now, 0.1))
            self.last_ns = t_ns if self.last_ns is None else max(self.last_ns, t_ns)
            return True
