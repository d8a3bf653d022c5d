#!/usr/bin/env python3
"""Are two revisions' outputs bit-identical? For changes meant to preserve behaviour.

Runs every revision on the same cases and prints, per case, a hash of each output that a
behaviour-preserving change must not move: `trajectory_final.tum`, `trajectory_online.tum`,
`map.ply` and the summary's counts (frames, poses, keyframes, landmarks, segments, resets,
landmarks re-found, place events); then whether every revision agrees. The cases:

* three replicas (MH_04, V1_02, V2_01; development world 0, first `--duration` s),
  stereo-inertial and visual-only;
* the V1_02 replica on TUM-VI's fisheye rig (`synth --rig tumvi`), stereo-inertial;
* the real KITTI excerpt (`../shared/data/kitti_excerpt`, where present), visual-only by itself;
* a robot's bag: a RealSense-like flight written as a realsense-ros MCAP (raw images,
  accelerometer and gyroscope apart, calibration only in CameraInfo and /tf_static);
* a blackout flight (built-in motion, 30 s, cameras black and no IMU for 12-15 s: relocalization);
* two sessions: a built-in flight run once, then again started in the first run's map.

usage: .venv/bin/python benchmarks/bench_identical.py [--duration 30] base=HEAD new=.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from bench_ab import Variant, checked_out, parse_variant
from bench_slam import EXE, REPO, make_replica

KITTI = (
    Path(os.environ.get("EUROCSLAM_SHARED_KITTI", REPO.parent / "shared/data/kitti_excerpt"))
    / "sequences"
    / "k2"
)
COUNTS = (
    "frames",
    "frames_with_pose",
    "keyframes",
    "landmarks",
    "segments",
    "landmarks_reused",
)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12] if path.exists() else "-"


def _counts(out: Path) -> str:
    s = json.loads((out / "summary.json").read_text())
    parts = [str(s.get(k, "?")) for k in COUNTS]
    parts.append(str(len(s.get("resets", []))))
    places = s.get("places", {})
    parts.append(
        "/".join(str(len(places.get(k, []))) for k in ("loops", "relocalizations", "merges"))
    )
    return " ".join(parts)


def outputs(out: Path) -> dict[str, str]:
    return {
        "final": _digest(out / "trajectory_final.tum"),
        "online": _digest(out / "trajectory_online.tum"),
        "map.ply": _digest(out / "map.ply"),
        "counts": hashlib.sha256(_counts(out).encode()).hexdigest()[:12],
    }


def _run(v: Variant, seq: Path, out: Path, *args: str) -> None:
    cmd = [str(EXE), "run", str(seq), "-o", str(out), "--no-progress", "--no-mcap", *args]
    env = dict(os.environ, PYTHONPATH=str(v.src))
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        tail = (r.stderr or r.stdout).strip().splitlines()[-1:]
        raise SystemExit(f"{v.name}: {' '.join(cmd)} failed: {' '.join(tail)}")


def cases(
    cache: Path, duration: float, tmp: Path
) -> list[tuple[str, Callable[[Variant, Path], Path]]]:
    from eurocslam.synth import SynthSpec, synthesize

    out: list[tuple[str, Callable[[Variant, Path], Path]]] = []
    for short in ("MH_04", "V1_02", "V2_01"):
        for mode, extra in (("si", ()), ("vo", ("--no-imu",))):

            def replica(v: Variant, o: Path, s: str = short, a: tuple[str, ...] = extra) -> Path:
                _run(v, make_replica(s, cache, duration, 0), o, *a)
                return o

            out.append((f"{short} {mode}", replica))

    def fisheye(v: Variant, o: Path) -> Path:
        _run(v, make_replica("V1_02", cache, duration, 0, rig="tumvi"), o)
        return o

    out.append(("V1_02 tumvi si", fisheye))
    if KITTI.is_dir():

        def kitti(v: Variant, o: Path) -> Path:
            _run(v, KITTI, o)
            return o

        out.append(("KITTI excerpt", kitti))
    flights = tmp / "flights"

    def flight(name: str, spec: SynthSpec) -> Path:
        path = flights / name
        if not (path / "mav0").is_dir():
            synthesize(spec, path, progress=False)
        return path

    def blackout(v: Variant, o: Path) -> Path:
        seq = flight("blackout", SynthSpec(duration_s=30.0, seed=0, blackout=(12.0, 15.0)))
        _run(v, seq, o)
        return o

    def sessions(v: Variant, o: Path) -> Path:
        seq = flight("sessions", SynthSpec(duration_s=8.0, seed=1))
        _run(v, seq, o.with_name(o.name + "_first"))
        _run(v, seq, o, "--map", str(o.with_name(o.name + "_first") / "map"))
        return o

    def robot_bag(v: Variant, o: Path) -> Path:
        from eurocslam.dataset.asl import AslSequence
        from eurocslam.dataset.split_imu import read_split_imu
        from eurocslam.synth.robot_bag import RealsenseBagOptions, write_realsense_bag

        bag = flights / "realsense.mcap"
        if not bag.exists():
            seq = AslSequence(flight("realsense", SynthSpec.realsense(seed=2, duration_s=10.0)))
            opt = RealsenseBagOptions(imu="split")
            write_realsense_bag(seq, bag, "ros2-mcap", opt, split=read_split_imu(seq.mav0))
        _run(v, bag, o)
        return o

    out += [
        ("blackout flight", blackout),
        ("second session in a map", sessions),
        ("realsense bag, split IMU", robot_bag),
    ]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="+", help="NAME=REV (e.g. base=HEAD new=.)")
    ap.add_argument("--duration", type=float, default=30.0, help="replicas: first S seconds")
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "eurocslam_replicas"
    )
    args = ap.parse_args()
    variants = [parse_variant(t) for t in args.variants]
    if len({v.name for v in variants}) != len(variants):
        raise SystemExit("variant names must differ")
    if not EXE.exists():
        raise SystemExit(f"no {EXE} (set up the virtual environment: see README)")
    rows: list[tuple[str, dict[str, dict[str, str]]]] = []
    with (
        tempfile.TemporaryDirectory(prefix="bench_identical_") as tmp,
        checked_out(variants, Path(tmp)),
    ):
        for label, case in cases(args.cache, args.duration, Path(tmp)):
            got = {}
            for v in variants:
                got[v.name] = outputs(case(v, Path(tmp) / f"{v.name}_{len(rows)}"))
                print(f"  {label:<24} {v.name:<8} {got[v.name]}", file=sys.stderr, flush=True)
            rows.append((label, got))
    print(f"# outputs of {', '.join(f'{v.name}={v.rev}' for v in variants)} (sha256, 12 hex)")
    print("| case | " + " | ".join(v.name for v in variants) + " | identical |")
    print("|---|" + "---|" * (len(variants) + 1))
    same_all = True
    for label, got in rows:
        first = got[variants[0].name]
        same = all(got[v.name] == first for v in variants)
        same_all &= same
        cells = [" ".join(f"{k} {h}" for k, h in got[v.name].items()) for v in variants]
        print(f"| {label} | " + " | ".join(cells) + f" | {'yes' if same else 'NO'} |")
    print("all identical" if same_all else "DIFFERENT")
    return 0 if same_all else 1


if __name__ == "__main__":
    sys.exit(main())
