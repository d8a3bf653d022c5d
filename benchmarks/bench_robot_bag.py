#!/usr/bin/env python3
"""A robot's bag against the ASL folder it was written from (issue #37): `eurocslam run BAG`
with no sensor.yaml anywhere (calibration from CameraInfo and /tf_static only, IMU noise from
the folder's imu0/sensor.yaml through --imu-calib) must give the folder's trajectory.

The ASL folder (a replica, `eurocslam synth --rig realsense` output, ...) is cropped to its
first `--seconds` of frames; each variant is written as a realsense-ros style bag
(`synth/robot_bag.py`), run in its own process, and compared with the run on the
folder: the largest position difference of the final and online trajectories (the same frames
are processed: both runs stop at the last written frame's stamp) and the ATE RMSE of both
against the folder's ground truth. CPU seconds are the child process's.

Variants: NAME=FORMAT:IMAGES:IMU[:ACCEL_HZ:GYRO_HZ], e.g. `ros1:raw:united`,
`ros2-mcap:rect:split`, `ros2-db3:raw:split:63:200` (the split streams resampled at those
rates; without rates: the folder's accel0/gyro0 streams if it has them, else its own rows).
IMAGES: raw, rect (a driver's float maps) or rect-fixed (the frontend's own fixed-point maps:
the images the frontend would make from the raw ones).

usage: .venv/bin/python benchmarks/bench_robot_bag.py ASL [--seconds 20] [--work DIR]
       [--variant NAME=SPEC ...] [--json OUT.json]
       .venv/bin/python benchmarks/bench_robot_bag.py --summarize A.json B.json ...
`--summarize` reads the `--json` files of runs on several folders (replicas, worlds) and prints
per variant the ATE ratios bag / folder and their geometric mean with a 90 % t-interval: a
single run's ratio moves by tens of percent under any sub-grey-level change of the images, so a
rectification that differs is judged on the mean over many.
Runs the code of the checkout the script is in (its src/ first on PYTHONPATH): to measure a
commit while editing, run the script from a `git worktree` of that commit.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
# the CLI of this checkout's src (a worktree of another revision runs its own code)
EXE = [sys.executable, "-m", "eurocslam.cli"]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"),
                                                    os.environ.get("PYTHONPATH", "")])}  # fmt: skip
DEFAULT_VARIANTS = [
    "ros1_raw_united=ros1:raw:united",
    "db3_raw_split=ros2-db3:raw:split",
    "mcap_raw_split=ros2-mcap:raw:split",
    "mcap_rect_united=ros2-mcap:rect:united",
    "mcap_rect_fixed_united=ros2-mcap:rect-fixed:united",
    "mcap_raw_split_63_200=ros2-mcap:raw:split:63:200",
]


def run(src: Path, out: Path, end_ns: int, imu_calib: Path) -> float:
    """`eurocslam run` in a subprocess; returns its CPU seconds."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cmd = [*EXE, "run", str(src), "-o", str(out), "--no-mcap", "--no-progress",
           "--end", str(end_ns), "--imu-calib", str(imu_calib)]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def ate(run_dir: Path, gt_folder: Path) -> dict[str, float]:
    js = run_dir / "eval.json"
    cmd = [*EXE, "eval", str(run_dir), str(gt_folder), "--json", str(js)]
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr[-2000:]}")
    res = json.loads(js.read_text())["results"]
    return {r["label"].split()[0]: float(r["ate_trans_m"]["rmse"]) for r in res}


def traj(run_dir: Path, which: str) -> np.ndarray:
    return np.loadtxt(run_dir / f"trajectory_{which}.csv", delimiter=",", comments="#")


