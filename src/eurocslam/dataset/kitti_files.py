"""The text files of a KITTI odometry sequence: `calib.txt`, `times.txt` and the ground truth
`poses/NN.txt`. Each parser raises a one-line `DatasetError` naming the file and row at fault.

* `calib.txt`: rows `NAME: v1 .. v12`; `P0:` and `P1:` are the 3x4 projections of the rectified
  grey cameras (image_0, image_1). Other rows (P2, P3, Tr, ...) are ignored.
* `times.txt`: one time in seconds per frame (`0.000000e+00`), converted to int64 nanoseconds
  exactly (decimal, no float rounding), strictly increasing.
* `poses/NN.txt`: one 3x4 row-major `T_world_cam0` per frame (12 numbers per line), one line per
  row of `times.txt`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.dataset.types import I64
from eurocslam.errors import DatasetError
from eurocslam.geometry import F64
from eurocslam.textfile import read_text
from eurocslam.timebase import ns_to_seconds_str, seconds_str_to_ns

CALIB = "calib.txt"
TIMES = "times.txt"
IMAGE_DIRS = ("image_0", "image_1")
ROTATION_TOL = 1e-2  # |R^T R - I| above this: not a rotation (6-decimal files reach ~1e-6)


def _numbers(tokens: list[str], where: str) -> list[float]:
    out = []
    for tok in tokens:
        try:
            v = float(tok)
        except ValueError:
            raise DatasetError(f"{where}: non-numeric value '{tok}'") from None
        if not np.isfinite(v):
            raise DatasetError(f"{where}: non-finite value '{tok}'")
        out.append(v)
    return out


@dataclass(frozen=True)
class KittiCalib:
    """The rectified grey pair of `calib.txt`: the 3x4 projections and the rows they came from."""

    path: Path
    P0: F64
    P1: F64
    row_P0: int
    row_P1: int

    @property
    def baseline(self) -> float:
        """cam1's offset along x from cam0 [m]: `-P1[0,3]/P1[0,0]` (P0 carries no offset)."""
        return float(self.t_cam0_cam1[0])

    @property
    def t_cam0_cam1(self) -> F64:
        """cam1's origin in cam0 (both rectified, same orientation). `P = K [I | t]` puts a
        camera's origin at `-t` in the reference frame; KITTI's grey pair has `t = (-b, 0, 0)`
        for cam1 and 0 for cam0, so this is `(b, 0, 0)` with `b = -P1[0,3]/P1[0,0]` exactly."""
        return _offset(self.P0) - _offset(self.P1)


def _offset(P: F64) -> F64:
    """`t` of `P = K [I | t]` (exactly `P[0,3]/P[0,0]` along x when the other terms are 0)."""
    if P[1, 3] == 0.0 and P[2, 3] == 0.0:
        return np.array([P[0, 3] / P[0, 0], 0.0, 0.0])
    return np.asarray(np.linalg.solve(P[:, :3], P[:, 3]), dtype=np.float64)


def read_calib(path: Path) -> KittiCalib:
    """`P0` and `P1` of a KITTI `calib.txt` (see the module docstring)."""
    text = read_text(path, DatasetError)
    rows: dict[str, tuple[int, F64]] = {}
    for no, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        name, colon, rest = line.partition(":")
        name = name.strip()
        if not colon or not name or " " in name:
            raise DatasetError(f"{path}:{no}: expected 'NAME: 12 numbers', got '{line.strip()}'")
        if name not in ("P0", "P1"):
            continue  # P2, P3 (colour cameras), Tr (velodyne): not used
        where = f"{path}:{no} ({name})"
        if name in rows:
            raise DatasetError(f"{where}: a second '{name}:' row (first on row {rows[name][0]})")
        vals = _numbers(rest.split(), where)
        if len(vals) != 12:
            raise DatasetError(f"{where}: expected 12 numbers (3x4 row-major), found {len(vals)}")
        P = np.array(vals, dtype=np.float64).reshape(3, 4)
        if P[0, 0] <= 0 or P[1, 1] <= 0:
            raise DatasetError(
                f"{where}: focal lengths P[0,0] = {P[0, 0]:g}, P[1,1] = {P[1, 1]:g} "
                "must be positive"
            )
        if P[1, 0] != 0 or P[2, 0] != 0 or P[2, 1] != 0 or P[2, 2] != 1:
            raise DatasetError(
                f"{where}: not a rectified pinhole projection (expected K [I | t] with K upper "
                f"triangular and K[2,2] = 1, got rows {P[1].tolist()}, {P[2].tolist()})"
            )
        rows[name] = (no, P)
    for name, what in (("P0", "left (image_0)"), ("P1", "right (image_1)")):
        if name not in rows:
            raise DatasetError(
                f"{path}: no '{name}:' row (the {what} camera's 3x4 projection matrix)"
            )
    calib = KittiCalib(path, rows["P0"][1], rows["P1"][1], rows["P0"][0], rows["P1"][0])
    if not calib.baseline > 0:
        raise DatasetError(
            f"{path}:{calib.row_P1} (P1): baseline -P1[0,3]/P1[0,0] = {calib.baseline:g} m; "
            "image_1 must be the right camera (a positive baseline)"
        )
    return calib


