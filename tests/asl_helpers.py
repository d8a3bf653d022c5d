"""Build small, clean, editable copies of the real EuRoC folders for reader/doctor tests.

`clean_v101_copy` makes a copy of `V1_01_easy_micro` that the doctor passes with no warning:
the 95 real stereo pairs (images symlinked, so corrupting one means replacing its link), the
real sensor.yaml files, cam1/data.csv without the 4 rows whose images do not exist, and the real
IMU and ground truth cropped to the image window plus a margin (keeps every test fast). All
values are the real ones; nothing is invented.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

MARGIN_NS = 500_000_000  # IMU / ground truth kept this far around the images


def read_lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def write_lines(path: Path, lines: list[str], eol: str = "\n") -> None:
    path.write_bytes((eol.join(lines) + eol).encode())


def _crop_csv(src: Path, dst: Path, t0: int, t1: int) -> None:
    lines = read_lines(src)
    t = np.array([int(ln[:19]) if ln[:1] != "#" else -1 for ln in lines], dtype=np.int64)
    keep = (t == -1) | ((t >= t0) & (t <= t1))
    write_lines(dst, [ln for ln, k in zip(lines, keep, strict=True) if k])


def clean_v101_copy(v101_micro: Path, dst: Path, max_frames: int | None = None) -> Path:
    """Copy of V1_01_easy_micro at `dst` (the sequence folder), keeping the first `max_frames`
    stereo pairs (all 95 by default); returns `dst / 'mav0'`."""
    src = v101_micro / "mav0"
    mav0 = dst / "mav0"
    mav0.mkdir(parents=True)
    shutil.copy(src / "body.yaml", mav0 / "body.yaml")
    times: list[int] = []
    for cam in ("cam0", "cam1"):
        (mav0 / cam / "data").mkdir(parents=True)
        shutil.copy(src / cam / "sensor.yaml", mav0 / cam / "sensor.yaml")
        present = {p.name for p in (src / cam / "data").iterdir()}
        rows = []
        for ln in read_lines(src / cam / "data.csv"):
            if ln.startswith("#"):
                rows.append(ln)
                continue
            name = ln.split(",")[1].strip()
            if name in present and (max_frames is None or len(rows) <= max_frames):
                rows.append(ln)
                (mav0 / cam / "data" / name).symlink_to(src / cam / "data" / name)
                times.append(int(ln.split(",")[0]))
        write_lines(mav0 / cam / "data.csv", rows)
    t0, t1 = min(times) - MARGIN_NS, max(times) + MARGIN_NS
    for s in ("imu0", "state_groundtruth_estimate0"):
        (mav0 / s).mkdir()
        shutil.copy(src / s / "sensor.yaml", mav0 / s / "sensor.yaml")
        _crop_csv(src / s / "data.csv", mav0 / s / "data.csv", t0, t1)
    return mav0


def image_names(mav0: Path, cam: str) -> list[str]:
    return [ln.split(",")[1] for ln in read_lines(mav0 / cam / "data.csv") if ln[:1] != "#"]


def materialise(path: Path) -> Path:
    """Replace a symlinked image by a real copy (so it can be modified)."""
    if path.is_symlink():
        data = path.read_bytes()
        path.unlink()
        path.write_bytes(data)
    return path


def data_rows(path: Path) -> list[str]:
    return [ln for ln in read_lines(path) if ln and not ln.startswith("#")]


def imu_times(mav0: Path) -> np.ndarray:
    return np.array([int(r.split(",")[0]) for r in data_rows(mav0 / "imu0" / "data.csv")])
