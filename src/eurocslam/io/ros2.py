"""ROS 2 (humble) messages without a ROS install: exact schema texts, CDR encoding, builders.

Every builder returns the message already CDR-encoded (`bytes`, little-endian, with the 4-byte
encapsulation header), so any sink (MCAP file, live view, tee) forwards the same bytes and the
encoding cost is paid once. Builders take int64 nanosecond stamps and `T_a_b` 4x4 poses.

Schema texts (`schema_text(msgtype)`) come from rosbags' bundled humble definitions: the root
definition first, then each dependency after a line of 80 `=` and `MSG: pkg/Name`, spelled exactly
as the fields spell it (what rosbag2 and foxglove_bridge write; Foxglove rejects anything else).

Types (canonical names, as used for MCAP schema names):

| builder | msgtype |
|---|---|
| `image` | sensor_msgs/msg/Image (mono8, or rgb8/bgr8 for HxWx3) |
| `compressed_image` | sensor_msgs/msg/CompressedImage (png / jpeg) |
| `camera_info` (+ `stereo_camera_infos(rig)`) | sensor_msgs/msg/CameraInfo |
| `imu` (+ `imu_covariances(calib)`) | sensor_msgs/msg/Imu |
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

from eurocslam.dataset.calib import CameraCalib, ImuCalib, StereoRig
from eurocslam.geometry import F64, rot_to_quat_wxyz, wxyz_to_xyzw

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

CDR_LE_HEADER = b"\x00\x01\x00\x00"


@functools.cache
def _typestore():  # type: ignore[no-untyped-def]
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


@functools.cache
def schema_text(msgtype: str) -> str:
    """The `ros2msg` schema text of `msgtype` (e.g. 'sensor_msgs/msg/Image'), root first."""
    text, _ = _typestore().generate_msgdef(msgtype, ros_version=2)
    return text


# ---- CDR writer -------------------------------------------------------------------------------
_I32 = struct.Struct("<i")
_U32 = struct.Struct("<I")
_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
_TIME = struct.Struct("<iI")
_SEC = 1_000_000_000


def stamp_bytes(t_ns: int) -> bytes:
    """The CDR bytes of a `builtin_interfaces/Time` (sec, nanosec), 4-aligned in a message."""
    return _TIME.pack(*split_ns(t_ns))


def split_ns(t_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a ROS time from int64 nanoseconds."""
    t = int(t_ns)
    return t // _SEC, t % _SEC


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
    out.bytes_seq(memoryview(img).cast("B"))
    return out.getvalue()


def compressed_image(t_ns: int, frame_id: str, fmt: str, data: bytes) -> bytes:
    """sensor_msgs/CompressedImage; `fmt` is 'png' or 'jpeg' (what Foxglove looks for)."""
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.string(fmt)
    out.bytes_seq(data)
    return out.getvalue()


@dataclass(frozen=True)
class CameraInfoData:
    """The static part of a sensor_msgs/CameraInfo (everything but the header)."""

    width: int
    height: int
    distortion_model: str
    D: F64
    K: F64  # 3x3
    R: F64  # 3x3 rectification rotation
    P: F64  # 3x4 projection of the rectified camera


def stereo_camera_infos(rig: StereoRig) -> tuple[CameraInfoData, CameraInfoData]:
    """CameraInfo for cam0 and cam1: K, D (plumb_bob) and R/P from `cv2.stereoRectify` of the
    rig (zero disparity at infinity, alpha 0). cam1's P[0, 3] = -fx' * baseline, as in ROS."""
    import cv2

    c0, c1 = rig.cam0, rig.cam1
    T_cam1_cam0 = rig.T_cam1_cam0
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        c0.K,
        _plumb_bob(c0),
        c1.K,
        _plumb_bob(c1),
        (c0.width, c0.height),
        T_cam1_cam0[:3, :3].copy(),
        T_cam1_cam0[:3, 3].reshape(3, 1).copy(),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0.0,
    )
    return _info(c0, R1, P1), _info(c1, R2, P2)


def _plumb_bob(c: CameraCalib) -> F64:
    d = np.zeros(5)
    d[: len(c.distortion)] = c.distortion
    return d


def _info(c: CameraCalib, R: F64, P: F64) -> CameraInfoData:
    return CameraInfoData(
        c.width,
        c.height,
        "plumb_bob",
        _plumb_bob(c),
        c.K.copy(),
        np.asarray(R, dtype=np.float64),
        np.asarray(P, dtype=np.float64),
    )


def camera_info(t_ns: int, frame_id: str, info: CameraInfoData) -> bytes:
    out = CdrWriter()
    out.header(t_ns, frame_id)
    out.u32(info.height)
    out.u32(info.width)
    out.string(info.distortion_model)
    out.f64_seq(info.D)
    out.f64_fixed(info.K, 9)
    out.f64_fixed(info.R, 9)
    out.f64_fixed(info.P, 12)
    out.u32(0)  # binning_x
    out.u32(0)  # binning_y
    for _ in range(4):  # roi: x_offset, y_offset, height, width (all 0 = full image)
        out.u32(0)
    out.bool(False)  # roi.do_rectify
    return out.getvalue()


def imu_covariances(calib: ImuCalib) -> tuple[F64, F64]:
    """Diagonal 3x3 gyro and accel covariances of one sample: density**2 / dt (= * rate_hz)."""
    return (np.eye(3) * calib.discrete_gyro_variance(), np.eye(3) * calib.discrete_accel_variance())


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


# ---- batches of fixed-layout messages (high-rate streams: IMU, ground truth) -----------------
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
    rows["sec"] = t_ns // _SEC
    rows["nsec"] = t_ns % _SEC
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
        rows["sec"] = st[1:] // _SEC
        rows["nsec"] = st[1:] % _SEC
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
