"""`eurocslam run SEQUENCE -o OUT`: stereo-inertial SLAM; trajectory, map and sensor streams."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "run"
HELP = "stereo-inertial SLAM: OUT/run.mcap (sensor streams + estimate), trajectories, map"
# `run` closes what it opens (extraction workers, the MCAP writer's thread, the live view): the
# `eurocslam` process may end right after it, without freeing the run's objects one by one
QUICK_EXIT = True


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from eurocslam.commands._args import add_sequence_arguments, finite_float, non_negative_float
    from eurocslam.run_options import COMPRESSIONS, IMAGE_MODES, RunOptions

    add_sequence_arguments(parser)
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT",
        help="output folder (created): run.mcap, trajectory_*.tum/.csv, map.ply, map/, "
        "config.yaml, summary.json, layout.json (this run's Foxglove layout); a previous run's "
        "outputs there are replaced",
    )
    parser.add_argument(
        "--no-imu",
        action="store_true",
        help="visual-only (stereo VO + sliding-window BA, no IMU factors); the same as "
        "mode: visual-only in the config",
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML config (default: configs/euroc.yaml; unknown keys are errors)",
    )
    parser.add_argument(
        "--start",
        type=finite_float,
        metavar="S",
        help="first time to process: seconds from the sequence start, or an "
        "absolute timestamp in ns",
    )
    parser.add_argument("--end", type=finite_float, metavar="S", help="last time to process")
    parser.add_argument(
        "--no-mcap", action="store_true", help="skip run.mcap (trajectories, map and summary only)"
    )
    parser.add_argument(
        "--compression",
        choices=COMPRESSIONS,
        default=RunOptions.compression,
        help=f"MCAP chunk compression (default {RunOptions.compression}; lz4: fast, zstd: smaller)",
    )
    parser.add_argument(
        "--images",
        choices=IMAGE_MODES,
        default=RunOptions.images,
        help="how camera images go into run.mcap (as in convert)",
    )
    parser.add_argument(
        "--map",
        metavar="DIR",
        help="an earlier run's OUT/map: start by localizing in it by appearance, then track "
        "and map on in its frame; OUT/map is saved as the union of both",
    )
    parser.add_argument(
        "--localize-only",
        action="store_true",
        help="keep the map as it is: do not write OUT/map",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    live = parser.add_argument_group("live view (Foxglove WebSocket)")
    live.add_argument(
        "--live",
        action="store_true",
        help="also stream every run.mcap topic live while processing: open Foxglove and "
        "connect to ws://localhost:PORT (the layout to import is printed at the start)",
    )
    live.add_argument("--port", type=int, help="live view port (default 8765; 0: any free port)")
    live.add_argument(
        "--host", help="live view address (default 127.0.0.1, this machine only; 0.0.0.0: all)"
    )
    live.add_argument(
        "--rate",
        type=non_negative_float,
        help="live view pacing, x the data's own rate (default 1; 0 = as fast as possible)",
    )


def _check_live_args(args: argparse.Namespace) -> None:
    from eurocslam.errors import EurocSlamError

    if not args.live:
        given = [f for f in ("port", "host", "rate") if getattr(args, f) is not None]
        if given:
            raise EurocSlamError(f"--{given[0]} is an option of the live view: add --live")
        return
    if args.no_mcap:
        raise EurocSlamError("--live streams what goes into run.mcap: drop --no-mcap")
    if args.rate is not None and args.rate < 0:
        raise EurocSlamError(f"--rate must be >= 0 (0 = as fast as possible), got {args.rate}")


def _live_layout_hint(source, inertial: bool, images: str) -> str:  # type: ignore[no-untyped-def]
    """Which layout the live view's viewer imports: this run's, written before the run into a
    new temporary folder (the run's own outputs are committed at its end), with its panels
    (visual-only without an IMU, the `--images` topics) and the 3D panel framed on as far as
    the ground truth goes from its start; the shipped one where that cannot be written."""
    import tempfile

    import numpy as np

    from eurocslam.io.layout import RUN_LAYOUT, live_layout, write_run_layouts

    gt = source.groundtruth
    reach = None
    if gt is not None and len(gt):
        p = np.asarray(gt.p, dtype=np.float64).reshape(-1, 3)
        d = np.linalg.norm(p - p[0], axis=1)
        reach = float(d[np.isfinite(d)].max()) if np.isfinite(d).any() else None
    try:
        folder = Path(tempfile.mkdtemp(prefix="eurocslam-live-"))
        write_run_layouts(folder, live_layout(inertial=inertial, images=images, reach_m=reach))
    except OSError:
        shipped = "eurocslam.json" if inertial else "eurocslam-visual.json"
        return f"layouts/{shipped} (shipped)"
    framing = "its 3D view framed on the ground truth" if reach is not None else "its panels"
    return f"{folder / RUN_LAYOUT} (this run's layout: {framing})"


def _start_live(args: argparse.Namespace, inertial: bool, source):  # type: ignore[no-untyped-def]
    from eurocslam.io.live import DEFAULT_PORT, LiveSink

    layout = _live_layout_hint(source, inertial, args.images)
    rate = 1.0 if args.rate is None else args.rate

    sink = LiveSink(
        host=args.host or "127.0.0.1",
        port=DEFAULT_PORT if args.port is None else args.port,
        rate=rate or None,
    )
    print(
        f"eurocslam run: live view on {sink.url} (Foxglove: Open connection > Foxglove "
        f"WebSocket; Layouts > Import from file > {layout})",
        file=sys.stderr,
        flush=True,
    )
    return sink


def _foxglove_hint(out: Path, source) -> None:  # type: ignore[no-untyped-def]
    from eurocslam.convert import sequence_start_ns
    from eurocslam.io.layout import RUN_LAYOUT
    from eurocslam.timebase import time_base

    print(
        f"Foxglove: open {out / 'run.mcap'}, then Layouts > Import from file > {out / RUN_LAYOUT} "
        "(this run's layout: its panels and 3D framing)"
    )
    if time_base(sequence_start_ns(source)) == "relative":
        print(
            "note: the stamps start at 0 s (the sequence's own clock): in Foxglove, choose "
            "Seconds in the time display below the panels to read them as sequence time"
        )


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from eurocslam.config import VISUAL_ONLY, load_config, resolve_mode
    from eurocslam.frontend.spawn import discard_early, start_early

    _check_live_args(args)
    if args.localize_only and not args.map:
        from eurocslam.errors import EurocSlamError

        raise EurocSlamError("--localize-only is an option of --map: add --map DIR")
    cfg = load_config(args.config)
    if cfg.frontend.prefetch:
        # the extraction workers import numpy and OpenCV while this process imports the rest
        start_early(cfg.frontend.prefetch_workers)
    live_sink = None
    try:
        from eurocslam.commands._args import source_options
        from eurocslam.dataset import open_sequence
        from eurocslam.dataset.types import has_imu

        if args.no_imu:
            cfg = dataclasses.replace(cfg, mode=VISUAL_ONLY)
        source = open_sequence(args.sequence, **source_options(args, cfg.imu))
        cfg = resolve_mode(cfg, has_imu(source), source.name)
        live_sink = _start_live(args, cfg.inertial, source) if args.live else None
        return _run(args, cfg, source, live_sink)
    finally:  # also on Ctrl-C (the CLI reports it, exit 130) and on errors
        discard_early()  # workers started early that no extraction took
        if live_sink is not None:
            live_sink.close()


def _run(args: argparse.Namespace, cfg, source, live_sink) -> int:  # type: ignore[no-untyped-def]
    from eurocslam.run_options import RunOptions
    from eurocslam.runner import run_slam

    opts = RunOptions(
        start=args.start,
        end=args.end,
        mcap=not args.no_mcap,
        compression=args.compression,
        images=args.images,
        progress=False if args.no_progress else None,
        map=Path(args.map) if args.map else None,
        localize_only=args.localize_only,
    )
    result = run_slam(source, args.output, cfg, opts, extra_sinks=[live_sink] if live_sink else ())
    for line in result.summary.lines():
        print(line)
    if source.skips.total:
        print(f"note: {source.skips.total} item(s) skipped while reading:", file=sys.stderr)
        for line in source.skips.lines():
            print(f"  {line}", file=sys.stderr)
    if opts.mcap:
        _foxglove_hint(Path(args.output), source)
    print(f"outputs in {args.output}")  # the last line (scripts read it)
    if live_sink is not None and live_sink.n_clients > 0:
        print(
            "eurocslam run: the live view keeps the final state until the viewer disconnects "
            "(Ctrl-C to stop)",
            file=sys.stderr,
            flush=True,
        )
        while not live_sink.wait_all_disconnected(0.5):
            pass
    return 0
