#!/usr/bin/env python3
"""Throughput and peak memory of `eurocslam convert` vs the tutorial's way, in one run.

The real V1_01 micro frames (95 stereo pairs) are cycled into a temporary ASL folder (symlinks,
under /tmp) with --pairs stereo pairs at 20 Hz and the real IMU cycled to the same span. Each
variant runs in its own subprocess; peak RSS is that child's `ru_maxrss` (os.wait4).

baseline = what the tutorial does: decode each PNG, serialise with mcap_ros2's default writer
(default zstd), one stream after another (all cam0, then all cam1, then the IMU).

usage: .venv/bin/python benchmarks/bench_convert.py [--pairs 1000] [--repeat 3]
       [--variants baseline,raw,...] [--rev NAME=REV ...] [--workers N]
Variants (--variants, default all): baseline, raw (the default: raw images, zstd), lz4, none,
png, jpeg, long (raw + zstd on twice the pairs). --rev NAME=REV adds the default settings at git
revision REV (a temporary worktree; `.` is the working tree), for A/B of code changes.
The machine is shared and noisy: variants run interleaved, round after round; "x baseline" is
the median over rounds of each round's ratio to that round's baseline.
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
from dataclasses import dataclass, field
from pathlib import Path

from bench_ab import checkout  # a temporary worktree of a revision

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


def child_ours(seq: Path, out: Path, images: str, compression: str, workers: int | None) -> dict:
    from eurocslam.convert import ConvertOptions, convert
    from eurocslam.dataset import open_sequence

    kw = {} if workers is None else {"workers": workers}
    res = convert(
        open_sequence(seq),
        out,
        ConvertOptions(images=images, compression=compression, progress=False, **kw),
    )
    return {
        "images": res.summary.topics[
            next(t for t in res.summary.topics if "cam0" in t and "image" in t)
        ].count
        * 2
    }


def run_child(variant: str, seq: Path, out: Path, src: Path | None = None) -> dict:
    """One conversion in its own process; `src`: the `src` folder of the code to run."""
    cmd = [sys.executable, __file__, "--child", variant, "--seq", str(seq), "--out", str(out)]
    env = None if src is None else dict(os.environ, PYTHONPATH=str(src))
    out.unlink(missing_ok=True)  # not timed: freeing the previous run's file is not conversion
    os.sync()  # nor is writing back the previous run's dirty pages
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env)
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


# short name -> (label, child spec, pairs factor)
VARIANTS = {
    "baseline": ("baseline (tutorial: mcap_ros2, zstd)", "baseline", 1),
    "raw": ("eurocslam raw, zstd (default)", "ours:raw:zstd", 1),
    "lz4": ("eurocslam raw, lz4", "ours:raw:lz4", 1),
    "none": ("eurocslam raw, none", "ours:raw:none", 1),
    "png": ("eurocslam png (lossless), zstd", "ours:png:zstd", 1),
    "jpeg": ("eurocslam jpeg, zstd", "ours:jpeg:zstd", 1),
    "long": ("eurocslam raw, zstd, 2x pairs", "ours:raw:zstd", 2),
}


@dataclass
class Variant:
    label: str
    spec: str
    factor: int
    src: Path | None = None  # None: this checkout's code
    runs: list[dict] = field(default_factory=list)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=1000, help="stereo pairs (2 images each)")
    ap.add_argument("--repeat", type=int, default=3, help="rounds (every variant once each)")
    ap.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help=f"comma-separated subset of {','.join(VARIANTS)} (default: all)",
    )
    ap.add_argument(
        "--rev",
        action="append",
        default=[],
        metavar="NAME=REV",
        help="also the default settings at git revision REV (repeatable)",
    )
    ap.add_argument("--workers", type=int, help="--workers of every eurocslam variant")
    ap.add_argument("--child")
    ap.add_argument("--seq", type=Path)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    if a.child:
        t = time.perf_counter()
        if a.child == "baseline":
            res = child_baseline(a.seq, a.out)
        else:
            _, images, comp, workers = [*a.child.split(":"), ""][:4]
            res = child_ours(a.seq, a.out, images, comp, int(workers) if workers else None)
        res["seconds"] = time.perf_counter() - t
        print(json.dumps(res))
        return 0
    if not MICRO.exists():
        print(f"real data not available: {MICRO}", file=sys.stderr)
        return 2
    names = [n.strip() for n in a.variants.split(",") if n.strip()]
    unknown = [n for n in names if n not in VARIANTS]
    if unknown or "baseline" not in names:
        raise SystemExit(
            f"--variants: unknown {unknown}; choose from {','.join(VARIANTS)} (with baseline)"
        )
    wsuffix = "" if a.workers is None else f":{a.workers}"
    variants = [
        Variant(
            VARIANTS[n][0], VARIANTS[n][1] + ("" if n == "baseline" else wsuffix), VARIANTS[n][2]
        )
        for n in names
    ]
    with tempfile.TemporaryDirectory(prefix="bench_convert_", dir="/tmp") as tmp:
        tmpd = Path(tmp)
        worktrees = []
        try:
            for text in a.rev:
                name, sep, rev = text.partition("=")
                if not sep or not name or not rev:
                    raise SystemExit(f"--rev {text!r}: expected NAME=REV")
                src = checkout(rev, tmpd / f"tree_{name}")
                if rev != ".":
                    worktrees.append(src.parent)
                variants.append(
                    Variant(
                        f"eurocslam raw, zstd @ {name} ({rev})", "ours:raw:zstd" + wsuffix, 1, src
                    )
                )
            run_rounds(a, variants, tmpd)
        finally:
            for w in worktrees:
                subprocess.run(
                    ["git", "-C", str(REPO), "worktree", "remove", "--force", str(w)],
                    capture_output=True,
                )
    report(a, variants)
    return 0


def run_rounds(a: argparse.Namespace, variants: list[Variant], tmpd: Path) -> None:
    seqs = {
        f: make_sequence(tmpd / f"seq{f * a.pairs}", f * a.pairs)
        for f in {v.factor for v in variants}
    }
    a.load = [os.getloadavg()[0]]
    for k in range(a.repeat):  # interleave variants so noise hits all of them alike
        for v in variants:
            r = run_child(v.spec, seqs[v.factor], tmpd / "out.mcap", v.src)
            v.runs.append(r)
            print(
                f"  round {k + 1}/{a.repeat} {v.label:<44} "
                f"{r['images'] / r['seconds']:7.1f} images/s"
                f"  CPU {r['cpu_s'] / r['images'] * 1e3:5.2f} ms/image  RSS {r['rss_mb']:4.0f} MB",
                file=sys.stderr,
                flush=True,
            )
        a.load.append(os.getloadavg()[0])


def report(a: argparse.Namespace, variants: list[Variant]) -> None:
    base = variants[0]
    print(
        f"\nconvert benchmark: {a.pairs} stereo pairs ({2 * a.pairs} images, 752x480) + "
        f"IMU, {a.repeat} rounds interleaved, medians; {os.cpu_count()} CPUs, load average "
        f"{min(a.load):.1f}-{max(a.load):.1f}\n"
    )
    print(
        f"| {'variant':<44} | images | images/s | MB/s (pixels) | x baseline (per round) | "
        "CPU ms/image | peak RSS MB | file MB |"
    )
    print(
        f"|{'-' * 46}|--------|----------|---------------|---|--------------|"
        "-------------|---------|"
    )
    img_mb = 752 * 480 / 1e6
    for v in variants:
        ips = [r["images"] / r["seconds"] for r in v.runs]
        ratios = [x / (b["images"] / b["seconds"]) for x, b in zip(ips, base.runs, strict=True)]
        cpu = statistics.median(r["cpu_s"] / r["images"] * 1e3 for r in v.runs)
        rss = max(r["rss_mb"] for r in v.runs)
        per = " ".join(f"{x:.2f}" for x in ratios)
        mips = statistics.median(ips)
        print(
            f"| {v.label:<44} | {v.runs[0]['images']:>6} | {mips:>8.1f} | {mips * img_mb:>13.1f} | "
            f"{statistics.median(ratios):.2f} ({per}) | {cpu:>12.2f} | {rss:>11.0f} | "
            f"{v.runs[0]['out_mb']:>7.0f} |"
        )
    print(
        "\nimages/s and CPU ms/image include interpreter start-up and imports (same for "
        "all variants); MB/s counts decoded pixels (752 x 480 bytes per image)."
    )


if __name__ == "__main__":
    sys.exit(main())
