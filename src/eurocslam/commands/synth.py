"""`eurocslam synth OUT`: write a synthetic or semi-real EuRoC ASL sequence."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from eurocslam.commands._args import finite_float

if TYPE_CHECKING:
    from eurocslam.synth.spec import SynthSpec

NAME = "synth"
HELP = "write a synthetic or semi-real EuRoC sequence (rendered stereo, IMU, ground truth)"

_SWITCHES = (
    ("noise", "image_noise", "image sensor noise (read + shot noise)"),
    ("vignetting", "vignetting", "lens vignetting"),
    ("exposure", "exposure", "slow exposure (gain) changes"),
    ("blur", "motion_blur", "motion blur over an 8 ms exposure (5x render cost)"),
    ("imu-noise", "imu_noise", "IMU white noise and bias random walk from imu0/sensor.yaml"),
    ("bias", "imu_bias", "non-zero initial IMU biases"),
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from eurocslam.synth.spec import RIGS, SynthSpec

    d = SynthSpec()
    p.add_argument("out", type=Path, metavar="OUT", help="output sequence folder (gets mav0/)")
    p.add_argument(
        "--duration",
        type=finite_float,
        default=None,
        metavar="S",
        help="length in seconds (built-in motion: default 30; with --trajectory: caps the crop)",
    )
    p.add_argument("--seed", type=int, default=0, help="world, motion and noise seed (default 0)")
    p.add_argument(
        "--trajectory",
        type=Path,
        default=None,
        metavar="GT",
        help="replicate this motion: EuRoC ASL ground truth CSV or TUM file",
    )
    p.add_argument(
        "--world-from",
        type=Path,
        nargs="+",
        default=None,
        metavar="GT",
        help="build the world around these ground truths of one place (same frame, e.g. "
        "MH_01..MH_05) instead of --trajectory alone: every session rendered with the same "
        "files and --seed flies through the same world (its id is printed)",
    )
    p.add_argument(
        "--imu",
        type=Path,
        default=None,
        metavar="IMU",
        help="ship these real IMU rows (ASL imu0/data.csv, or a sequence folder) instead of "
        "simulated ones; needs --trajectory with the matching ground truth",
    )
    p.add_argument(
        "--start",
        type=finite_float,
        default=None,
        metavar="S",
        help="crop: start S seconds after the trajectory's first pose",
    )
    p.add_argument(
        "--end",
        type=finite_float,
        default=None,
        metavar="S",
        help="crop: end S seconds after the trajectory's first pose",
    )
    p.add_argument(
        "--calib",
        type=Path,
        default=None,
        metavar="FOLDER",
        help="folder with cam0/cam1/imu0 sensor.yaml (default: EuRoC's, built in)",
    )
    p.add_argument(
        "--rig",
        choices=RIGS,
        default="euroc",
        help="euroc: EuRoC's cameras and IMU (or --calib's), an EuRoC ASL folder; tumvi: "
        "TUM-VI's 512x512 stereo fisheye (equidistant, ~0.10 m baseline) and IMU, 20 Hz "
        "images, 200 Hz IMU, written as a TUM-VI folder (dso/camchain.yaml, mav0/mocap0); "
        "realsense: a RealSense-like 848x480 infrared pair at 30 Hz, ~5 cm baseline, gyro 400 Hz, "
        "accelerometer apart at 250 Hz, an EuRoC ASL folder; with --trajectory a rig's cam0 "
        "flies where EuRoC's cam0 does (default: euroc)",
    )
    p.add_argument(
        "--imu-rate",
        type=finite_float,
        default=None,
        metavar="HZ",
        help="IMU (gyro) rate instead of the calibration's (e.g. 200 for a RealSense)",
    )
    p.add_argument(
        "--accel-rate",
        type=finite_float,
        default=None,
        metavar="HZ",
        help="the accelerometer as a separate stream at this rate, united onto the gyro's "
        "stamps in imu0/ (both streams also in accel0/, gyro0/); --rig realsense: 250",
    )
    bags = p.add_argument_group("robot-style bags (written after the ASL folder, in OUT/bags/)")
    bags.add_argument(
        "--bag",
        action="append",
        default=[],
        choices=("ros1", "ros2-db3", "ros2-mcap"),
        help="also write the sequence as a realsense-ros style bag: CameraInfo and /tf_static "
        "only, no sensor.yaml (repeatable)",
    )
    bags.add_argument(
        "--bag-images",
        choices=("raw", "rect", "both"),
        default="raw",
        help="raw images (K, D, R/P) or rectified as a driver does (image_rect_raw); default raw",
    )
    bags.add_argument(
        "--bag-imu",
        choices=("united", "split", "both"),
        default="split",
        help="one /camera/imu topic or /camera/accel/sample + /camera/gyro/sample (default)",
    )
    for flag, field, text in _SWITCHES:
        default = getattr(d, field)
        p.add_argument(
            f"--{flag}",
            dest=field,
            action=argparse.BooleanOptionalAction,
            default=default,
            help=f"{text} (default: {'on' if default else 'off'})",
        )
    p.add_argument(
        "--ideal",
        action="store_true",
        help="turn every realism switch off (exact images and IMU, zero biases)",
    )
    p.add_argument(
        "--blackout",
        metavar="START:END",
        help="both cameras black and no IMU rows from START to END seconds after the first "
        "frame (a sensor blackout; the ground truth goes on)",
    )
    p.add_argument("--tiny", action="store_true", help="a 2 s sequence (tests, quick looks)")
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="rendering processes (default: all cores)",
    )
    p.add_argument(
        "--force", action="store_true", help="replace OUT if it holds an earlier synthetic sequence"
    )
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")


def spec_from_args(args: argparse.Namespace) -> SynthSpec:
    from eurocslam.errors import DatasetError
    from eurocslam.synth.spec import REALSENSE_ACCEL_HZ, TINY_DURATION_S, SynthSpec

    duration = args.duration
    if args.tiny and duration is None:
        duration = TINY_DURATION_S
    blackout = None
    if args.blackout:
        try:
            a, b = (float(x) for x in args.blackout.split(":"))
        except ValueError:
            raise DatasetError(f"--blackout {args.blackout}: expected START:END seconds") from None
        if not 0 <= a < b:
            raise DatasetError(f"--blackout {args.blackout}: need 0 <= START < END")
        blackout = (a, b)
    accel_rate = args.accel_rate
    if accel_rate is None and args.rig == "realsense":
        accel_rate = REALSENSE_ACCEL_HZ
    spec = SynthSpec(
        duration_s=duration,
        seed=args.seed,
        trajectory=args.trajectory,
        imu=args.imu,
        start_s=args.start,
        end_s=args.end,
        calib=args.calib,
        rig=args.rig,
        imu_rate_hz=args.imu_rate,
        accel_rate_hz=accel_rate,
        blackout=blackout,
        world_from=tuple(args.world_from) if args.world_from else None,
        **{field: getattr(args, field) for _, field, _ in _SWITCHES},
    )
    return spec.ideal() if args.ideal else spec


def run(args: argparse.Namespace) -> int:
    from eurocslam.errors import DatasetError
    from eurocslam.synth.sequence import synthesize

    if args.duration is not None and args.duration <= 0:
        raise DatasetError(f"--duration {args.duration:g}: must be positive")
    if args.workers is not None and args.workers < 1:
        raise DatasetError(f"--workers {args.workers}: must be at least 1")
    spec = spec_from_args(args)
    out = synthesize(spec, args.out, workers=args.workers, overwrite=args.force)
    summary = json.loads((out / "synth.json").read_text())
    written = write_bags(out, args, "calib" if spec.calib else spec.rig)
    if written:
        summary["bags"] = [str(b) for b in written]
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
        return 0
    s = summary
    print(f"wrote {out}", file=sys.stdout)
    print(
        f"  motion   {s['motion']}  ({s['path_length_m']:.1f} m, up to "
        f"{s['max_speed_mps']:.2f} m/s and {s['max_rate_radps']:.2f} rad/s)"
    )
    if s["fit_rms_m"] > 0:
        print(
            f"  fit      spline vs the given poses: {100 * s['fit_rms_m']:.2f} cm RMS, "
            f"{s['fit_rms_deg']:.2f} deg RMS"
        )
    print(f"  world    {s['world']}")
    print(
        f"  frames   {s['frames']} stereo pairs, {s['imu_samples']} IMU samples ({s['imu']}), "
        f"{s['duration_s']:.2f} s"
    )
    print(
        f"  render   {s['render_wall_s']:.1f} s with {s['workers']} worker(s), "
        f"{s['render_cpu_ms_per_pair']:.0f} ms CPU per stereo pair"
    )
    for b in written:
        print(f"  bag      {b}")
    print(f"  next     eurocslam doctor {written[0] if written else out}")
    return 0


def write_bags(out: Path, args: argparse.Namespace, rig_name: str) -> list[Path]:
    """The realsense-style bags asked for (`--bag`, `--bag-images`, `--bag-imu`), written from
    the ASL folder just made into OUT/bags/; returns their paths."""
    from eurocslam.dataset.asl import AslSequence
    from eurocslam.dataset.split_imu import read_split_imu
    from eurocslam.synth.robot_bag import RealsenseBagOptions, write_realsense_bag

    if not args.bag:
        return []
    seq = AslSequence(out)
    split = read_split_imu(seq.mav0)
    images = ("raw", "rect") if args.bag_images == "both" else (args.bag_images,)
    imus = ("united", "split") if args.bag_imu == "both" else (args.bag_imu,)
    folder = out / "bags"
    folder.mkdir(exist_ok=True)
    written = []
    for fmt in dict.fromkeys(args.bag):
        for im in images:
            for iu in imus:
                name = f"{rig_name}_{im}_{iu}_{fmt.replace('-', '_')}"
                path = folder / (name + ".bag" if fmt == "ros1" else name)
                if path.exists():
                    import shutil

                    shutil.rmtree(path) if path.is_dir() else path.unlink()
                opts = RealsenseBagOptions(images=im, imu=iu)
                written.append(write_realsense_bag(seq, path, fmt, opts, split=split))
    return written
