"""CDR encoding (little-endian XCDR1, what ROS 2 uses): a growing-buffer writer, ROS time stamps
and 4x4 poses as ROS position + quaternion.

Every message starts with the 4-byte encapsulation header `CDR_LE_HEADER`; alignment is relative
to its end. Times are int64 nanoseconds, split into ROS (sec, nanosec).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from eurocslam.geometry import F64, rot_to_quat_wxyz, wxyz_to_xyzw
from eurocslam.timebase import NS_PER_S

CDR_LE_HEADER = b"\x00\x01\x00\x00"
_I32 = struct.Struct("<i")
_U32 = struct.Struct("<I")
_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
_TIME = struct.Struct("<iI")


def stamp_bytes(t_ns: int) -> bytes:
    """The CDR bytes of a `builtin_interfaces/Time` (sec, nanosec), 4-aligned in a message."""
    return _TIME.pack(*split_ns(t_ns))


def split_ns(t_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a ROS time from int64 nanoseconds."""
    t = int(t_ns)
    return t // NS_PER_S, t % NS_PER_S


class CdrWriter:
    """Little-endian XCDR1 (what ROS 2 uses) into a growing buffer. Alignment is relative to the
    end of the 4-byte encapsulation header."""

    __slots__ = ("buf",)

    def __init__(self) -> None:
        self.buf = bytearray(CDR_LE_HEADER)

    def align(self, n: int) -> None:
        pad = -(len(self.buf) - 4) % n
        if pad:
            self.buf += b"\x00" * pad

    def u8(self, v: int) -> None:
        self.buf.append(v & 0xFF)

    def bool(self, v: bool) -> None:
        self.buf.append(1 if v else 0)

    def i32(self, v: int) -> None:
        self.align(4)
        self.buf += _I32.pack(v)

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += _U32.pack(v)

    def f32(self, v: float) -> None:
        self.align(4)
        self.buf += _F32.pack(v)

    def f64(self, v: float) -> None:
        self.align(8)
        self.buf += _F64.pack(v)

    def f64_fixed(self, values: ArrayLike, n: int) -> None:
        """A fixed-size float64[n] array (no length prefix)."""
        a = np.ascontiguousarray(values, dtype="<f8").reshape(-1)
        if a.size != n:
            raise ValueError(f"expected {n} float64 values, got {a.size}")
        self.align(8)
        self.buf += a.tobytes()

    def f64_seq(self, values: ArrayLike) -> None:
        a = np.ascontiguousarray(values, dtype="<f8").reshape(-1)
        self.u32(a.size)
        if a.size:
            self.align(8)
            self.buf += a.tobytes()

    def bytes_seq(self, data: bytes | bytearray | memoryview) -> None:
        self.u32(len(data))
        self.buf += data

    def string(self, s: str) -> None:
        b = s.encode()
        self.u32(len(b) + 1)
        self.buf += b
        self.buf.append(0)

    def time(self, t_ns: int) -> None:
        self.align(4)
        self.buf += _TIME.pack(*split_ns(t_ns))

    def header(self, t_ns: int, frame_id: str) -> None:
        self.time(t_ns)
        self.string(frame_id)

    def xyz(self, v: ArrayLike) -> None:
        self.f64_fixed(v, 3)

    def pose(self, T: F64) -> None:
        """geometry_msgs/Pose from a 4x4 transform: position then quaternion xyzw."""
        self.f64_fixed(pose7(T), 7)

    def color(self, rgba: Sequence[float]) -> None:
        self.align(4)
        self.buf += struct.pack("<4f", *rgba)

    def getvalue(self) -> bytes:
        return bytes(self.buf)


def pose7(T: ArrayLike) -> F64:
    """[x, y, z, qx, qy, qz, qw] of a 4x4 transform (quaternion with w >= 0)."""
    T = np.asarray(T, dtype=np.float64)
    q = wxyz_to_xyzw(rot_to_quat_wxyz(T[:3, :3]))
    return np.concatenate([T[:3, 3], q])


def poses7(T: ArrayLike) -> F64:
    """(N, 7) [x, y, z, qx, qy, qz, qw] of (N, 4, 4) transforms (vectorised)."""
    T = np.asarray(T, dtype=np.float64)
    q = wxyz_to_xyzw(rot_to_quat_wxyz(T[:, :3, :3]))
    return np.concatenate([T[:, :3, 3], q], axis=1)
