#!/usr/bin/env python3
"""Throughput and peak memory of `eurocslam convert` vs the tutorial's way, in one run.

The real V1_01 micro frames (95 stereo pairs) are cycled into a temporary ASL folder (symlinks,
under /tmp) with --pairs stereo pairs at 20 Hz and the real IMU cycled to the same span. Each
variant runs in its own subprocess; peak RSS is that child's `ru_maxrss` (os.wait4).

baseline = what the tutorial does: decode each PNG, serialise with mcap_ros2's default writer
(default zstd), one stream after another (all cam0, then all cam1, then the IMU).

usage: .venv/bin/python benchmarks/bench_convert.py [--pairs 1000] [--repeat 3]
The machine is shared and noisy: compare ratios within one run; the table shows medians.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MICRO = (
    Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))
    / "V1_01_easy_micro"
)


def make_sequence(dst: Path, pairs: int) -> Path:
    """ASL folder with `pairs` stereo pairs cycled from the micro sequence (symlinked PNGs)."""
    src = MICRO / "mav0"
    mav0 = dst / "mav0"
    names = sorted(p.name for p in (src / "cam1" / "data").glob("*.png"))
    t0 = 1_403_715_273_262_142_976
    for cam in ("cam0", "cam1"):
        d = mav0 / cam / "data"
        d.mkdir(parents=True)
        shutil.copy(src / cam / "sensor.yaml", mav0 / cam / "sensor.yaml")
        rows = ["#timestamp [ns],filename"]
        for k in range(pairs):
            t = t0 + k * 50_000_000
            (d / f"{t}.png").symlink_to(src / cam / "data" / names[k % len(names)])
            rows.append(f"{t},{t}.png")
        (mav0 / cam / "data.csv").write_text("\n".join(rows) + "\n")
    (mav0 / "imu0").mkdir(parents=True)
    shutil.copy(src / "imu0" / "sensor.yaml", mav0 / "imu0" / "sensor.yaml")
    lines = [ln for ln in (src / "imu0" / "data.csv").read_text().splitlines() if ln.strip()]
    header, body = lines[0], lines[1:]
    n_imu = pairs * 10  # 200 Hz over the image span
    out = [header]
    for k in range(n_imu):
        vals = body[k % len(body)].split(",")[1:]
        out.append(",".join([str(t0 + k * 5_000_000), *vals]))
    (mav0 / "imu0" / "data.csv").write_text("\n".join(out) + "\n")
    return dst


# ---- children ---------------------------------------------------------------------------------
def child_baseline(seq: Path, out: Path) -> dict:
    import cv2
    from mcap_ros2.writer import Writer

    from eurocslam.io import ros2

    mav0 = seq / "mav0"
    n_img = 0
    with out.open("wb") as f:
        w = Writer(f)  # defaults: zstd chunk compression
        img_schema = w.register_msgdef(ros2.IMAGE, ros2.schema_text(ros2.IMAGE))
        imu_schema = w.register_msgdef(ros2.IMU, ros2.schema_text(ros2.IMU))
        for cam in ("cam0", "cam1"):
            for ln in (mav0 / cam / "data.csv").read_text().splitlines()[1:]:
                t_s, name = ln.split(",")
                t = int(t_s)
                img = cv2.imread(str(mav0 / cam / "data" / name), cv2.IMREAD_UNCHANGED)
                msg = {
                    "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": cam},
                    "height": img.shape[0],
                    "width": img.shape[1],
                    "encoding": "mono8",
                    "is_bigendian": 0,
                    "step": img.shape[1],
                    "data": img.tobytes(),
                }
                w.write_message(f"/{cam}/image_raw", img_schema, msg, log_time=t, publish_time=t)
                n_img += 1
        for ln in (mav0 / "imu0" / "data.csv").read_text().splitlines()[1:]:
            v = ln.split(",")
            t = int(v[0])
            g = [float(x) for x in v[1:4]]
            a = [float(x) for x in v[4:7]]
            msg = {
                "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "imu0"},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                "orientation_covariance": [-1.0] + [0.0] * 8,
                "angular_velocity": {"x": g[0], "y": g[1], "z": g[2]},
                "angular_velocity_covariance": [0.0] * 9,
                "linear_acceleration": {"x": a[0], "y": a[1], "z": a[2]},
                "linear_acceleration_covariance": [0.0] * 9,
            }
            w.write_message("/imu0", imu_schema, msg, log_time=t, publish_time=t)
        w.finish()
    return {"images": n_img}


def child_ours(seq: Path, out: Path, images: str, compression: str) -> dict:
    from eurocslam.convert import ConvertOptions, convert
    from eurocslam.dataset import open_sequence

    res = convert(
        open_sequence(seq),
        out,
        ConvertOptions(images=images, compression=compression, progress=False),
    )
    return {
        "images": res.summary.topics[
            next(t for t in res.summary.topics if "cam0" in t and "image" in t)
        ].count
        * 2
    }


def run_child(variant: str, seq: Path, out: Path) -> dict:
    cmd = [sys.executable, __file__, "--child", variant, "--seq", str(seq), "--out", str(out)]
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    stdout = p.stdout.read() if p.stdout else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{variant} failed")
    res = json.loads(stdout.strip().splitlines()[-1])
    res.update(
        wall_s=wall,
        cpu_s=ru.ru_utime + ru.ru_stime,
        rss_mb=ru.ru_maxrss / 1024,
        out_mb=out.stat().st_size / 1e6,
    )
    return res


VARIANTS = {
    "baseline (tutorial: mcap_ros2, zstd)": "baseline",
    "eurocslam raw, zstd": "ours:raw:zstd",
    "eurocslam raw, lz4": "ours:raw:lz4",
    "eurocslam raw, none": "ours:raw:none",
    "eurocslam png (lossless), zstd": "ours:png:zstd",
    "eurocslam jpeg, zstd": "ours:jpeg:zstd",
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=1000, help="stereo pairs (2 images each)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--child")
    ap.add_argument("--seq", type=Path)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    if a.child:
        t = time.perf_counter()
        if a.child == "baseline":
            res = child_baseline(a.seq, a.out)
        else:
            _, images, comp = a.child.split(":")
            res = child_ours(a.seq, a.out, images, comp)
        res["seconds"] = time.perf_counter() - t
        print(json.dumps(res))
        return 0
    if not MICRO.exists():
        print(f"real data not available: {MICRO}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="bench_convert_", dir="/tmp") as tmp:
        tmpd = Path(tmp)
        seqs = {
            a.pairs: make_sequence(tmpd / f"seq{a.pairs}", a.pairs),
            2 * a.pairs: make_sequence(tmpd / f"seq{2 * a.pairs}", 2 * a.pairs),
        }
        img_mb = 752 * 480 / 1e6
        results: dict[str, list[dict]] = {k: [] for k in VARIANTS}
        results[f"eurocslam raw, zstd, {2 * a.pairs} pairs"] = []
        for _ in range(a.repeat):  # interleave variants so noise hits all of them alike
            for label, v in VARIANTS.items():
                results[label].append(run_child(v, seqs[a.pairs], tmpd / "out.mcap"))
            results[f"eurocslam raw, zstd, {2 * a.pairs} pairs"].append(
                run_child("ours:raw:zstd", seqs[2 * a.pairs], tmpd / "out.mcap")
            )
        base = statistics.median(r["images"] / r["seconds"] for r in results[next(iter(VARIANTS))])
        print(
            f"\nconvert benchmark: {a.pairs} stereo pairs ({2 * a.pairs} images, 752x480) + "
            f"IMU, median of {a.repeat}, {os.cpu_count()} CPUs\n"
        )
        print(
            f"| {'variant':<38} | images | images/s | MB/s (pixels) | x baseline | "
            "CPU ms/image | peak RSS MB | file MB |"
        )
        print(
            f"|{'-' * 40}|--------|----------|---------------|------------|--------------|"
            "-------------|---------|"
        )
        for label, rs in results.items():
            ips = statistics.median(r["images"] / r["seconds"] for r in rs)
            cpu = statistics.median(r["cpu_s"] / r["images"] * 1e3 for r in rs)
            rss = max(r["rss_mb"] for r in rs)
            print(
                f"| {label:<38} | {rs[0]['images']:>6} | {ips:>8.1f} | {ips * img_mb:>13.1f} | "
                f"{ips / base:>10.2f} | {cpu:>12.2f} | {rss:>11.0f} | {rs[0]['out_mb']:>7.0f} |"
            )
        print(
            "\nimages/s and CPU ms/image include interpreter start-up and imports (same for "
            "all variants); MB/s counts decoded pixels (752 x 480 bytes per image)."
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
