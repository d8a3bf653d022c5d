"""Reading throughput: the same stereo frames from an EuRoC ASL folder, a ROS 1 bag, a ROS 2 bag
(sqlite3) and a ROS 2 MCAP, through `open_sequence` (what `run` and `convert` use).

The 95 real V1_01 micro stereo pairs are cycled to `--frames` pairs at 20 Hz (ASL: symlinks to
the real PNGs under new timestamps), with the real IMU rows re-stamped at 200 Hz over the same
span; the bags are written from that ASL folder with `write_rosbag` (untimed). Each reader runs
in its own process (so peak RSS is its own), `--repeat` times; the table shows medians.

    .venv/bin/python benchmarks/bench_read.py                # 1000 pairs, 3 repeats
    .venv/bin/python benchmarks/bench_read.py --frames 2000 --repeat 5

Columns: open = constructing the sequence (bags: one indexing pass over every message, IMU and
ground truth decoded); frames = iterating every stereo pair (images decoded to 8-bit mono);
pairs/s and images/s over open + frames; MB/s = input bytes / (open + frames).
The machine is shared and noisy: compare the rows of one run, not numbers across runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

REPO = Path(__file__).resolve().parents[1]
MICRO = (
    Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))
    / "V1_01_easy_micro"
)


def build_asl(root: Path, n_frames: int) -> Path:
    """An ASL folder of `n_frames` stereo pairs cycled from the micro sequence (symlinked PNGs)."""
    import numpy as np

    from eurocslam.dataset.asl import AslSequence

    src = AslSequence(MICRO)
    pairs = [e for e in src.entries if e.left is not None and e.right is not None]
    mav0 = root / "mav0"
    t0 = int(pairs[0].t_ns)
    times = [t0 + i * 50_000_000 for i in range(n_frames)]
    for cam in ("cam0", "cam1"):
        d = mav0 / cam / "data"
        d.mkdir(parents=True)
        shutil.copy(MICRO / "mav0" / cam / "sensor.yaml", mav0 / cam / "sensor.yaml")
        rows = ["#timestamp [ns],filename"]
        for i, t in enumerate(times):
            e = pairs[i % len(pairs)]
            target = e.left if cam == "cam0" else e.right
            assert target is not None
            (d / f"{t}.png").symlink_to(target.resolve())
            rows.append(f"{t},{t}.png")
        (mav0 / cam / "data.csv").write_text("\n".join(rows) + "\n")
    # real IMU values, re-stamped at 200 Hz over the frame span (+0.5 s each side)
    imu = src.imu
    t_imu = np.arange(times[0] - 500_000_000, times[-1] + 500_000_001, 5_000_000, dtype=np.int64)
    k = np.arange(t_imu.size) % len(imu)
    (mav0 / "imu0").mkdir(parents=True)
    shutil.copy(MICRO / "mav0" / "imu0" / "sensor.yaml", mav0 / "imu0" / "sensor.yaml")
    lines = ["#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z"]
    for t, g, a in zip(t_imu.tolist(), imu.gyro[k].tolist(), imu.accel[k].tolist(), strict=True):
        lines.append(f"{t},{g[0]!r},{g[1]!r},{g[2]!r},{a[0]!r},{a[1]!r},{a[2]!r}")
    (mav0 / "imu0" / "data.csv").write_text("\n".join(lines) + "\n")
    return root


def input_bytes(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    total = 0
    for p in path.rglob("*"):
        if p.is_file():
            total += p.resolve().stat().st_size  # PNG symlinks count as their targets
    return total


def worker(path: str) -> None:
    from eurocslam.dataset import open_sequence

    t0 = time.perf_counter()
    seq = open_sequence(path, quiet=True)
    t1 = time.perf_counter()
    n = 0
    for f in seq.frames():
        n += 1
        assert f.left is not None and f.right is not None
    t2 = time.perf_counter()
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"open": t1 - t0, "frames": t2 - t1, "n": n, "rss_mb": rss_mb}))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=1000, help="stereo pairs (default 1000)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per reader (median shown)")
    ap.add_argument("--keep", type=Path, default=None, help="write inputs here and keep them")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args.worker)
        return 0
    if not MICRO.exists():
        print(f"real EuRoC micro data not found at {MICRO}", file=sys.stderr)
        return 2

    from eurocslam.dataset.asl import AslSequence
    from eurocslam.dataset.bag.writer import write_rosbag

    tmp = args.keep or Path(tempfile.mkdtemp(prefix="bench_read_"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        print(f"building inputs: {args.frames} stereo pairs in {tmp}", file=sys.stderr)
        asl_root = build_asl(tmp / "asl", args.frames)
        asl = AslSequence(asl_root)
        src = SimpleNamespace(frames=asl.frames, imu=asl.imu, groundtruth=None, leica=None)
        inputs = {"ASL folder (PNG)": asl_root}
        for label, fmt, name in (
            ("ROS 1 bag", "ros1", "seq.bag"),
            ("ROS 2 bag (sqlite3)", "ros2-db3", "seq_db3"),
            ("ROS 2 MCAP", "ros2-mcap", "seq_mcap"),
        ):
            t = time.perf_counter()
            out = write_rosbag(src, tmp / name, fmt)
            print(f"  wrote {label} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
            inputs[label] = out if fmt == "ros1" else out / f"{name}.{fmt.split('-')[1]}"
        results: dict[str, list[dict[str, float]]] = {k: [] for k in inputs}
        for r in range(args.repeat):
            for label, path in inputs.items():  # interleaved, so noise hits every reader alike
                proc = subprocess.run(
                    [sys.executable, __file__, "--worker", str(path)],
                    capture_output=True, text=True, check=False,
                )  # fmt: skip
                if proc.returncode != 0:
                    print(proc.stderr, file=sys.stderr)
                    return 1
                results[label].append(json.loads(proc.stdout.strip().splitlines()[-1]))
            print(f"  run {r + 1}/{args.repeat} done", file=sys.stderr)

        def med(label: str, key: str) -> float:
            return statistics.median(x[key] for x in results[label])

        base = med("ASL folder (PNG)", "open") + med("ASL folder (PNG)", "frames")
        print(f"\nreading {args.frames} stereo pairs ({2 * args.frames} images 752x480 mono8), "
              f"median of {args.repeat}\n")  # fmt: skip
        hdr = (f"{'input':<22} {'MB':>7} {'open s':>7} {'frames s':>9} {'pairs/s':>8} "
               f"{'images/s':>9} {'MB/s':>7} {'vs ASL':>7} {'peak RSS MB':>12}")  # fmt: skip
        print(hdr)
        print("-" * len(hdr))
        for label, path in inputs.items():
            n = results[label][0]["n"]
            assert n == args.frames, f"{label}: {n} pairs read, expected {args.frames}"
            o, f = med(label, "open"), med(label, "frames")
            mb = input_bytes(path) / 1e6
            print(f"{label:<22} {mb:7.0f} {o:7.2f} {f:9.2f} {n / (o + f):8.1f} "
                  f"{2 * n / (o + f):9.1f} {mb / (o + f):7.0f} {base / (o + f):6.2f}x "
                  f"{med(label, 'rss_mb'):12.0f}")  # fmt: skip
    finally:
        if args.keep is None:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
