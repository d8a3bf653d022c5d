"""Writing bags: any `SequenceSource` as a ROS 1 bag or a ROS 2 bag folder (sqlite3 or MCAP
storage), with EuRoC's topic names (tests, benchmarks, and users who want a bag from an ASL
folder)."""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.bag.calibration import EUROC_T_BODY_VICON, orthonormalize
from eurocslam.dataset.bag.topics import EUROC_VICON_TOPIC, TopicMap
from eurocslam.dataset.types import U8
from eurocslam.errors import DatasetError
from eurocslam.geometry import rot_to_quat_wxyz
from eurocslam.timebase import NS_PER_S

BAG_FORMATS = ("ros1", "ros2-db3", "ros2-mcap")


def _header(ts: Any, t_ns: int, frame_id: str, ros1: bool) -> Any:
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    stamp = Time(sec=t_ns // NS_PER_S, nanosec=t_ns % NS_PER_S)
    if ros1:
        return Header(seq=0, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def write_rosbag(
    seq: Any,
    out: Path | str,
    fmt: str = "ros1",
    *,
    encoding: str = "mono8",
    groundtruth: str = "pose",
    topics: TopicMap | None = None,
    max_frames: int | None = None,
    zero_header_stamps: bool = False,
    cam1_offset_ns: int = 0,
    compression: str | None = None,
) -> Path:
    """Write a `SequenceSource` as a ROS 1 bag or a ROS 2 bag folder (sqlite3 or MCAP storage),
    with EuRoC's topic names: cam0/cam1 `sensor_msgs/Image` (`encoding` mono8, bgr8, rgb8 or
    mono16), `/imu0` (when the sequence has IMU rows), ground truth as PoseStamped on
    `/groundtruth/pose` (`groundtruth="pose"`) or as EuRoC's raw Vicon TransformStamped
    (`"vicon"`: the body pose moved to the marker frame), and Leica PointStamped on
    `/leica/position`. Messages in stamp order, log time = stamp (or header stamps all zero with
    `zero_header_stamps`); `cam1_offset_ns` shifts cam1's stamps and log times (cameras without
    synchronised stamps); `compression`: ROS 1 chunk compression "bz2" or "lz4", ROS 2 per-file
    "zstd". Returns the written path.
    """
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    if fmt not in BAG_FORMATS:
        raise DatasetError(f"bag format '{fmt}' unknown (expected {', '.join(BAG_FORMATS)})")
    if encoding not in ("mono8", "bgr8", "rgb8", "mono16"):
        raise DatasetError(f"cannot write image encoding '{encoding}'")
    tm = topics or TopicMap()
    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out}: already exists")
    if fmt == "ros1" and out.suffix != ".bag":
        raise DatasetError(f"{out}: a ROS 1 bag's name must end in .bag")
    ros1 = fmt == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    T = ts.types
    Vector3 = T["geometry_msgs/msg/Vector3"]
    Quaternion = T["geometry_msgs/msg/Quaternion"]
    Point = T["geometry_msgs/msg/Point"]

    def hdr(t: int, frame: str) -> Any:
        return _header(ts, 0 if zero_header_stamps else t, frame, ros1)

    def image(t: int, img: U8, frame: str) -> Any:
        h, w = img.shape
        data: NDArray[Any]
        if encoding == "mono8":
            data, step = np.ascontiguousarray(img).reshape(-1), w
        elif encoding == "mono16":
            data, step = (img.astype(">u2") * 257).view(np.uint8).reshape(-1), 2 * w
        else:
            code = cv2.COLOR_GRAY2BGR if encoding == "bgr8" else cv2.COLOR_GRAY2RGB
            data, step = cv2.cvtColor(img, code).reshape(-1), 3 * w
        return T["sensor_msgs/msg/Image"](
            header=hdr(t, frame), height=h, width=w, encoding=encoding,
            is_bigendian=1 if encoding == "mono16" else 0, step=step, data=data,
        )  # fmt: skip

    z9 = np.zeros(9)
    cov_none = np.array([-1.0, *[0.0] * 8])

    def imu_msg(i: int) -> Any:
        g, a = seq.imu.gyro[i], seq.imu.accel[i]
        return T["sensor_msgs/msg/Imu"](
            header=hdr(int(seq.imu.t_ns[i]), "imu0"),
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=cov_none,
            angular_velocity=Vector3(x=g[0], y=g[1], z=g[2]),
            angular_velocity_covariance=z9,
            linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2]),
            linear_acceleration_covariance=z9,
        )

    gt = seq.groundtruth
    gt_T = None
    if gt is not None:
        gt_T = gt.T_world_body()
        if groundtruth == "vicon":
            gt_T = gt_T @ orthonormalize(EUROC_T_BODY_VICON)

    def gt_msg(i: int) -> Any:
        assert gt_T is not None
        t = int(gt.t_ns[i])
        p = gt_T[i, :3, 3]
        q = rot_to_quat_wxyz(gt_T[i, :3, :3]) if groundtruth == "vicon" else gt.q_wxyz[i]
        quat = Quaternion(x=q[1], y=q[2], z=q[3], w=q[0])
        if groundtruth == "vicon":
            tr = T["geometry_msgs/msg/Transform"](
                translation=Vector3(x=p[0], y=p[1], z=p[2]), rotation=quat
            )
            return T["geometry_msgs/msg/TransformStamped"](
                header=hdr(t, "world"), child_frame_id="firefly_sbx", transform=tr
            )
        pose = T["geometry_msgs/msg/Pose"](position=Point(x=p[0], y=p[1], z=p[2]), orientation=quat)
        return T["geometry_msgs/msg/PoseStamped"](header=hdr(t, "world"), pose=pose)

    def leica_msg(i: int) -> Any:
        p = seq.leica.p[i]
        return T["geometry_msgs/msg/PointStamped"](
            header=hdr(int(seq.leica.t_ns[i]), "world"), point=Point(x=p[0], y=p[1], z=p[2])
        )

    # each stream yields (t, connection index, message); connections 0 and 1 are cam0, cam1
    cam_type = "sensor_msgs/msg/Image"
    channels: list[tuple[str, str]] = [(tm.cam0[0], cam_type), (tm.cam1[0], cam_type)]
    streams: list[Iterator[tuple[int, int, Any]]] = []

    def frames_stream() -> Iterator[tuple[int, int, Any]]:
        # incomplete frames too: a camera's missing image is a missing message in the bag
        for k, f in enumerate(seq.frames(include_incomplete=True)):
            if max_frames is not None and k >= max_frames:
                return
            for side, img in ((0, f.left), (1, f.right)):
                if img is not None:
                    t = f.t_ns + (cam1_offset_ns if side == 1 else 0)
                    yield t, side, image(t, img, f"cam{side}")

    def add_stream(topic: str, typ: str, n: int, t_ns: Any, make: Any) -> None:
        k = len(channels)
        channels.append((topic, typ))
        streams.append((int(t_ns[i]), k, make(i)) for i in range(n))

    streams.append(frames_stream())
    if len(seq.imu):  # a stereo-only sequence has no IMU topic
        add_stream(tm.imu[0], "sensor_msgs/msg/Imu", len(seq.imu), seq.imu.t_ns, imu_msg)
    if gt is not None:
        if groundtruth == "vicon":
            gt_topic, gt_type = EUROC_VICON_TOPIC, "geometry_msgs/msg/TransformStamped"
        else:
            gt_topic, gt_type = "/groundtruth/pose", "geometry_msgs/msg/PoseStamped"
        add_stream(gt_topic, gt_type, len(gt), gt.t_ns, gt_msg)
    if seq.leica is not None:
        add_stream(
            "/leica/position", "geometry_msgs/msg/PointStamped", len(seq.leica.t_ns),
            seq.leica.t_ns, leica_msg,
        )  # fmt: skip

    merged = heapq.merge(*streams, key=lambda x: (x[0], x[1]))
    if ros1:
        writer: Any = Writer1(out)
        if compression is not None:
            if compression not in ("bz2", "lz4"):
                raise DatasetError(f"ROS 1 bag compression '{compression}' unknown (bz2, lz4)")
            writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    else:
        plugin = StoragePlugin.MCAP if fmt == "ros2-mcap" else StoragePlugin.SQLITE3
        writer = Writer2(out, version=9, storage_plugin=plugin)
        if compression is not None:
            if compression != "zstd":
                raise DatasetError(f"ROS 2 bag compression '{compression}' unknown (zstd)")
            writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    with writer:
        conns = [writer.add_connection(topic, typ, typestore=ts) for topic, typ in channels]
        for t, k, msg in merged:
            writer.write(conns[k], t, ser(msg, channels[k][1]))
    return out
