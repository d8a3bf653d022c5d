#!/usr/bin/env python3
"""How long `eurocslam doctor` takes on a full-length sequence, default vs `--full`.

A temporary ASL folder spans the whole real V1_01 IMU (29,120 rows, 145.6 s at 200 Hz) and
ground truth (2,895 rows): cam0/cam1 list one stereo pair every 50 ms over that span (2,912 per
camera), each a symlink to one of the 95 real micro PNGs, cycled. That is what the doctor meets
on a real 145 s EuRoC sequence, except that the PNG bytes come from the page cache.

Rows: `open` = `AslSequence(...)` (the reader, what `run`/`convert` pay before the first frame);
`doctor` = default (every PNG header + IEND read, `--sample` images decoded per camera);
`doctor --full` = every image decoded (`--skip-full` leaves it out). Medians of `--repeat` runs;
the machine is shared and noisy: compare rows of one run.

    .venv/bin/python benchmarks/bench_doctor.py [--repeat 3] [--skip-full]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MICRO = (
    Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))
    / "V1_01_easy_micro"
)


def make_sequence(dst: Path) -> tuple[Path, int]:
    src = MICRO / "mav0"
    mav0 = dst / "mav0"
    imu_lines = (src / "imu0" / "data.csv").read_text().splitlines()
    t_imu = [int(ln.split(",", 1)[0]) for ln in imu_lines if not ln.startswith("#")]
    names = sorted(p.name for p in (src / "cam1" / "data").glob("*.png"))
    n = (t_imu[-1] - t_imu[0]) // 50_000_000 + 1
    for cam in ("cam0", "cam1"):
        (mav0 / cam / "data").mkdir(parents=True)
        (mav0 / cam / "sensor.yaml").symlink_to(src / cam / "sensor.yaml")
        rows = ["#timestamp [ns],filename"]
        for k in range(n):
            t = t_imu[0] + 50_000_000 * k
            (mav0 / cam / "data" / f"{t}.png").symlink_to(src / cam / "data" / names[k % 95])
            rows.append(f"{t},{t}.png")
        (mav0 / cam / "data.csv").write_text("\n".join(rows) + "\n")
    for s in ("imu0", "state_groundtruth_estimate0"):
        (mav0 / s).mkdir()
        for f in ("sensor.yaml", "data.csv"):
            (mav0 / s / f).symlink_to(src / s / f)
    return dst, n


def timed(fn: object, repeat: int) -> float:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()  # type: ignore[operator]
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sample", type=int, default=24)
    ap.add_argument("--skip-full", action="store_true", help="do not time --full")
    args = ap.parse_args()
    if not MICRO.exists():
        print(f"real data not found: {MICRO}", file=sys.stderr)
        return 2
    from eurocslam.dataset.asl import AslSequence
    from eurocslam.dataset.doctor.asl_checks import diagnose

    with tempfile.TemporaryDirectory(prefix="bench_doctor_") as tmp:
        seq, n = make_sequence(Path(tmp) / "V1_01_long")
        report = diagnose(seq, sample=args.sample)  # warm the page cache; show the verdict
        print(f"sequence: {n} stereo pairs, 29,120 IMU rows, 2,895 ground-truth rows")
        print(f"doctor verdict: exit {report.exit_code}, {report.errors} errors, "
              f"{report.warnings} warnings")  # fmt: skip
        rows = [
            ("open (reader)", timed(lambda: AslSequence(seq), args.repeat), 0),
            (
                f"doctor (headers + {args.sample}/camera decoded)",
                timed(lambda: diagnose(seq, sample=args.sample), args.repeat),
                2 * min(n, args.sample),
            ),
        ]
        if not args.skip_full:
            rows.append(
                ("doctor --full (all decoded)", timed(lambda: diagnose(seq, full=True), 1), 2 * n)
            )
        print(f"\n| {'what':<38} | {'time [s]':>9} | {'images decoded':>14} |")
        print(f"|{'-' * 40}|{'-' * 11}|{'-' * 16}|")
        for name, t, dec in rows:
            print(f"| {name:<38} | {t:>9.3f} | {dec:>14} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
