"""Small robot-style bags written directly with rosbags, for the calibration cases the
realsense writer never makes (a CameraInfo with K all zeros, a tf tree that misses a frame):
three frames of noise images, a CameraInfo per camera, `/tf_static`, a 200 Hz IMU."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.geometry import F64, make_T, rot_to_quat_wxyz

T0_NS = 1_700_000_000_000_000_000
R_OPT = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical in a body frame


def pinhole_info(
    w: int = 64, h: int = 48, f: float = 50.0, tx: float = 0.0, **over: Any
) -> dict[str, Any]:
    """CameraInfo fields of a distortion-free pinhole (`over` replaces any of them)."""
    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    P = np.hstack([K, np.array([[tx], [0.0], [0.0]])])
    info: dict[str, Any] = {
        "width": w, "height": h, "distortion_model": "plumb_bob", "d": np.zeros(5),
        "k": K.ravel(), "r": np.eye(3).ravel(), "p": P.ravel(), "frame_id": "",
    }  # fmt: skip
    info.update(over)
    return info


def realsense_tree(baseline: float = 0.05) -> list[tuple[str, str, F64]]:
    """camera_link -> infra1/infra2 (frame -> optical) and gyro -> imu_optical, realsense-style."""
    Topt = make_T(R_OPT, np.zeros(3))
    return [
        ("camera_link", "camera_infra1_frame", np.eye(4)),
        ("camera_infra1_frame", "camera_infra1_optical_frame", Topt),
        ("camera_link", "camera_infra2_frame", make_T(np.eye(3), np.array([0.0, -baseline, 0.0]))),
        ("camera_infra2_frame", "camera_infra2_optical_frame", Topt),
        ("camera_link", "camera_gyro_frame", make_T(np.eye(3), np.array([-0.01, -0.005, 0.004]))),
        ("camera_gyro_frame", "camera_imu_optical_frame", Topt),
    ]


def write_robot_bag(
    path: Path,
    infos: tuple[dict[str, Any], dict[str, Any]],
    tf: list[tuple[str, str, F64]],
    *,
    frames: tuple[str, str] = ("camera_infra1_optical_frame", "camera_infra2_optical_frame"),
    imu_frame: str | None = "camera_imu_optical_frame",
    image_size: tuple[int, int] = (64, 48),
    topics: tuple[str, str] = ("/camera/infra1/image_rect_raw", "/camera/infra2/image_rect_raw"),
    n: int = 3,
    storage: str = "mcap",
) -> Path:
    """A bag with the given CameraInfo fields and static transforms: a ROS 2 bag folder
    (`storage` "mcap" or "sqlite3") or a ROS 1 `.bag` file ("ros1": `path` gets the suffix; the
    CameraInfo fields are ROS 1's D, K, R, P)."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = storage == "ros1"
    if ros1:
        from eurocslam.synth.robot_bag import _ros1_typestore

        ts = _ros1_typestore()
    else:
        ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types

    def ser(msg: Any, msgtype: str) -> Any:
        return ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)

    def hdr(t: int, frame: str) -> Any:
        stamp = T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9)
        if ros1:
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        path = path.with_suffix(".bag")
        writer: Any = Writer1(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)

    rng = np.random.default_rng(0)
    w, h = image_size
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    with writer as wr:
        img_c = [wr.add_connection(t, "sensor_msgs/msg/Image", typestore=ts) for t in topics]
        info_c = [
            wr.add_connection(t.rsplit("/", 1)[0] + "/camera_info", "sensor_msgs/msg/CameraInfo",
                              typestore=ts)
            for t in topics
        ]  # fmt: skip
        tf_c = wr.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        imu_c = wr.add_connection("/camera/imu", "sensor_msgs/msg/Imu", typestore=ts)
        trs = []
        for parent, child, Tpc in tf:
            q = rot_to_quat_wxyz(Tpc[:3, :3])
            p = Tpc[:3, 3]
            tr = T["geometry_msgs/msg/Transform"](
                translation=V3(x=p[0], y=p[1], z=p[2]), rotation=Q(x=q[1], y=q[2], z=q[3], w=q[0])
            )
            trs.append(T["geometry_msgs/msg/TransformStamped"](
                header=hdr(T0_NS, parent), child_frame_id=child, transform=tr))  # fmt: skip
        wr.write(tf_c, T0_NS, ser(T["tf2_msgs/msg/TFMessage"](transforms=trs),
                                  "tf2_msgs/msg/TFMessage"))  # fmt: skip
        roi = T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        for i in range(n):
            t = T0_NS + i * 50_000_000
            for k in range(2):
                img = rng.integers(0, 256, (h, w), dtype=np.uint8)
                msg = T["sensor_msgs/msg/Image"](
                    header=hdr(t, frames[k]), height=h, width=w, encoding="mono8",
                    is_bigendian=0, step=w, data=img.reshape(-1),
                )  # fmt: skip
                wr.write(img_c[k], t, ser(msg, "sensor_msgs/msg/Image"))
                f = dict(infos[k])
                frame = f.pop("frame_id") or frames[k]
                ci = T["sensor_msgs/msg/CameraInfo"](
                    header=hdr(t, frame), binning_x=0, binning_y=0, roi=roi,
                    **{(key.upper() if ros1 and key in "dkrp" else key):
                       (np.asarray(v, dtype=np.float64) if key in "dkrp" else v)
                       for key, v in f.items()},
                )  # fmt: skip
                wr.write(info_c[k], t, ser(ci, "sensor_msgs/msg/CameraInfo"))
            for j in range(10):
                tj = t + j * 5_000_000
                imu = T["sensor_msgs/msg/Imu"](
                    header=hdr(tj, imu_frame or ""), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.array([-1.0] + [0.0] * 8),
                    angular_velocity=V3(x=0.0, y=0.0, z=0.0),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=V3(x=0.0, y=-9.81, z=0.0),
                    linear_acceleration_covariance=np.zeros(9),
                )  # fmt: skip
                wr.write(imu_c, tj, ser(imu, "sensor_msgs/msg/Imu"))
    return path
