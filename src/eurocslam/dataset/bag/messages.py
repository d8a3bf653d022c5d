"""Decoding bag messages: header stamps and numbers straight from the serialized bytes, and camera
images to 8-bit mono."""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.types import U8
from eurocslam.errors import DatasetError
from eurocslam.timebase import stamp_ns

_LE_TIME = struct.Struct("<iI")
_BE_TIME = struct.Struct(">iI")
_ROS1_TIME = struct.Struct("<II")


def header_stamp_ns(raw: bytes | memoryview, ros2: bool) -> int:
    """`header.stamp` of a serialized message whose first field is a `std_msgs/Header`.

    ROS 1: uint32 seq, uint32 sec, uint32 nsec. ROS 2 CDR: 4-byte encapsulation header
    (byte 1 odd = little endian), then int32 sec, uint32 nanosec.
    """
    if ros2:
        st = _LE_TIME if raw[1] & 1 else _BE_TIME
        sec, nsec = st.unpack_from(raw, 4)
    else:
        sec, nsec = _ROS1_TIME.unpack_from(raw, 4)
    return stamp_ns(sec, nsec)


def stamp_of(msg: Any) -> int:
    """`header.stamp` of a decoded message, in nanoseconds."""
    st = msg.header.stamp
    return stamp_ns(st.sec, st.nanosec)


SUPPORTED_ENCODINGS = {
    "mono8": 1, "8uc1": 1, "mono16": 2, "16uc1": 2,
    "bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4,
}  # fmt: skip
_TO_GRAY = {
    "bgr8": cv2.COLOR_BGR2GRAY,
    "rgb8": cv2.COLOR_RGB2GRAY,
    "bgra8": cv2.COLOR_BGRA2GRAY,
    "rgba8": cv2.COLOR_RGBA2GRAY,
}


def check_encoding(encoding: str, topic: str) -> None:
    if encoding.lower() not in SUPPORTED_ENCODINGS:
        raise DatasetError(
            f"{topic}: image encoding '{encoding}' is not supported (supported: mono8, mono16, "
            "bgr8, rgb8, bgra8, rgba8, 8UC1, 16UC1)"
        )


def image_msg_to_mono(msg: Any, topic: str) -> U8 | None:
    """8-bit mono image from a `sensor_msgs/Image` (colour converted, 16-bit scaled by 1/256).

    None when the data is shorter than `step * height` (caller counts the skip); an unsupported
    encoding raises `DatasetError` naming topic and encoding.
    """
    enc = str(msg.encoding).lower()
    check_encoding(str(msg.encoding), topic)
    bpp = SUPPORTED_ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h <= 0 or w <= 0 or step < w * bpp or data.size < step * h:
        return None
    rows = data[: step * h].reshape(h, step)[:, : w * bpp]
    if bpp == 1:
        return np.array(rows, dtype=np.uint8, copy=True)
    if bpp == 2:
        dt = np.dtype(">u2" if msg.is_bigendian else "<u2")
        img16 = np.ascontiguousarray(rows).view(dt).reshape(h, w)
        return (img16 >> 8).astype(np.uint8)
    color = np.ascontiguousarray(rows).reshape(h, w, bpp)
    return np.asarray(cv2.cvtColor(color, _TO_GRAY[enc]), dtype=np.uint8)


def compressed_msg_to_mono(msg: Any) -> U8 | None:
    """8-bit mono image from a `sensor_msgs/CompressedImage` (png/jpeg); None if undecodable."""
    buf = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if buf.size == 0:
        return None
    img: NDArray[Any] | None = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    if img.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = np.asarray(cv2.cvtColor(img, code))
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    return np.asarray(img, dtype=np.uint8)


def message_values(msg: Any, msgtype: str) -> tuple[float, ...]:
    """Numbers of a decoded message: Imu -> (wx, wy, wz, ax, ay, az); poses -> (x, y, z, qx, qy,
    qz, qw) from PoseStamped, TransformStamped, Odometry, PoseWithCovarianceStamped;
    PointStamped -> (x, y, z)."""
    if msgtype == "sensor_msgs/msg/Imu":
        w, a = msg.angular_velocity, msg.linear_acceleration
        return (w.x, w.y, w.z, a.x, a.y, a.z)
    if msgtype == "geometry_msgs/msg/PointStamped":
        return (msg.point.x, msg.point.y, msg.point.z)
    if hasattr(msg, "transform"):
        t, q = msg.transform.translation, msg.transform.rotation
    else:
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        t, q = pose.position, pose.orientation
    return (t.x, t.y, t.z, q.x, q.y, q.z, q.w)


# Raw layouts: (strings after header.frame_id, leading float64 fields to read, indices kept).
# Imu: orientation 4, orientation_covariance 9, angular_velocity 3 (13..15), its covariance 9,
# linear_acceleration 3 (25..27).
_FAST_LAYOUTS: dict[str, tuple[int, int, tuple[int, ...]]] = {
    "sensor_msgs/msg/Imu": (0, 28, (13, 14, 15, 25, 26, 27)),
    "geometry_msgs/msg/PoseStamped": (0, 7, tuple(range(7))),
    "geometry_msgs/msg/PoseWithCovarianceStamped": (0, 7, tuple(range(7))),
    "geometry_msgs/msg/TransformStamped": (1, 7, tuple(range(7))),
    "nav_msgs/msg/Odometry": (1, 7, tuple(range(7))),
    "geometry_msgs/msg/PointStamped": (0, 3, (0, 1, 2)),
}


def fast_values(raw: bytes | memoryview, ros2: bool, msgtype: str) -> tuple[int, tuple[float, ...]]:
    """`message_values` and the header stamp straight from the serialized bytes (ROS 1 or plain
    CDR), 3-5x faster than a full decode (measured: 5-9 us vs 17-42 us per Imu message).
    Callers verify it against the full decoder."""
    extra, n, keep = _FAST_LAYOUTS[msgtype]
    if ros2:
        if raw[0] != 0 or raw[1] > 1:
            raise struct.error("not plain CDR")
        e = "<" if raw[1] & 1 else ">"
    else:
        e = "<"
    stamp = header_stamp_ns(raw, ros2)
    pos = 12
    for _ in range(1 + extra):
        if ros2:
            pos = 4 + ((pos - 4 + 3) & ~3)
        (length,) = struct.unpack_from(e + "I", raw, pos)
        pos += 4 + length
    if ros2:
        pos = 4 + ((pos - 4 + 7) & ~7)
    vals = struct.unpack_from(f"{e}{n}d", raw, pos)
    return stamp, tuple(vals[i] for i in keep)
