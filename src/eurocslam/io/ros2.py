"""ROS 2 (humble) messages without a ROS install: type names, exact schema texts, builders.

Every builder returns the message already CDR-encoded (`bytes`, little-endian, with the 4-byte
encapsulation header; see `io.cdr`), so any sink (MCAP file, live view, tee) forwards the same
bytes and the encoding cost is paid once. Builders take int64 nanosecond stamps and `T_a_b` 4x4
poses. Vectorised builders of high-rate streams are in `io.ros2_batch`, the calibration messages
(CameraInfo, IMU covariances) in `io.ros2_calib`.

Schema texts (`schema_text(msgtype)`) come from rosbags' bundled humble definitions: the root
definition first, then each dependency after a line of 80 `=` and `MSG: pkg/Name`, spelled exactly
as the fields spell it (what rosbag2 and foxglove_bridge write; Foxglove rejects anything else).

Types (canonical names, as used for MCAP schema names):

| builder | msgtype |
|---|---|
| `image` | sensor_msgs/msg/Image (mono8, or rgb8/bgr8 for HxWx3) |
| `compressed_image` | sensor_msgs/msg/CompressedImage (png / jpeg) |
| `ros2_calib.camera_info` (+ `stereo_camera_infos(rig, alpha)`) | sensor_msgs/msg/CameraInfo |
| `imu` (+ `ros2_calib.imu_covariances(calib)`) | sensor_msgs/msg/Imu |
| `tf_message(transforms)` with `Transform` | tf2_msgs/msg/TFMessage |
| `pose_stamped` | geometry_msgs/msg/PoseStamped |
| `path` | nav_msgs/msg/Path |
| `point_stamped` | geometry_msgs/msg/PointStamped |
| `point_cloud2` | sensor_msgs/msg/PointCloud2 (xyz float32 + optional rgb / intensity) |
| `marker`, `marker_array` with `Marker` | visualization_msgs/msg/Marker(Array) |
| `image_marker` | visualization_msgs/msg/ImageMarker (drawn on Foxglove's Image panel) |
| `float64_multi_array` | std_msgs/msg/Float64MultiArray (plot `/topic.data[i]`) |
| `float64` | std_msgs/msg/Float64 (plot `/topic.data`) |
| `string` | std_msgs/msg/String (e.g. tracking state for a StateTransitions panel) |
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from eurocslam.geometry import F64
from eurocslam.io.cdr import CDR_LE_HEADER, NS_PER_SEC, CdrWriter, pose7, poses7, split_ns

# message type names (MCAP schema names)
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
MARKER = "visualization_msgs/msg/Marker"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
IMAGE_MARKER = "visualization_msgs/msg/ImageMarker"
FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
FLOAT64 = "std_msgs/msg/Float64"
STRING = "std_msgs/msg/String"


@functools.cache
def _typestore():  # type: ignore[no-untyped-def]
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


@functools.cache
def schema_text(msgtype: str) -> str:
    """The `ros2msg` schema text of `msgtype` (e.g. 'sensor_msgs/msg/Image'), root first."""
    text, _ = _typestore().generate_msgdef(msgtype, ros_version=2)
    return text


# ---- sensor_msgs ------------------------------------------------------------------------------
_IMAGE_ENCODINGS = {1: "mono8", 3: "bgr8", 4: "bgra8"}


def image(t_ns: int, frame_id: str, img: NDArray[np.uint8], encoding: str | None = None) -> bytes:
    """sensor_msgs/Image from an 8-bit HxW (mono8) or HxWxC (bgr8/bgra8 by default) array."""
    img = np.ascontiguousarray(img)
    if img.dtype != np.uint8 or img.ndim not in (2, 3):
        raise ValueError(f"image must be uint8 HxW or HxWxC, got {img.dtype} {img.shape}")
    h, w = img.shape[:2]
    c = 1 if img.ndim == 2 else img.shape[2]
    enc = encoding or _IMAGE_ENCODINGS.get(c)
    if enc is None:
        raise ValueError(f"no default encoding for {c} channels")
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.u32(h)
    out.u32(w)
    out.string(enc)
    out.u8(0)  # is_bigendian
    out.u32(w * c)  # step
    out.u32(img.nbytes)  # data: uint8[] length, then the pixels
    return b"".join((out.buf, memoryview(img).cast("B")))  # type: ignore[arg-type]  # 1 copy


def compressed_image(t_ns: int, frame_id: str, fmt: str, data: bytes) -> bytes:
    """sensor_msgs/CompressedImage; `fmt` is 'png' or 'jpeg' (what Foxglove looks for)."""
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.string(fmt)
    out.bytes_seq(data)
    return out.getvalue()


@functools.cache
def _imu_struct(frame_id: str) -> tuple[struct.Struct, int]:
    fid = frame_id.encode() + b"\x00"
    # after encapsulation: sec, nanosec (8), strlen (4), string, pad to 8, then 37 doubles
    off = 8 + 4 + len(fid)
    pad = -off % 8
    fmt = f"<4siII{len(fid)}s{pad}x37d"
    return struct.Struct(fmt), len(fid)


def imu(
    t_ns: int, frame_id: str, gyro: ArrayLike, accel: ArrayLike, gyro_cov: F64, accel_cov: F64
) -> bytes:
    """sensor_msgs/Imu without orientation (orientation_covariance[0] = -1)."""
    st, _ = _imu_struct(frame_id)
    sec, nsec = split_ns(t_ns)
    g = np.asarray(gyro, dtype=np.float64)
    a = np.asarray(accel, dtype=np.float64)
    gc = np.asarray(gyro_cov, dtype=np.float64).reshape(9)
    ac = np.asarray(accel_cov, dtype=np.float64).reshape(9)
    return st.pack(
        CDR_LE_HEADER,
        sec,
        nsec,
        len(frame_id.encode()) + 1,
        frame_id.encode() + b"\x00",
        0.0,
        0.0,
        0.0,
        1.0,
        -1.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        g[0],
        g[1],
        g[2],
        *gc,
        a[0],
        a[1],
        a[2],
        *ac,
    )


def point_cloud2(
    t_ns: int,
    frame_id: str,
    xyz: ArrayLike,
    rgb: NDArray[np.uint8] | None = None,
    intensity: ArrayLike | None = None,
) -> bytes:
    """Unorganised sensor_msgs/PointCloud2: x, y, z float32, plus optional `rgb` (N, 3) uint8
    packed as a float32 'rgb' field (0x00RRGGBB, the PCL convention Foxglove reads) and an
    optional float32 `intensity`."""
    p = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    n = p.shape[0]
    names = [("x", 0), ("y", 4), ("z", 8)]
    cols = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if rgb is not None:
        names.append(("rgb", 12))
        cols.append(("rgb", "<u4"))
    if intensity is not None:
        names.append(("intensity", 4 * len(names)))
        cols.append(("intensity", "<f4"))
    arr = np.zeros(n, dtype=np.dtype(cols))
    arr["x"], arr["y"], arr["z"] = p[:, 0], p[:, 1], p[:, 2]
    if rgb is not None:
        c = np.asarray(rgb, dtype=np.uint32).reshape(n, 3)
        arr["rgb"] = (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
    if intensity is not None:
        arr["intensity"] = np.asarray(intensity, dtype=np.float32).reshape(n)
    step = arr.dtype.itemsize
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.u32(1)  # height
    out.u32(n)  # width
    out.u32(len(names))
    for name, offset in names:
        out.string(name)
        out.u32(offset)
        out.u8(7)  # FLOAT32 (rgb is read as float32-packed bytes, PCL style)
        out.u32(1)
    out.bool(False)  # is_bigendian
    out.u32(step)
    out.u32(step * n)
    out.bytes_seq(arr.tobytes())
    out.bool(True)  # is_dense
    return out.getvalue()


# ---- geometry / tf / nav ------------------------------------------------------------------------
@dataclass(frozen=True)
class Transform:
    """One geometry_msgs/TransformStamped: `T_parent_child` maps child-frame points to parent."""

    t_ns: int
    parent: str
    child: str
    T_parent_child: F64


def tf_message(transforms: Sequence[Transform]) -> bytes:
    """tf2_msgs/TFMessage (for /tf and /tf_static)."""
    out = CdrWriter()
    out.u32(len(transforms))
    for tr in transforms:
        out.header(tr.t_ns, tr.parent)
        out.string(tr.child)
        out.f64_fixed(pose7(tr.T_parent_child), 7)  # Transform: translation (3), rotation (4)
    return out.getvalue()


def pose_stamped(t_ns: int, frame_id: str, T: F64) -> bytes:
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.pose(T)
    return out.getvalue()


def path(t_ns: int, frame_id: str, stamps_ns: ArrayLike, poses: ArrayLike) -> bytes:
    """nav_msgs/Path; `poses` is (N, 4, 4) transforms or (N, 7) [x y z qx qy qz qw].
    Vectorised: every PoseStamped after the first starts 8-aligned, so they share one layout."""
    st = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim == 3:
        p = poses7(p) if len(p) else np.zeros((0, 7))
    if p.shape != (st.size, 7):
        raise ValueError(f"path: {st.size} stamps but poses of shape {p.shape}")
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.u32(st.size)
    if st.size == 0:
        return out.getvalue()
    out.header(int(st[0]), frame_id)
    out.f64_fixed(p[0], 7)
    if st.size > 1:
        fid = frame_id.encode() + b"\x00"
        pad = -(12 + len(fid)) % 8
        dt = np.dtype(
            [("sec", "<i4"), ("nsec", "<u4"), ("len", "<u4"), ("fid", f"S{len(fid)}")]
            + ([("pad", f"V{pad}")] if pad else [])
            + [("pose", "<f8", (7,))]
        )
        rows = np.zeros(st.size - 1, dtype=dt)
        rows["sec"] = st[1:] // NS_PER_SEC
        rows["nsec"] = st[1:] % NS_PER_SEC
        rows["len"] = len(fid)
        rows["fid"] = fid
        rows["pose"] = p[1:]
        out.buf += rows.tobytes()
    return out.getvalue()


def point_stamped(t_ns: int, frame_id: str, p: ArrayLike) -> bytes:
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.xyz(p)
    return out.getvalue()


# ---- visualization ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Marker:
    """visualization_msgs/Marker fields that matter for drawing (texture and mesh are unused).

    `type`: 0 ARROW, 1 CUBE, 2 SPHERE, 3 CYLINDER, 4 LINE_STRIP, 5 LINE_LIST, 6 CUBE_LIST,
    7 SPHERE_LIST, 8 POINTS, 9 TEXT_VIEW_FACING, 10 MESH_RESOURCE, 11 TRIANGLE_LIST.
    `action`: 0 ADD/MODIFY, 2 DELETE, 3 DELETEALL."""

    t_ns: int
    frame_id: str
    ns: str
    id: int
    type: int
    pose: F64 = field(default_factory=lambda: np.eye(4))
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    action: int = 0
    lifetime_ns: int = 0
    frame_locked: bool = False
    points: F64 | None = None  # (N, 3)
    colors: F64 | None = None  # (N, 4) rgba in [0, 1]
    text: str = ""
    mesh_resource: str = ""


def write_marker(out: CdrWriter, m: Marker) -> None:
    """Append one `visualization_msgs/Marker` to `out` (for arrays built piecewise)."""
    out.header(m.t_ns, m.frame_id)
    out.string(m.ns)
    out.i32(m.id)
    out.i32(m.type)
    out.i32(m.action)
    out.pose(m.pose)
    out.xyz(m.scale)
    out.color(m.color)
    out.time(m.lifetime_ns)  # builtin_interfaces/Duration has the Time layout
    out.bool(m.frame_locked)
    pts = np.zeros((0, 3)) if m.points is None else np.asarray(m.points, dtype="<f8")
    out.u32(len(pts))
    if len(pts):
        out.align(8)
        out.buf += np.ascontiguousarray(pts.reshape(-1, 3)).tobytes()
    cols = np.zeros((0, 4)) if m.colors is None else np.asarray(m.colors, dtype="<f4")
    out.u32(len(cols))
    if len(cols):
        out.buf += np.ascontiguousarray(cols.reshape(-1, 4)).tobytes()
    out.string("")  # texture_resource
    out.header(0, "")  # texture: sensor_msgs/CompressedImage (empty)
    out.string("")
    out.u32(0)
    out.u32(0)  # uv_coordinates
    out.string(m.text)
    out.string(m.mesh_resource)
    out.string("")  # mesh_file.filename
    out.u32(0)  # mesh_file.data
    out.bool(False)  # mesh_use_embedded_materials


def marker(m: Marker) -> bytes:
    out = CdrWriter()
    write_marker(out, m)
    return out.getvalue()


def marker_array(markers: Sequence[Marker]) -> bytes:
    out = CdrWriter()
    out.u32(len(markers))
    for m in markers:
        write_marker(out, m)
    return out.getvalue()


def image_marker(
    t_ns: int,
    frame_id: str,
    points_uv: ArrayLike,
    *,
    ns: str = "",
    id: int = 0,
    type: int = 4,
    scale: float = 3.0,
    outline_color: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0),
    outline_colors: ArrayLike | None = None,
    position: tuple[float, float] = (0.0, 0.0),
) -> bytes:
    """visualization_msgs/ImageMarker in pixel coordinates of the image on `frame_id`.

    `type`: 0 CIRCLE (at `position`, radius `scale`), 1 LINE_STRIP, 2 LINE_LIST, 3 POLYGON,
    4 POINTS (`points_uv` (N, 2), size `scale`). `outline_colors` (N, 4) colours points one by
    one. Foxglove's Image panel draws it over the image on the same topic namespace."""
    uv = np.asarray(points_uv, dtype=np.float64).reshape(-1, 2)
    pts = np.zeros((uv.shape[0], 3))
    pts[:, :2] = uv
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.string(ns)
    out.i32(id)
    out.i32(type)
    out.i32(0)  # ADD
    out.xyz((position[0], position[1], 0.0))
    out.f32(scale)
    out.color(outline_color)
    out.u8(0)  # filled
    out.color((0.0, 0.0, 0.0, 0.0))  # fill_color
    out.time(0)  # lifetime
    out.u32(len(pts))
    if len(pts):
        out.align(8)
        out.buf += pts.astype("<f8").tobytes()
    cols = (
        np.zeros((0, 4), dtype="<f4")
        if outline_colors is None
        else np.asarray(outline_colors, dtype="<f4").reshape(-1, 4)
    )
    out.u32(len(cols))
    out.buf += cols.tobytes()
    return out.getvalue()


# ---- std_msgs ----------------------------------------------------------------------------------
def float64_multi_array(values: ArrayLike, labels: Sequence[str] | None = None) -> bytes:
    """std_msgs/Float64MultiArray with one dimension; `labels` (joined by ',') name the entries
    in `layout.dim[0].label`, so a reader can tell what `data[i]` is."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    out = CdrWriter()
    out.u32(1)  # layout.dim: one MultiArrayDimension
    out.string(",".join(labels) if labels else "")
    out.u32(v.size)  # size
    out.u32(v.size)  # stride
    out.u32(0)  # data_offset
    out.f64_seq(v)
    return out.getvalue()


def float64(value: float) -> bytes:
    out = CdrWriter()
    out.f64(value)
    return out.getvalue()


def string(text: str) -> bytes:
    out = CdrWriter()
    out.string(text)
    return out.getvalue()