def summarize(files: list[Path]) -> int:
    """Per variant over the `--json` files: ATE ratios bag / folder, final and online, and
    their geometric means with a 90 % t-interval."""
    from scipy.stats import t as student_t

    logs: dict[str, dict[str, list[float]]] = {}
    print("| folder | variant | final mm folder / bag | ratio | online mm folder / bag | ratio |")
    print("|---|---|---|---|---|---|")
    for f in files:
        d = json.loads(f.read_text())
        ref = d["rows"][0]
        for row in d["rows"][1:]:
            ratio = {w: row[w] / ref[w] for w in ("final", "online")}
            for w, r in ratio.items():
                logs.setdefault(row["variant"], {}).setdefault(w, []).append(float(np.log(r)))
            print(f"| {Path(d['asl']).name} | {row['variant']} | {ref['final'] * 1e3:.2f} / "
                  f"{row['final'] * 1e3:.2f} | {ratio['final']:.3f} | {ref['online'] * 1e3:.2f} "
                  f"/ {row['online'] * 1e3:.2f} | {ratio['online']:.3f} |")  # fmt: skip
    for name, by in logs.items():
        parts = []
        for w, x in by.items():
            m = float(np.mean(x))
            if len(x) > 1:
                h = float(student_t.ppf(0.95, len(x) - 1) * np.std(x, ddof=1) / np.sqrt(len(x)))
                parts.append(f"{w} x{np.exp(m):.3f} ({np.exp(m - h):.3f}-{np.exp(m + h):.3f})")
            else:
                parts.append(f"{w} x{np.exp(m):.3f}")
        print(
            f"{name}: geometric mean over {len(by['final'])} folders, 90 % t-interval: "
            + ", ".join(parts)
        )
    return 0


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--summarize":
        return summarize([Path(a) for a in sys.argv[2:]])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("asl", type=Path)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--work", type=Path, default=None, help="keep bags and runs here")
    ap.add_argument("--variant", action="append", default=None, metavar="NAME=SPEC")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    sys.path.insert(0, str(REPO / "src"))
    from eurocslam.dataset.asl import AslSequence
    from eurocslam.dataset.split_imu import read_split_imu
    from eurocslam.synth.robot_bag import RealsenseBagOptions, write_realsense_bag

    seq = AslSequence(args.asl)
    t = seq.frame_times
    n = int(np.searchsorted(t, t[0] + round(args.seconds * 1e9), side="right"))
    end_ns = int(t[n - 1])
    imu_calib = seq.mav0 / "imu0" / "sensor.yaml"
    split = read_split_imu(seq.mav0)
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_robot_bag_"))
    work.mkdir(parents=True, exist_ok=True)
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()  # fmt: skip
    when = time.strftime("%Y-%m-%d %H:%M")
    print(f"# bench_robot_bag {args.asl} first {n} frames ({args.seconds:g} s), commit {commit}, "
          f"{when}, {platform.node()} {os.cpu_count()} cores")  # fmt: skip
    ref_dir = work / "run_asl"
    shutil.rmtree(ref_dir, ignore_errors=True)
    cpu = run(seq.root, ref_dir, end_ns, imu_calib)
    ref = {w: traj(ref_dir, w) for w in ("final", "online")}
    ref_ate = ate(ref_dir, seq.root)
    rows: list[dict[str, Any]] = [{"variant": "ASL folder", "cpu_s": cpu, **ref_ate}]
    print(f"{'variant':26s} {'write s':>8s} {'run CPU s':>9s} {'max|dp| final':>14s} "
          f"{'max|dp| online':>14s} {'ATE final mm':>12s} {'ATE online mm':>13s}")  # fmt: skip
    print(f"{'ASL folder':26s} {'':>8s} {cpu:9.1f} {'':>14s} {'':>14s} "
          f"{ref_ate['final'] * 1e3:12.3f} {ref_ate['online'] * 1e3:13.3f}")  # fmt: skip
    for text in args.variant or DEFAULT_VARIANTS:
        name, _, spec = text.partition("=")
        parts = spec.split(":")
        fmt, images, imu = parts[:3]
        rates = [float(x) for x in parts[3:5]] if len(parts) >= 5 else [None, None]
        maps = "fixed" if images == "rect-fixed" else "float"
        opt = RealsenseBagOptions(images=images.removesuffix("-fixed"), imu=imu, rect_maps=maps,
                                  accel_rate_hz=rates[0], gyro_rate_hz=rates[1],
                                  max_frames=n)  # fmt: skip
        bag = work / (name + (".bag" if fmt == "ros1" else ""))
        if bag.exists():
            shutil.rmtree(bag) if bag.is_dir() else bag.unlink()
        t0 = time.perf_counter()
        write_realsense_bag(seq, bag, fmt, opt, split=split)
        wall = time.perf_counter() - t0
        out = work / f"run_{name}"
        shutil.rmtree(out, ignore_errors=True)
        cpu = run(bag, out, end_ns, imu_calib)
        dp = {}
        for w in ("final", "online"):
            got = traj(out, w)
            same = got.shape == ref[w].shape and np.array_equal(got[:, 0], ref[w][:, 0])
            dp[w] = float(np.abs(got[:, 1:4] - ref[w][:, 1:4]).max()) if same else float("nan")
        a = ate(out, seq.root)
        rows.append({"variant": name, "spec": spec, "write_s": wall, "cpu_s": cpu,
                     "max_dp_final_m": dp["final"], "max_dp_online_m": dp["online"],
                     **a})  # fmt: skip
        print(f"{name:26s} {wall:8.1f} {cpu:9.1f} {dp['final']:14.3g} {dp['online']:14.3g} "
              f"{a['final'] * 1e3:12.3f} {a['online'] * 1e3:13.3f}", flush=True)  # fmt: skip
        shutil.rmtree(bag) if bag.is_dir() else bag.unlink()
    if args.json:
        args.json.write_text(json.dumps({"asl": str(args.asl), "frames": n, "commit": commit,
                                         "rows": rows}, indent=2))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
