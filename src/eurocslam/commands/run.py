"""`eurocslam run SEQUENCE -o OUT`: stereo-inertial SLAM; trajectory, map and sensor streams."""

from __future__ import annotations

import argparse
import sys

NAME = "run"
HELP = "stereo-inertial SLAM: OUT/run.mcap (sensor streams + estimate), trajectories, map"


def _time(value: str) -> float:
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{value}' is not a number") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from eurocslam.dataset.bag import add_source_arguments

    parser.add_argument(
        "sequence",
        help="sequence folder (containing mav0/) or its mav0/ folder; also a ROS 1 .bag, a "
        "ROS 2 bag folder, .db3 or .mcap (e.g. the output of convert)",
    )
    add_source_arguments(parser)
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT",
        help="output folder (created): run.mcap, trajectory_*.tum/.csv, map.ply, "
        "config.yaml, summary.json",
    )
    parser.add_argument(
        "--no-imu",
        action="store_true",
        help="visual-only (stereo VO + sliding-window BA, no IMU factors)",
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML config (default: configs/euroc.yaml; unknown keys are errors)",
    )
    parser.add_argument(
        "--start",
        type=_time,
        metavar="S",
        help="first time to process: seconds from the sequence start, or an "
        "absolute timestamp in ns",
    )
    parser.add_argument("--end", type=_time, metavar="S", help="last time to process")
    parser.add_argument(
        "--no-mcap", action="store_true", help="skip run.mcap (trajectories, map and summary only)"
    )
    parser.add_argument(
        "--compression",
        choices=("zstd", "lz4", "none"),
        default="lz4",
        help="MCAP chunk compression (default lz4: fast; zstd: smaller)",
    )
    parser.add_argument(
        "--images",
        choices=("raw", "png", "jpeg"),
        default="raw",
        help="how camera images go into run.mcap (as in convert)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from eurocslam.config import load_config
    from eurocslam.dataset import open_sequence
    from eurocslam.dataset.bag import source_options
    from eurocslam.runner import RunOptions, run_slam

    cfg = load_config(args.config)
    source = open_sequence(args.sequence, **source_options(args))
    opts = RunOptions(
        use_imu=not args.no_imu,
        start=args.start,
        end=args.end,
        mcap=not args.no_mcap,
        compression=args.compression,
        images=args.images,
        progress=False if args.no_progress else None,
    )
    result = run_slam(source, args.output, cfg, opts)
    for line in result.summary.lines():
        print(line)
    if source.skips.total:
        print(f"note: {source.skips.total} item(s) skipped while reading:", file=sys.stderr)
        for line in source.skips.lines():
            print(f"  {line}", file=sys.stderr)
    print(f"outputs in {args.output}")
    return 0
