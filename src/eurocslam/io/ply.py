"""PLY point clouds (binary little-endian): the sparse map of a run (`OUT/map.ply`).

Vertices carry `x y z` (float32) and optionally `red green blue` (uchar) and a `segment` (int)
property, readable by MeshLab, CloudCompare and Open3D.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from eurocslam.errors import OutputError


def ply_bytes(
    xyz: ArrayLike, rgb: ArrayLike | None = None, segment: ArrayLike | None = None
) -> bytes:
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    if not np.all(np.isfinite(p)):
        raise OutputError("point cloud holds non-finite coordinates")
    cols: list[tuple[str, str]] = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    props = ["property float x", "property float y", "property float z"]
    if rgb is not None:
        cols += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    if segment is not None:
        cols.append(("segment", "<i4"))
        props.append("property int segment")
    arr = np.zeros(n, dtype=np.dtype(cols))
    arr["x"], arr["y"], arr["z"] = p[:, 0], p[:, 1], p[:, 2]
    if rgb is not None:
        c = np.asarray(rgb, dtype=np.uint8).reshape(n, 3)
        arr["red"], arr["green"], arr["blue"] = c[:, 0], c[:, 1], c[:, 2]
    if segment is not None:
        arr["segment"] = np.asarray(segment, dtype=np.int32).reshape(n)
    header = (
        "\n".join(
            [
                "ply",
                "format binary_little_endian 1.0",
                "comment eurocslam sparse map",
                f"element vertex {n}",
                *props,
                "end_header",
            ]
        )
        + "\n"
    )
    return header.encode("ascii") + arr.tobytes()


def write_ply(
    path: Path | str,
    xyz: ArrayLike,
    rgb: ArrayLike | None = None,
    segment: ArrayLike | None = None,
) -> None:
    """Write a binary PLY atomically (`path.partial`, then rename)."""
    path = Path(path)
    data = ply_bytes(xyz, rgb, segment)
    tmp = path.with_name(path.name + ".partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as e:
        raise OutputError(f"{path}: cannot write: {e}") from None


def read_ply(path: Path | str) -> dict[str, np.ndarray]:
    """Read a binary little-endian PLY written by `write_ply` (vertex properties by name)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise OutputError(f"{path}: cannot read: {e}") from None
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise OutputError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise OutputError(f"{path}: only binary little-endian PLY is supported")
    n = 0
    cols: list[tuple[str, str]] = []
    kinds = {"float": "<f4", "uchar": "u1", "int": "<i4", "double": "<f8"}
    for ln in header:
        parts = ln.split()
        if parts[:2] == ["element", "vertex"]:
            n = int(parts[2])
        elif parts and parts[0] == "property" and parts[1] in kinds:
            cols.append((parts[2], kinds[parts[1]]))
    arr = np.frombuffer(data, dtype=np.dtype(cols), count=n, offset=end + len("end_header\n"))
    return {name: arr[name].copy() for name, _ in cols}
