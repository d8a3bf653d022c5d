"""Arguments shared by the subcommands (not a command itself: the CLI skips `_` modules).

argparse's plain `type=float` accepts `nan` and `inf`, which then fail deep inside as an internal
error; these reject them at the command line with argparse's usual one-line message. The input
SEQUENCE with `--calib`, `--imu-calib` and `--topic` is read the same way by every command that
reads one (`add_sequence_arguments`, `source_options`)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any


def finite_float(value: str) -> float:
    """A finite number (`nan`/`inf` rejected)."""
    try:
        v = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{value}' is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"'{value}' is not a finite number")
    return v


def positive_float(value: str) -> float:
    """A finite number > 0."""
    v = finite_float(value)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"'{value}' must be > 0")
    return v


def non_negative_float(value: str) -> float:
    """A finite number >= 0."""
    v = finite_float(value)
    if v < 0:
        raise argparse.ArgumentTypeError(f"'{value}' must be >= 0")
    return v


SEQUENCE_HELP = (
    "sequence folder (containing mav0/) or its mav0/ folder; a KITTI odometry sequence folder "
    "(sequences/NN); also a ROS 1 .bag, a ROS 2 bag folder, .db3 or .mcap (e.g. the output of "
    "convert)"
)


def add_sequence_arguments(parser: argparse.ArgumentParser) -> None:
    """The input SEQUENCE of a command that reads one (ASL folder or bag), with `--calib`,
    `--imu-calib` and `--topic`."""
    parser.add_argument("sequence", help=SEQUENCE_HELP)
    parser.add_argument(
        "--calib",
        metavar="FILE|DIR",
        type=Path,
        default=None,
        help="the calibration to use: a folder with cam0/, cam1/ and (optional) imu0/ "
        "sensor.yaml files; for ASL folders also a Kalibr camchain.yaml (its imu.yaml beside "
        "it) or a folder holding one (default: the folder's sensor.yaml, TUM-VI's "
        "dso/camchain.yaml, a Kalibr camchain beside it; bags: an MCAP's attached sensor.yaml, "
        "else the bag's CameraInfo and /tf_static, else the built-in EuRoC calibration)",
    )
    parser.add_argument(
        "--imu-calib",
        metavar="FILE",
        type=Path,
        default=None,
        help="IMU noise figures (a Kalibr imu.yaml or an imu0/sensor.yaml) replacing the "
        "calibration's; a bag carries none",
    )
    parser.add_argument(
        "--topic",
        metavar="ROLE=TOPIC",
        action="append",
        default=[],
        help="input bags: read this topic for a role (cam0/left, cam1/right, imu, or accel "
        "and gyro as separate streams, cam0_info, cam1_info, groundtruth, leica), e.g. "
        "--topic left=/camera/infra1/image_rect_raw; repeatable (default: EuRoC's names, "
        "else found by message type)",
    )


def source_options(args: argparse.Namespace, imu_config: Any = None) -> dict[str, Any]:
    """`open_sequence` keyword arguments from the options `add_sequence_arguments` added.
    IMU noise: `--imu-calib`'s file, else the figures `imu_config` (a run configuration's
    `imu:` section) sets."""
    from eurocslam.dataset.bag.topics import TopicMap
    from eurocslam.dataset.imu_noise import load_imu_noise, noise_from_config

    specs = getattr(args, "topic", None) or []
    imu_file = getattr(args, "imu_calib", None)
    noise = None
    if imu_file is not None:
        noise = load_imu_noise(imu_file)
    elif imu_config is not None:
        noise = noise_from_config(imu_config)
    return {
        "calib": getattr(args, "calib", None),
        "topics": TopicMap.from_specs(specs) if specs else None,
        "imu_noise": noise if noise is not None and not noise.empty else None,
    }


# eurocslam.eval.align.ALIGN_MODES (kept literal so that building the parser imports no numpy;
# a test keeps the two equal)
ALIGN_MODES = ("se3", "sim3", "posyaw", "origin", "none")


def add_alignment_arguments(parser: argparse.ArgumentParser, align_help: str) -> None:
    """`--align` and `--max-diff`, as `eval` and `bench` take them."""
    parser.add_argument("--align", choices=ALIGN_MODES, default="se3", help=align_help)
    parser.add_argument(
        "--max-diff",
        type=non_negative_float,
        default=0.01,
        metavar="S",
        help="max timestamp difference for association [s] (default 0.01, as evo)",
    )
