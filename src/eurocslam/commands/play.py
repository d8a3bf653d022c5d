"""`eurocslam play RUN.mcap --live`: serve a recorded MCAP to Foxglove over WebSocket."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

from eurocslam.commands._args import non_negative_float
from eurocslam.errors import EurocSlamError
from eurocslam.timebase import NS_PER_S

if TYPE_CHECKING:
    from eurocslam.io.playback import McapInfo

NAME = "play"
HELP = "serve a recorded MCAP (e.g. OUT/run.mcap) live to Foxglove over WebSocket"

logger = logging.getLogger(__name__)

_GRACE_S = 3.0  # a viewer reloading its page reconnects within this time


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mcap", type=Path, help="an MCAP file, e.g. OUT/run.mcap from `eurocslam run`")
    p.add_argument(
        "--live",
        action="store_true",
        help="serve over the Foxglove WebSocket protocol (connect Foxglove to ws://localhost:PORT)",
    )
    p.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765; 0: any)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1, this machine only; 0.0.0.0 for all)",
    )
    p.add_argument(
        "--rate",
        type=non_negative_float,
        default=1.0,
        help="playback speed, x real time (default 1; 0 = as fast as possible)",
    )
    p.add_argument("--loop", action="store_true", help="start again at the end of the file")
    p.add_argument(
        "--no-wait",
        action="store_true",
        help="start playing at once instead of waiting for a viewer to connect",
    )
    p.add_argument(
        "--keep-serving",
        action="store_true",
        help="keep serving when every viewer has disconnected (default: stop, exit 0)",
    )


class _ViewerWatch:
    """True once a viewer has connected and every viewer has then been gone for longer than the
    grace period."""

    def __init__(self, n_clients: object, grace_s: float = _GRACE_S) -> None:
        self._n = n_clients
        self._grace = grace_s
        self._gone_since: float | None = None
        self._seen = False

    def __call__(self) -> bool:
        if self._n() > 0:  # type: ignore[operator]
            self._gone_since = None
            self._seen = True
            return False
        if not self._seen:
            return False
        now = time.monotonic()
        if self._gone_since is None:
            self._gone_since = now
        return now - self._gone_since > self._grace


def run(args: argparse.Namespace) -> int:
    from eurocslam.io.live import LiveSink
    from eurocslam.io.playback import advertise_mcap, play_mcap, read_mcap_info
    from eurocslam.progress import bar

    if not args.live:
        raise EurocSlamError(
            "play: add --live to serve the file over the Foxglove WebSocket protocol "
            "(to open it offline instead, drag the file into Foxglove)"
        )
    if args.rate < 0:
        raise EurocSlamError(
            f"play: --rate must be >= 0 (0 = as fast as possible), got {args.rate}"
        )
    if not 0 <= args.port <= 65535:
        raise EurocSlamError(f"play: --port must be 0..65535, got {args.port}")
    info = read_mcap_info(args.mcap)
    if info.message_count == 0:
        raise EurocSlamError(f"{info.path}: the MCAP holds no messages")
    span_s = (info.end_ns - info.start_ns) / NS_PER_S
    sink = LiveSink(
        host=args.host,
        port=args.port,
        rate=args.rate or None,
        playback_range_ns=(info.start_ns, info.end_ns),
    )
    try:
        advertise_mcap(info, sink)
        logger.info(
            f"eurocslam play: serving {info.path} ({info.message_count} messages, {span_s:.1f} s, "
            f"{len(info.channels)} topics) on {sink.url}\n"
            "  In Foxglove: Open connection > Foxglove WebSocket > "
            f"{sink.url}; layout: Layouts > Import from file > {_layout_for(info)}"
        )
        if not args.no_wait:
            logger.info("eurocslam play: waiting for a viewer to connect (Ctrl-C to stop)")
            while not sink.wait_for_client(1.0):
                pass
            sink.wait_subscriptions_settled()  # let every panel subscribe before the first message
        watch = None if args.keep_serving else _ViewerWatch(lambda: sink.n_clients)
        pb = bar(total=round(span_s, 1), desc="play", unit="s")
        shown = [0.0]

        def on_message(t_ns: int) -> None:
            done = round((t_ns - info.start_ns) / NS_PER_S, 1)
            if done > shown[0]:
                pb.update(done - shown[0])
                shown[0] = done

        try:
            res = play_mcap(
                info, sink, loop=args.loop, stop_when_no_clients=watch, on_message=on_message
            )
        finally:
            pb.close()
        if not res.finished:
            logger.info(
                f"eurocslam play: stopped after {res.messages} messages ({res.stopped_because})"
            )
            return 0
        logger.info(
            f"eurocslam play: end of file after {res.messages} messages"
            + (f", {res.seeks} seeks" if res.seeks else "")
        )
        if watch is None:
            logger.info("eurocslam play: still serving (Ctrl-C to stop)")
            while True:
                time.sleep(0.5)
        logger.info(
            "eurocslam play: still serving the last state until the viewer disconnects "
            "(Ctrl-C to stop now)"
        )
        while not watch():
            time.sleep(0.2)
        logger.info("eurocslam play: the viewer disconnected")
        return 0
    except KeyboardInterrupt:
        logger.info("eurocslam play: stopped (Ctrl-C)")
        return 0
    finally:
        sink.close()


def _layout_for(info: McapInfo) -> str:
    """The run's own layout beside its run.mcap, else the shipped one for its kind of run."""
    from eurocslam.io.layout import RUN_LAYOUT

    own = Path(info.path).parent / RUN_LAYOUT
    if own.is_file():
        return str(own)
    has_imu = any(c.topic == "/imu0" for c in info.channels.values())
    return "layouts/eurocslam.json" if has_imu else "layouts/eurocslam-visual.json"
