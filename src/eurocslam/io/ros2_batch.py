"""ROS 2 messages of high-rate streams (IMU, ground truth) built in vectorised batches.

N messages of one fixed layout (same frame ids) are rows of one numpy structured array, so a
batch costs one `tobytes`. Each function returns the same bytes as N calls of its one-message
builder in `io.ros2` (`imu`, `pose_stamped`, `tf_message`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from eurocslam.geometry import F64
from eurocslam.io.cdr import CDR_LE_HEADER
from eurocslam.timebase import NS_PER_S


def _header_fields(frame_id: str, start: int) -> tuple[list[tuple[str, str]], int]:
    """dtype fields of a Header (stamp + frame_id) starting at CDR offset `start` (a multiple of
    4, relative to the end of the encapsulation header); returns the fields and the end offset."""
    fid = frame_id.encode() + b"\x00"
    fields = [("sec", "<i4"), ("nsec", "<u4"), ("flen", "<u4"), ("fid", f"S{len(fid)}")]
    return fields, start + 12 + len(fid)


def _pad(fields: list[tuple[str, str]], off: int, align: int, name: str) -> int:
    pad = -off % align
    if pad:
        fields.append((name, f"V{pad}"))
    return off + pad


def _split(rows: np.ndarray) -> list[bytes]:
    buf = rows.tobytes()
    n = rows.dtype.itemsize
    return [buf[i : i + n] for i in range(0, len(buf), n)]


def _fill_header(rows: np.ndarray, t_ns: NDArray[np.int64], frame_id: str) -> None:
    rows["encap"] = CDR_LE_HEADER
    rows["sec"] = t_ns // NS_PER_S
    rows["nsec"] = t_ns % NS_PER_S
    rows["flen"] = len(frame_id.encode()) + 1
    rows["fid"] = frame_id.encode()


def imu_batch(
    t_ns: ArrayLike,
    frame_id: str,
    gyro: ArrayLike,
    accel: ArrayLike,
    gyro_cov: F64,
    accel_cov: F64,
) -> list[bytes]:
    """`imu(...)` for N samples at once (vectorised; identical bytes)."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    fields, off = _header_fields(frame_id, 0)
    fields = [("encap", "S4"), *fields]
    _pad(fields, off, 8, "pad")
    fields.append(("v", "<f8", (37,)))  # type: ignore[arg-type]
    rows = np.zeros(t.size, dtype=np.dtype(fields))
    _fill_header(rows, t, frame_id)
    v = np.zeros((t.size, 37))
    v[:, 3] = 1.0  # orientation w
    v[:, 4] = -1.0  # orientation_covariance[0]: no orientation
    v[:, 13:16] = np.asarray(gyro, dtype=np.float64).reshape(-1, 3)
    v[:, 16:25] = np.asarray(gyro_cov, dtype=np.float64).reshape(9)
    v[:, 25:28] = np.asarray(accel, dtype=np.float64).reshape(-1, 3)
    v[:, 28:37] = np.asarray(accel_cov, dtype=np.float64).reshape(9)
    rows["v"] = v
    return _split(rows)


def pose_stamped_batch(t_ns: ArrayLike, frame_id: str, poses7: ArrayLike) -> list[bytes]:
    """`pose_stamped` for N poses given as (N, 7) [x y z qx qy qz qw] (vectorised)."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    fields, off = _header_fields(frame_id, 0)
    fields = [("encap", "S4"), *fields]
    _pad(fields, off, 8, "pad")
    fields.append(("pose", "<f8", (7,)))  # type: ignore[arg-type]
    rows = np.zeros(t.size, dtype=np.dtype(fields))
    _fill_header(rows, t, frame_id)
    rows["pose"] = np.asarray(poses7, dtype=np.float64).reshape(-1, 7)
    return _split(rows)


def tf_batch(t_ns: ArrayLike, parent: str, child: str, poses7: ArrayLike) -> list[bytes]:
    """N TFMessages, each holding one transform parent -> child given as a (N, 7) row
    [x y z qx qy qz qw] (vectorised; e.g. a ground-truth pose stream on /tf)."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    hdr, off = _header_fields(parent, 4)
    fields = [("encap", "S4"), ("count", "<u4"), *hdr]
    off = _pad(fields, off, 4, "pad0")
    cid = child.encode() + b"\x00"
    fields += [("clen", "<u4"), ("cid", f"S{len(cid)}")]
    off += 4 + len(cid)
    _pad(fields, off, 8, "pad1")
    fields.append(("pose", "<f8", (7,)))  # type: ignore[arg-type]
    rows = np.zeros(t.size, dtype=np.dtype(fields))
    _fill_header(rows, t, parent)
    rows["count"] = 1
    rows["clen"] = len(cid)
    rows["cid"] = child.encode()
    rows["pose"] = np.asarray(poses7, dtype=np.float64).reshape(-1, 7)
    return _split(rows)