def read_times(path: Path) -> tuple[I64, I64]:
    """Frame times [ns] of `times.txt` (exact decimal conversion) and their 1-based line
    numbers. Every row one time in seconds, not negative, each after the previous one."""
    text = read_text(path, DatasetError)
    t: list[int] = []
    lines: list[int] = []
    for no, line in enumerate(text.splitlines(), start=1):
        tok = line.strip()
        if not tok:
            continue
        if len(tok.split()) != 1:
            raise DatasetError(f"{path}:{no}: expected one time in seconds, got '{tok}'")
        try:
            ns = seconds_str_to_ns(tok)
        except ValueError:
            raise DatasetError(f"{path}:{no}: '{tok}' is not a time in seconds") from None
        if ns < 0:
            raise DatasetError(f"{path}:{no}: negative time '{tok}'")
        if t and ns <= t[-1]:
            raise DatasetError(
                f"{path}:{no}: time {ns_to_seconds_str(ns)} s is not after the previous row's "
                f"{ns_to_seconds_str(t[-1])} s (times must increase)"
            )
        t.append(ns)
        lines.append(no)
    if not t:
        raise DatasetError(f"{path}: no rows (one time in seconds per frame)")
    return np.array(t, dtype=np.int64), np.array(lines, dtype=np.int64)


def read_poses(path: Path, n_expected: int | None = None, times_path: Path | None = None) -> F64:
    """(N, 4, 4) `T_world_cam0` of a KITTI poses file; with `n_expected` the row count must
    match (`times_path` is named in that error)."""
    text = read_text(path, DatasetError)
    rows: list[list[float]] = []
    nos: list[int] = []
    for no, line in enumerate(text.splitlines(), start=1):
        toks = line.split()
        if not toks:
            continue
        where = f"{path}:{no}"
        vals = _numbers(toks, where)
        if len(vals) != 12:
            raise DatasetError(
                f"{where}: expected 12 numbers (3x4 row-major T_world_cam0), found {len(vals)}"
            )
        rows.append(vals)
        nos.append(no)
    if not rows:
        raise DatasetError(f"{path}: no rows (one 3x4 pose per frame)")
    if n_expected is not None and len(rows) != n_expected:
        other = times_path if times_path is not None else TIMES
        raise DatasetError(
            f"{path}: {len(rows)} pose rows but {other} has {n_expected} rows (one pose per frame)"
        )
    T = np.zeros((len(rows), 4, 4))
    T[:, :3, :] = np.array(rows, dtype=np.float64).reshape(-1, 3, 4)
    T[:, 3, 3] = 1.0
    R = T[:, :3, :3]
    dev = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((dev > ROTATION_TOL) | (det <= 0))
    if bad.size:
        i = int(bad[0])
        raise DatasetError(
            f"{path}:{nos[i]}: the 3x3 part is not a rotation (|R^T R - I| = {dev[i]:.2g}, "
            f"det {det[i]:.3g})"
        )
    return T


def poses_path_of(seq_dir: Path) -> Path:
    """Where KITTI keeps a sequence's ground truth: `sequences/NN` -> `poses/NN.txt`."""
    return seq_dir.parent.parent / "poses" / f"{seq_dir.name}.txt"


def times_paths_for_poses(poses: Path) -> tuple[Path, Path]:
    """Where the times of a poses file may be: `poses/NN.txt` -> `sequences/NN/times.txt`
    beside `poses/`, or a `times.txt` in the poses file's own folder."""
    stem = poses.name.rsplit(".", 1)[0]
    return poses.parent.parent / "sequences" / stem / TIMES, poses.parent / TIMES


def frame_image_name(index: int) -> str:
    """KITTI's image name of frame `index`: `000017.png`."""
    return f"{index:06d}.png"


def is_kitti_sequence(path: Path) -> bool:
    """A folder laid out as a KITTI odometry sequence (`image_0/`, `calib.txt` or `times.txt`,
    and no `mav0/` or `cam0/` of an ASL folder)."""
    if not path.is_dir() or (path / "mav0").exists() or (path / "cam0").exists():
        return False
    return (path / IMAGE_DIRS[0]).is_dir() or (path / CALIB).is_file() or (path / TIMES).is_file()


def is_kitti_root(path: Path) -> bool:
    """A KITTI odometry dataset root (`sequences/NN/...`), not one sequence."""
    seqs = path / "sequences"
    return seqs.is_dir() and any(is_kitti_sequence(p) for p in seqs.iterdir())


def looks_like_kitti_poses(path: Path) -> bool:
    """A text file whose first non-blank line holds 12 numbers (a KITTI poses file)."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as f:
            for line in f:
                toks = line.split()
                if not toks:
                    continue
                if len(toks) != 12:
                    return False
                try:
                    [float(t) for t in toks]
                except ValueError:
                    return False
                return True
    except OSError:
        return False
    return False
