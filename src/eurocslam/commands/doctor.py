"""`eurocslam doctor SEQUENCE`: check an EuRoC ASL folder, a KITTI odometry sequence or a ROS bag /
MCAP input; exit 0 ok, 1 warnings, 2 errors."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from eurocslam.commands._args import add_sequence_arguments, source_options

NAME = "doctor"
HELP = (
    "check an EuRoC, TUM-VI or KITTI sequence folder (files, CSVs, timestamps, images, "
    "calibration) or a bag"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_sequence_arguments(parser)
    parser.add_argument(
        "--full",
        action="store_true",
        help="decode every image (default: read every PNG header, decode a sample)",
    )
    parser.add_argument(
        "--sample",
        type=int,
        default=24,
        metavar="N",
        help="images per camera to decode fully when not --full (default 24)",
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.epilog = (
        "Exit codes: 0 no problem, 1 warnings only, 2 errors. Each finding names the file, "
        "line and key."
    )


def run(args: argparse.Namespace) -> int:
    from eurocslam.dataset.bag.files import is_bag_path
    from eurocslam.dataset.doctor.asl_checks import diagnose
    from eurocslam.dataset.doctor.bag_checks import diagnose_bag
    from eurocslam.dataset.doctor.kitti_checks import diagnose_kitti
    from eurocslam.dataset.kitti_files import is_kitti_root, is_kitti_sequence
    from eurocslam.progress import bar

    if args.sample < 0:
        print("eurocslam doctor: error: --sample must be >= 0", file=sys.stderr)
        return 2
    if is_bag_path(args.sequence):
        report = diagnose_bag(args.sequence, **source_options(args))
    else:
        path = Path(args.sequence)
        kitti = is_kitti_sequence(path) or is_kitti_root(path)
        if args.topic or args.imu_calib or (args.calib and kitti):
            print(
                "eurocslam doctor: error: --topic and --imu-calib apply to bags, and a KITTI "
                "sequence is checked against its own calib.txt (--calib: ASL folders and bags)",
                file=sys.stderr,
            )
            return 2
        pbar = bar(
            total=None, desc="decoding images", unit="img", enabled=None if args.full else False
        )

        def progress(n: int, cam: str) -> None:
            pbar.update(n)

        try:
            if kitti:
                report = diagnose_kitti(
                    args.sequence, full=args.full, sample=args.sample, progress=progress
                )
            else:
                report = diagnose(
                    args.sequence,
                    full=args.full,
                    sample=args.sample,
                    progress=progress,
                    calib=args.calib,
                )
        finally:
            pbar.close()
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        print(report.format_text())
    return report.exit_code
