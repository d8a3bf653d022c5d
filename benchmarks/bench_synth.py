"""Synthetic sequence benchmark: rendering speed and realism against real EuRoC frames.

    .venv/bin/python benchmarks/bench_synth.py               # speed + realism (a few minutes)
    .venv/bin/python benchmarks/bench_synth.py --replica 180 # also a real 180 s replica

Tables:
1. ms per stereo pair on one core (CPU time and wall time, medians over the frames): radiance
   only, and the full frame (sensor effects + both PNGs written).
2. A short sequence written with 1 and 2 worker processes (wall time per pair, speed-up), and
   the time a 180 s replica (3,600 pairs) would take, extrapolated; with --replica S, one real
   measurement of an S-second replica of MH_01_easy.
3. Realism: FAST corners, ORB keypoints and stereo matches per frame on real V1_01 frames (from
   ../shared/data/euroc) and on rendered frames, with the same detector and matcher.

The machine may be shared: compare ratios within one run, read medians.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from eurocslam.synth import Scene, SynthSpec, synthesize
from eurocslam.synth.sequence import PNG_PARAMS

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))


def per_pair_times(scene: Scene, frames: list[int]) -> dict[str, tuple[float, float]]:
    """Median (cpu ms, wall ms) per stereo pair: radiance only, and full frame + PNG."""
    cv2.setNumThreads(1)
    rad_cpu, rad_wall, full_cpu, full_wall = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in frames:
            c0, w0 = time.process_time(), time.perf_counter()
            scene.radiance(k, 0)
            scene.radiance(k, 1)
            rad_cpu.append(time.process_time() - c0)
            rad_wall.append(time.perf_counter() - w0)
            c0, w0 = time.process_time(), time.perf_counter()
            for cam in (0, 1):
                img, _ = scene.image(k, cam)
                cv2.imwrite(f"{tmp}/{cam}.png", img, PNG_PARAMS)
            full_cpu.append(time.process_time() - c0)
            full_wall.append(time.perf_counter() - w0)
    med = statistics.median
    return {
        "radiance (both cameras)": (1e3 * med(rad_cpu), 1e3 * med(rad_wall)),
        "full frame + 2 PNGs": (1e3 * med(full_cpu), 1e3 * med(full_wall)),
    }


def timed_synth(spec: SynthSpec, workers: int) -> tuple[float, float, int]:
    """(total wall s, render wall s, pairs) for writing `spec` with `workers` processes."""
    import json

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        out = synthesize(spec, Path(tmp) / "seq", progress=False, workers=workers)
        total = time.perf_counter() - t0
        s = json.loads((out / "synth.json").read_text())
    return total, s["render_wall_s"], s["frames"]


def fast_corners(img: np.ndarray) -> int:
    """FAST corners (threshold 20) at full resolution: how much fine detail an image has."""
    return len(cv2.FastFeatureDetector_create(20).detect(img))


def orb_stats(left: np.ndarray, right: np.ndarray, rig) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    """(ORB keypoints in left, stereo matches left-right passing the rectified epipolar check)."""
    orb = cv2.ORB_create(nfeatures=2000)
    k0, d0 = orb.detectAndCompute(left, None)
    k1, d1 = orb.detectAndCompute(right, None)
    if d0 is None or d1 is None:
        return len(k0), 0
    R1, R2, P1, P2, *_ = cv2.stereoRectify(
        rig.cam0.K,
        rig.cam0.D,
        rig.cam1.K,
        rig.cam1.D,
        (752, 480),
        rig.T_cam1_cam0[:3, :3],
        rig.T_cam1_cam0[:3, 3].reshape(3, 1),
        alpha=0,
    )
    p0 = cv2.undistortPoints(
        np.float32([k.pt for k in k0]).reshape(-1, 1, 2), rig.cam0.K, rig.cam0.D, R=R1, P=P1
    ).reshape(-1, 2)
    p1 = cv2.undistortPoints(
        np.float32([k.pt for k in k1]).reshape(-1, 1, 2), rig.cam1.K, rig.cam1.D, R=R2, P=P2
    ).reshape(-1, 2)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d0, d1)
    good = 0
    for m in matches:
        a, b = p0[m.queryIdx], p1[m.trainIdx]
        disp = a[0] - b[0]
        if abs(a[1] - b[1]) < 2.0 and 0.0 < disp < 200.0 and m.distance < 50:
            good += 1
    return len(k0), good


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="frames for the per-pair timing")
    ap.add_argument("--seconds", type=float, default=10.0, help="length of the worker test")
    ap.add_argument(
        "--replica",
        type=float,
        default=0.0,
        metavar="S",
        help="also write an S-second replica of MH_01_easy (e.g. 180)",
    )
    args = ap.parse_args()

    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    t0 = time.perf_counter()
    scene = Scene.build(SynthSpec(duration_s=30.0, seed=0))
    print(
        f"scene build (30 s built-in flight): {time.perf_counter() - t0:.1f} s, "
        f"{scene.world.describe()}\n"
    )
    n = scene.cam_t_ns.size
    frames = list(np.linspace(0, n - 1, args.frames).astype(int))
    times = per_pair_times(scene, frames)
    print("## ms per stereo pair, one core (median)\n")
    print("| stage | CPU ms | wall ms |\n|---|---|---|")
    for k, (c, w) in times.items():
        print(f"| {k} | {c:.1f} | {w:.1f} |")

    print(f"\n## writing a {args.seconds:g} s sequence ({int(args.seconds * 20) + 1} pairs)\n")
    print(
        "| workers | total s | render s | wall ms / pair | 180 s replica (3,600 pairs), "
        "extrapolated |\n|---|---|---|---|---|"
    )
    spec = SynthSpec(duration_s=args.seconds, seed=1)
    base = None
    for w in (1, 2):
        total, render, pairs = timed_synth(spec, w)
        per = render / pairs
        setup = total - render
        if base is None:
            base = per
        print(
            f"| {w} | {total:.1f} | {render:.1f} | {1e3 * per:.1f} (x{base / per:.2f}) | "
            f"{(3600 * per + setup) / 60:.1f} min |"
        )

    if args.replica > 0:
        gt = SHARED / "groundtruth" / "MH_01_easy.txt"
        if not gt.exists():
            print(f"\n(replica skipped: {gt} not found)")
        else:
            spec = SynthSpec(trajectory=gt, duration_s=args.replica, seed=0)
            total, render, pairs = timed_synth(spec, 2)
            print(f"\n## measured: {args.replica:g} s replica of MH_01_easy, 2 workers\n")
            print("| pairs | total s | render s | wall ms / pair |\n|---|---|---|---|")
            print(f"| {pairs} | {total:.1f} | {render:.1f} | {1e3 * render / pairs:.1f} |")

    real = SHARED / "V1_01_easy_micro" / "mav0"
    print("\n## realism per frame (medians)\n")
    print("FAST-20: corners at full resolution; ORB: nfeatures 2000; matches: rectified stereo\n")
    print("| images | frames | FAST-20 | ORB keypoints | stereo matches |\n|---|---|---|---|---|")
    rows = []
    if real.exists():
        names = sorted((real / "cam0" / "data").glob("*.png"))[::10]
        kp, mt, fc = [], [], []
        for p in names:
            right = real / "cam1" / "data" / p.name
            if not right.exists():
                continue
            left_img = cv2.imread(str(p), 0)
            a, b = orb_stats(left_img, cv2.imread(str(right), 0), scene.rig)
            kp.append(a)
            mt.append(b)
            fc.append(fast_corners(left_img))
        rows.append(("real V1_01 (drone on the floor)", kp, mt, fc))
    for label, sc in (
        ("synthetic, default realism", scene),
        ("synthetic, --ideal", Scene.build(SynthSpec(duration_s=30.0).ideal())),
    ):
        kp, mt, fc = [], [], []
        for k in frames[::3]:
            left_img = sc.image(k, 0)[0]
            a, b = orb_stats(left_img, sc.image(k, 1)[0], sc.rig)
            kp.append(a)
            mt.append(b)
            fc.append(fast_corners(left_img))
        rows.append((label, kp, mt, fc))
    med = statistics.median
    for label, kp, mt, fc in rows:
        print(f"| {label} | {len(kp)} | {med(fc):.0f} | {med(kp):.0f} | {med(mt):.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
