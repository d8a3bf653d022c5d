"""`eurocslam convert SEQUENCE -o out.mcap`: an EuRoC ASL folder, a KITTI sequence or a bag -> ROS 2
MCAP (Foxglove, ros2 bag)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from eurocslam.commands._args import add_sequence_arguments, finite_float, source_options

NAME = "convert"
HELP = (
    "convert an EuRoC or KITTI sequence to a ROS 2 MCAP (images, camera_info, IMU, tf, ground "
    "truth)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_sequence_arguments(parser)
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT.mcap",
        help="output file (written as OUT.mcap.partial, renamed when complete)",
    )
    parser.add_argument(
        "--compression",
        choices=("zstd", "lz4", "none"),
        default="zstd",
        help="MCAP chunk compression (default zstd; lz4 is faster, larger)",
    )
    parser.add_argument(
        "--images",
        choices=("raw", "png", "jpeg"),
        default="raw",
        help="raw: sensor_msgs/Image mono8 on /camN/image_raw (default); png "
        "(lossless) or jpeg: sensor_msgs/CompressedImage on "
        "/camN/image_raw/compressed",
    )
    parser.add_argument(
        "--start",
        type=finite_float,
        metavar="S",
        help="first time to keep: seconds from the sequence start, or an absolute timestamp in ns",
    )
    parser.add_argument(
        "--end", type=finite_float, metavar="S", help="last time to keep (same units as --start)"
    )
    parser.add_argument(
        "--topics",
        nargs="+",
        metavar="TOPIC",
        help="only these topics (default: all; see README 'MCAP topics')",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=2,
        metavar="N",
        help="image decode/encode threads (default 2)",
    )
    parser.add_argument(
        "--compress-threads",
        type=int,
        default=0,
        metavar="N",
        help="MCAP chunk compression threads (default 0: in the writer thread, which already "
        "runs beside the decode threads; more helps with --workers > 2 on more cores)",
    )
    parser.add_argument(
        "--force", action="store_true", help="replace OUT.mcap if it exists (default: refuse)"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from eurocslam.convert import ConvertOptions, convert
    from eurocslam.dataset import open_sequence
    from eurocslam.errors import OutputError

    if not str(args.output).endswith(".mcap"):
        raise OutputError(f"{args.output}: the output name must end in .mcap")
    source = open_sequence(args.sequence, **source_options(args))  # input errors first
    out = Path(args.output)
    if out.is_dir():
        raise OutputError(f"{out}: is a folder; give the output file name (e.g. {out}/out.mcap)")
    if out.exists() and out.resolve() == Path(args.sequence).resolve():
        raise OutputError(f"{out}: is the input; write the output to another file")
    if out.exists() and not args.force:
        raise OutputError(f"{out}: already exists (pass --force to replace it)")
    opts = ConvertOptions(
        compression=args.compression,
        images=args.images,
        topics=frozenset(args.topics) if args.topics else None,
        start=args.start,
        end=args.end,
        workers=max(1, args.workers),
        compress_threads=max(0, args.compress_threads),
        progress=False if args.no_progress else None,
    )
    result = convert(source, args.output, opts)
    for line in result.lines():
        print(line)
    if result.skips.total:
        print(
            f"note: {result.skips.total} item(s) skipped while reading (listed above)",
            file=sys.stderr,
        )
    return 0
