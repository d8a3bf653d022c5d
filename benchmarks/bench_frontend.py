#!/usr/bin/env python
"""Benchmark the stereo frontend and visual odometry on semi-real EuRoC replicas.

1. Replicas: `eurocslam.dataset.synth` renders each EuRoC sequence's real ground-truth motion
   (../shared/data/euroc/groundtruth) with the real calibration, cropped to `--duration`
   seconds centred on the middle of the sequence (MH sequences start with the drone being
   picked up and set down). Rendered once into `--cache` and reused.
2. Speed (frontend alone, no BA) on `--speed-seq`: milliseconds per stereo frame for each stage
   (PNG decode, rectification, ORB, stereo matching, tracking, PnP) measured sequentially in one
   thread, then frames/s wall clock for the sequential loop and for the two-stage pipeline
   (decode+rectify+ORB+stereo of frame k+1 in a worker thread while frame k is tracked).
3. Accuracy: visual odometry (`VisualOdometry`, default config: frame-to-map tracking) on
   every replica, translation ATE RMSE after SE(3) alignment (eurocslam.eval), a pose for every
   frame. With `--compare-ba` also with the GTSAM local bundle adjustment switched on.

The machine is shared: compare ratios within one run and quote medians. Example:

    .venv/bin/python benchmarks/bench_frontend.py --duration 30
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from eurocslam.dataset import open_sequence
from eurocslam.dataset.synth import SynthSpec, synthesize
from eurocslam.dataset.types import StereoFrame
from eurocslam.eval.align import align
from eurocslam.eval.associate import associate
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.frontend import StereoFrontend
from eurocslam.frontend.types import TrackingState
from eurocslam.frontend.vo import VisualOdometry

REPO = Path(__file__).resolve().parents[1]
GT_DIR = REPO.parent / "shared/data/euroc/groundtruth"
SEQUENCES = [
    "MH_01_easy", "MH_02_easy", "MH_03_medium", "MH_04_difficult", "MH_05_difficult",
    "V1_01_easy", "V1_02_medium", "V1_03_difficult", "V2_01_easy", "V2_02_medium",
    "V2_03_difficult",
]  # fmt: skip
# GUIDE section 4: ORB-SLAM3 ATE RMSE [m] on the REAL sequences. GUIDE lists its
# stereo-inertial figures (not stereo-only); shown for scale only.
ORBSLAM3_STEREO_INERTIAL = {
    "MH_01_easy": 0.037, "MH_02_easy": 0.031, "MH_03_medium": 0.026, "MH_04_difficult": 0.059,
    "MH_05_difficult": 0.086, "V1_01_easy": 0.037, "V1_02_medium": 0.014,
    "V1_03_difficult": 0.023, "V2_01_easy": 0.037, "V2_02_medium": 0.014,
    "V2_03_difficult": 0.029,
}  # fmt: skip
STAGES = ["decode", "rectify", "orb", "stereo_matching", "tracking", "pnp", "local_ba"]


def gt_file(name: str) -> Path:
    for ext in (".csv", ".txt"):
        p = GT_DIR / f"{name}{ext}"
        if p.exists():
            return p
    raise SystemExit(f"{GT_DIR}: no ground truth for {name}")


def gt_duration_s(path: Path) -> float:
    t = np.loadtxt(path, delimiter="," if path.suffix == ".csv" else None, comments="#", usecols=0)
    scale = 1e-9 if path.suffix == ".csv" else 1.0
    return float((t[-1] - t[0]) * scale)


def replica(name: str, duration: float, cache: Path, workers: int | None) -> Path:
    out = cache / f"{name}_{duration:g}s"
    if (out / "mav0").is_dir():
        return out
    gt = gt_file(name)
    total = gt_duration_s(gt)
    d = min(duration, total)
    start = max(0.0, (total - d) / 2.0)
    t0 = time.perf_counter()
    synthesize(SynthSpec(trajectory=gt, start_s=start, end_s=start + d), out, workers=workers)
    print(
        f"  rendered {name}: {d:g} s from {start:.1f} s in {time.perf_counter() - t0:.0f} s",
        file=sys.stderr,
    )
    return out


def timed(frames: Iterator[StereoFrame], sink: list[float]) -> Iterator[StereoFrame]:
    while True:
        t0 = time.perf_counter()
        try:
            fr = next(frames)
        except StopIteration:
            return
        sink.append((time.perf_counter() - t0) * 1e3)
        yield fr


def speed(seq_path: Path, max_frames: int) -> dict[str, float]:
    seq = open_sequence(seq_path)
    t_end = int(seq.frame_times[min(max_frames, len(seq.frame_times)) - 1])
    out: dict[str, float] = {}
    # sequential, one thread: per-stage times
    fe = StereoFrontend(seq.rig, FrontendConfig(prefetch=False))
    decode: list[float] = []
    per: dict[str, list[float]] = {k: [] for k in STAGES}
    n = 0
    t0 = time.perf_counter()
    for fr in timed(iter(seq.frames(t_end_ns=t_end)), decode):
        res = fe.process(fr)
        for k in STAGES:
            if k in res.timings_ms:
                per[k].append(res.timings_ms[k])
        n += 1
    wall_seq = time.perf_counter() - t0
    per["decode"] = decode
    for k, v in per.items():
        if v:
            out[f"ms_{k}"] = statistics.median(v)
    out["fps_sequential"] = n / wall_seq
    # two-stage pipeline (decode + extraction one frame ahead in a worker thread)
    fe2 = StereoFrontend(seq.rig, FrontendConfig(prefetch=True))
    n2 = 0
    t0 = time.perf_counter()
    for _, ff in fe2.stream(seq.frames(t_end_ns=t_end)):
        fe2.track(ff)
        n2 += 1
    out["fps_pipelined"] = n2 / (time.perf_counter() - t0)
    out["frames"] = float(n)
    return out


def vo_ate(seq_path: Path, config: FrontendConfig) -> dict[str, object]:
    seq = open_sequence(seq_path)
    vo = VisualOdometry(seq.rig, config)
    t_ns, poses, states = [], [], Counter()
    t0 = time.perf_counter()
    for res, T in vo.run(seq.frames()):
        t_ns.append(res.t_ns)
        poses.append(T)
        states[res.state.value] += 1
    wall = time.perf_counter() - t0
    gt = seq.groundtruth
    if gt is None:
        raise SystemExit(f"{seq_path}: no ground truth")
    a = associate(gt.t_ns, np.array(t_ns, dtype=np.int64), max_diff_ns=10_000_000)
    p_ref = gt.p[a.idx_ref]
    P = np.array(poses)
    p_est = P[a.idx_est, :3, 3]
    al = align("se3", p_ref, p_est)
    err = np.linalg.norm(p_est @ al.R.T + al.t - p_ref, axis=1)
    path = float(np.linalg.norm(np.diff(p_ref, axis=0), axis=1).sum())
    return {
        "ate": float(np.sqrt(np.mean(err**2))),
        "max": float(err.max()),
        "frames": len(poses),
        "matched": a.matched,
        "ok": states.get(TrackingState.OK.value, 0) + states.get(TrackingState.INIT.value, 0),
        "lost": states.get(TrackingState.LOST.value, 0),
        "path": path,
        "fps": len(poses) / wall,
        "ba_ms": statistics.median(vo.ba_ms) if vo.ba_ms else float("nan"),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequences", nargs="+", default=SEQUENCES, metavar="NAME")
    ap.add_argument("--duration", type=float, default=30.0, help="replica length [s]")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eurocslam_bench_frontend"))
    ap.add_argument("--workers", type=int, default=None, help="render processes")
    ap.add_argument("--speed-seq", default=None, help="replica for the speed table (first)")
    ap.add_argument("--speed-frames", type=int, default=300)
    ap.add_argument("--compare-ba", action="store_true", help="also run with the local BA on")
    ap.add_argument("--skip-speed", action="store_true")
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    print(f"rendering/reusing replicas in {args.cache} ...", file=sys.stderr)
    paths = {n: replica(n, args.duration, args.cache, args.workers) for n in args.sequences}

    if not args.skip_speed:
        sname = args.speed_seq or args.sequences[0]
        sp = speed(paths[sname], args.speed_frames)
        print(f"\n## Frontend speed ({sname} replica, {int(sp['frames'])} frames, no BA)\n")
        print("| stage | ms / stereo frame (median) |\n|---|---|")
        for k in STAGES:
            if f"ms_{k}" in sp:
                print(f"| {k} | {sp[f'ms_{k}']:.2f} |")
        print(
            f"\nframes/s: sequential {sp['fps_sequential']:.1f}, "
            f"pipelined (2 threads) {sp['fps_pipelined']:.1f}"
        )

    print(f"\n## Visual odometry ATE on semi-real replicas ({args.duration:g} s, centred crop)\n")
    head = "| sequence | path [m] | frames | lost | VO ATE RMSE [m] | max [m] |"
    sep = "|---|---|---|---|---|---|"
    head += " VO frames/s |"
    sep += "---|"
    if args.compare_ba:
        head += " ATE with local BA [m] | BA ms |"
        sep += "---|---|"
    head += " ORB-SLAM3 stereo-inertial, real images [m] |"
    sep += "---|"
    rows = []
    for n in args.sequences:
        r = vo_ate(paths[n], FrontendConfig())
        row = (
            f"| {n} | {r['path']:.1f} | {r['frames']} | {r['lost']} | {r['ate']:.4f} | "
            f"{r['max']:.4f} |"
        )
        row += f" {r['fps']:.1f} |"
        if args.compare_ba:
            r2 = vo_ate(paths[n], FrontendConfig(ba_enabled=True))
            row += f" {r2['ate']:.4f} | {r2['ba_ms']:.0f} |"
        row += f" {ORBSLAM3_STEREO_INERTIAL[n]:.3f} |"
        rows.append(row)
        print(f"  {n}: ATE {r['ate']:.4f} m", file=sys.stderr)
    print(head)
    print(sep)
    for row in rows:
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
