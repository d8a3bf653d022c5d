"""Small synthetic KITTI odometry folders for reader/doctor/convert/eval tests, and a converter of
a KITTI sequence into a stereo-only ASL folder (sensor.yaml pinhole without distortion, data.csv
with the KITTI times in ns, images hard-linked or copied)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import cv2
import numpy as np

from eurocslam.geometry import make_T, so3_exp

FX, CX, CY = 130.0, 80.5, 60.25
WIDTH, HEIGHT = 160, 120
BASELINE = 0.5
# the 12 numbers of each calib.txt row, written as KITTI writes them
P0 = [FX, 0.0, CX, 0.0, 0.0, FX, CY, 0.0, 0.0, 0.0, 1.0, 0.0]
P1 = [FX, 0.0, CX, -FX * BASELINE, 0.0, FX, CY, 0.0, 0.0, 0.0, 1.0, 0.0]


def kitti_row(name: str, values: list[float]) -> str:
    return f"{name}: " + " ".join(f"{v:.12e}" for v in values)


def gt_poses(n: int) -> np.ndarray:
    """(n, 4, 4) `T_world_cam0`: forward along z on a curve, turning about y, starting at I."""
    out = []
    for i in range(n):
        R = so3_exp(np.array([0.0, 0.02 * i, 0.0]))
        out.append(make_T(R, np.array([0.04 * i * i, 0.1 * np.sin(i), 1.0 * i])))
    return np.array(out)


def write_image(path: Path, rng: np.random.Generator, colour: bool = False) -> None:
    img = rng.integers(0, 256, size=(HEIGHT // 4, WIDTH // 4), dtype=np.uint8)
    img = cv2.resize(img, (WIDTH, HEIGHT), interpolation=cv2.INTER_LINEAR)
    if colour:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    assert cv2.imwrite(str(path), img)


def make_kitti(root: Path, n: int = 6, name: str = "00", poses: bool = True, seed: int = 0) -> Path:
    """A KITTI odometry dataset at `root` with one sequence `name` of `n` frames at 10 Hz;
    returns the sequence folder `root/sequences/name`."""
    rng = np.random.default_rng(seed)
    seq = root / "sequences" / name
    for d in ("image_0", "image_1"):
        (seq / d).mkdir(parents=True)
        for i in range(n):
            write_image(seq / d / f"{i:06d}.png", rng)
    calib = [
        kitti_row("P0", P0),
        kitti_row("P1", P1),
        kitti_row("P2", [FX, 0, CX, 46.0, 0, FX, CY, -0.3, 0, 0, 1, 0.004]),
        kitti_row("P3", [FX, 0, CX, -333.0, 0, FX, CY, 1.9, 0, 0, 1, 0.003]),
        kitti_row("Tr", [0.0] * 12),
    ]
    (seq / "calib.txt").write_text("\n".join(calib) + "\n")
    (seq / "times.txt").write_text("".join(f"{0.1 * i:.6e}\n" for i in range(n)))
    if poses:
        (root / "poses").mkdir()
        rows = [" ".join(f"{v:.9e}" for v in T[:3].ravel()) for T in gt_poses(n)]
        (root / "poses" / f"{name}.txt").write_text("\n".join(rows) + "\n")
    return seq


def _camera_yaml(T_BS: np.ndarray, rate_hz: float, size: tuple[int, int], intr: list[float]) -> str:
    data = ", ".join(repr(float(v)) for v in T_BS.ravel())
    return (
        "%YAML:1.0\nsensor_type: camera\ncomment: stereo-only test camera\n"
        f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{data}]\n"
        f"rate_hz: {rate_hz!r}\nresolution: [{size[0]}, {size[1]}]\ncamera_model: pinhole\n"
        f"intrinsics: [{', '.join(repr(float(v)) for v in intr)}]\n"
        "distortion_model: radial-tangential\ndistortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )


def kitti_to_asl(seq: Path, dst: Path) -> Path:
    """A stereo-only ASL folder (no imu0/) at `dst` holding KITTI sequence `seq`: the same
    images (hard-linked, copied across file systems), the KITTI times in ns, and cam0/cam1
    sensor.yaml (pinhole, no distortion) from calib.txt's P0/P1. Returns `dst`."""
    from eurocslam.dataset.kitti_files import read_calib, read_times

    calib = read_calib(seq / "calib.txt")
    t_ns, _ = read_times(seq / "times.txt")
    first = cv2.imread(str(seq / "image_0" / "000000.png"), cv2.IMREAD_UNCHANGED)
    size = (int(first.shape[1]), int(first.shape[0]))
    rate = 1e9 / float(np.median(np.diff(t_ns)))
    b = -calib.P1[0, 3] / calib.P1[0, 0]
    for k, cam in enumerate(("cam0", "cam1")):
        P = calib.P0 if k == 0 else calib.P1
        data = dst / "mav0" / cam / "data"
        data.mkdir(parents=True)
        T_BS = np.eye(4)
        T_BS[0, 3] = b if k == 1 else 0.0
        intr = [P[0, 0], P[1, 1], P[0, 2], P[1, 2]]
        (data.parent / "sensor.yaml").write_text(_camera_yaml(T_BS, rate, size, intr))
        rows = ["#timestamp [ns],filename"]
        for i, t in enumerate(t_ns.tolist()):
            src = seq / f"image_{k}" / f"{i:06d}.png"
            try:
                os.link(src, data / f"{t}.png")
            except OSError:
                shutil.copy(src, data / f"{t}.png")
            rows.append(f"{t},{t}.png")
        (data.parent / "data.csv").write_text("\n".join(rows) + "\n")
    return dst
