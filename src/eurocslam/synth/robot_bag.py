"""Writing a sequence as a robot's bag in realsense-ros style: the calibration only as
`sensor_msgs/CameraInfo` and `/tf_static` (no sensor.yaml attachments), realsense topic and
frame names, the IMU united or as separate accelerometer and gyroscope streams. ROS 1 `.bag`,
ROS 2 sqlite3 or ROS 2 MCAP (rosbags' writers). For tests, benchmarks and `eurocslam synth
--bag`: a bag like this must run to the ASL folder's trajectory.

Topics (`ns` = `/camera`):

- `images="raw"`: `/camera/infra{1,2}/image_raw`, the images as they are; CameraInfo with the
  calibration's K, D (`plumb_bob`, or `rational_polynomial` for 8 coefficients) and the stereo
  R/P of `camera.rectify_stereo` (cam1's P[0, 3] = -fx' * baseline).
- `images="rect"`: `/camera/infra{1,2}/image_rect_raw`, rectified here as a driver would
  (`rectify_stereo` with `rect_alpha`, float maps and bilinear interpolation: not the
  frontend's fixed-point maps, so the pixels differ a little from what the frontend would
  make; `rect_maps="fixed"` uses the frontend's fixed-point maps instead, the same pixels);
  CameraInfo with D = 0, R = I, K = P's pinhole, the baseline in the right camera's
  P[0, 3] (`p_tx`: "ros" as REP-104 says, "zero" as realsense-ros before 2.2.16, "flipped" with
  the sign of a left camera, as some realsense-ros versions publish). The optical frames are
  then the rectified cameras.
- `/camera/infra{1,2}/camera_info`; with `compressed` the images go as PNG
  `sensor_msgs/CompressedImage` on `.../compressed`.
- `imu="united"`: `/camera/imu` (frame `camera_imu_optical_frame`), the sequence's IMU rows.
  `imu="split"`: `/camera/accel/sample` and `/camera/gyro/sample` (frames
  `camera_{accel,gyro}_optical_frame`): the given `SplitImu` streams (a synthetic RealSense
  rig's), else resampled from the united rows at `accel_rate_hz` / `gyro_rate_hz` by linear
  interpolation (None: the rows' own stamps, exact).
- `/tf_static` (latched): `camera_link` (= infra1's `_frame`, REP-103 axes) ->
  `camera_infra{1,2}_frame` -> `camera_infra{1,2}_optical_frame`, `camera_link` ->
  `camera_{gyro,accel}_frame` -> `camera_{gyro,accel}_optical_frame`, and
  `camera_gyro_frame` -> `camera_imu_optical_frame`; the IMU optical frames are the body.
- `/groundtruth/pose` (PoseStamped of the body) when the sequence has ground truth and
  `groundtruth` is set; no robot has it, but `eval` can then take the bag.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from eurocslam.camera import rectify_stereo
from eurocslam.dataset.bag.writer import BAG_FORMATS
from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.split_imu import SplitImu
from eurocslam.dataset.types import U8
from eurocslam.errors import DatasetError
from eurocslam.geometry import F64, inv_T, make_T, rot_to_quat_wxyz
from eurocslam.timebase import NS_PER_S

IMAGE_VARIANTS = ("raw", "rect")
IMU_FORMS = ("united", "split")
P_TX = ("ros", "zero", "flipped")
# optical frame (x right, y down, z forward) in a REP-103 body frame (x forward, y left, z up)
R_FRAME_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class RealsenseBagOptions:
    """What to write (see the module docstring)."""

    images: str = "raw"
    imu: str = "united"
    accel_rate_hz: float | None = None
    gyro_rate_hz: float | None = None
    rect_alpha: float = 0.0
    rect_maps: str = "float"  # float (a driver's) | fixed (the frontend's CV_16SC2 tables)
    compressed: bool = False
    encoding: str = "mono8"  # mono8 | mono16 (raw Image messages)
    p_tx: str = "ros"
    groundtruth: bool = True
    max_frames: int | None = None
    ns: str = "/camera"
    prefix: str = "camera"  # frame names: <prefix>_link, <prefix>_infra1_optical_frame, ...

    def check(self) -> None:
        for name, value, allowed in (
            ("images", self.images, IMAGE_VARIANTS),
            ("imu", self.imu, IMU_FORMS),
            ("p_tx", self.p_tx, P_TX),
            ("encoding", self.encoding, ("mono8", "mono16")),
            ("rect_maps", self.rect_maps, ("float", "fixed")),
        ):
            if value not in allowed:
                raise DatasetError(
                    f"realsense bag: {name} '{value}' unknown ({', '.join(allowed)})"
                )
        for name, rate in (("accel", self.accel_rate_hz), ("gyro", self.gyro_rate_hz)):
            if rate is not None and not rate > 0:
                raise DatasetError(f"realsense bag: {name} rate {rate} Hz must be > 0")

    def frame(self, name: str) -> str:
        return f"{self.prefix}_{name}"

    def image_topic(self, cam: int) -> str:
        leaf = "image_rect_raw" if self.images == "rect" else "image_raw"
        return f"{self.ns}/infra{cam + 1}/{leaf}" + ("/compressed" if self.compressed else "")


@dataclass(frozen=True)
class _Calib:
    """The geometry the bag publishes: per camera K, D, model, R, P and T_body_optical."""

    K: tuple[F64, F64]
    D: tuple[F64, F64]
    model: str
    R: tuple[F64, F64]
    P: tuple[F64, F64]
    T_body_optical: tuple[F64, F64]
    maps: tuple[Any, Any] | None  # rectification maps (images="rect")


def _published_calibration(rig: StereoRig, opt: RealsenseBagOptions) -> _Calib:
    rect = rectify_stereo(rig, opt.rect_alpha)
    c0, c1 = rig.cam0, rig.cam1
    if opt.images == "raw":
        model = c0.model.ros_name
        if c1.model.ros_name != model or not c0.model.perspective:
            raise DatasetError(
                f"realsense bag: raw images need both cameras in one pinhole model, not "
                f"{c0.distortion_model} and {c1.distortion_model}"
            )
        return _Calib(
            (c0.K, c1.K), (c0.model.ros_coeffs(), c1.model.ros_coeffs()), model,
            (rect.R_rect0_cam0, rect.R_rect1_cam1), (rect.P0, rect.P1),
            (c0.T_body_cam, c1.T_body_cam), None,
        )  # fmt: skip
    g = rect.geometry
    K = np.array([[g.fx, 0.0, g.cx], [0.0, g.fy, g.cy], [0.0, 0.0, 1.0]])
    P0 = np.hstack([K, np.zeros((3, 1))])
    P1 = P0.copy()
    P1[0, 3] = {"ros": -g.fx * g.baseline, "zero": 0.0, "flipped": g.fx * g.baseline}[opt.p_tx]
    T0 = g.T_body_rect0
    T1 = T0 @ make_T(np.eye(3), np.array([g.baseline, 0.0, 0.0]))
    size = (c0.width, c0.height)
    kind = cv2.CV_32FC1 if opt.rect_maps == "float" else cv2.CV_16SC2
    maps: tuple[Any, Any] = (
        cv2.initUndistortRectifyMap(c0.K, c0.D, rect.R_rect0_cam0, rect.P0, size, kind),
        cv2.initUndistortRectifyMap(c1.K, c1.D, rect.R_rect1_cam1, rect.P1, size, kind),
    )
    return _Calib((K, K), (np.zeros(5), np.zeros(5)), "plumb_bob", (np.eye(3), np.eye(3)),
                  (P0, P1), (T0, T1), maps)  # fmt: skip


def _static_transforms(
    rig: StereoRig, cal: _Calib, opt: RealsenseBagOptions
) -> list[tuple[str, str, F64]]:
    """(parent, child, T_parent_child) of the realsense tree, body = the IMU optical frames."""
    T_opt = make_T(R_FRAME_OPTICAL, np.zeros(3))
    T_body_imu = rig.imu.T_body_imu if rig.imu is not None else np.eye(4)
    # camera_link is infra1's _frame: T_body_link = T_body_infra1opt * inv(T_frame_optical)
    T_link_body = inv_T(cal.T_body_optical[0] @ inv_T(T_opt))
    f = opt.frame
    out = [
        (f("link"), f("infra1_frame"), np.eye(4)),
        (f("infra1_frame"), f("infra1_optical_frame"), T_opt),
        (f("link"), f("infra2_frame"), T_link_body @ cal.T_body_optical[1] @ inv_T(T_opt)),
        (f("infra2_frame"), f("infra2_optical_frame"), T_opt),
    ]
    for sensor in ("gyro", "accel"):
        out.append((f("link"), f(f"{sensor}_frame"), T_link_body @ T_body_imu @ inv_T(T_opt)))
        out.append((f(f"{sensor}_frame"), f(f"{sensor}_optical_frame"), T_opt))
    out.append((f("gyro_frame"), f("imu_optical_frame"), T_opt))
    return out


def _resample(t_src: Any, v_src: F64, rate_hz: float | None) -> tuple[Any, F64]:
    """A stream at `rate_hz` over the source's span by linear interpolation (None: as is)."""
    if rate_hz is None:
        return t_src, v_src
    period = NS_PER_S / rate_hz
    n = int(np.floor((int(t_src[-1]) - int(t_src[0])) / period)) + 1
    t = int(t_src[0]) + np.round(np.arange(n) * period).astype(np.int64)
    x = (t_src - t_src[0]).astype(np.float64)
    xq = (t - t_src[0]).astype(np.float64)
    return t, np.column_stack([np.interp(xq, x, v_src[:, k]) for k in range(3)])


def split_streams(seq: Any, opt: RealsenseBagOptions, split: SplitImu | None) -> SplitImu:
    """The accelerometer and gyroscope streams a split bag carries (module docstring)."""
    if split is not None and opt.accel_rate_hz is None and opt.gyro_rate_hz is None:
        return split
    imu = seq.imu
    at, a = _resample(imu.t_ns, imu.accel, opt.accel_rate_hz)
    gt, g = _resample(imu.t_ns, imu.gyro, opt.gyro_rate_hz)
    return SplitImu(np.asarray(at, np.int64), a, np.asarray(gt, np.int64), g)


def _ros1_typestore() -> Any:
    """ROS 1 noetic types plus `tf2_msgs/TFMessage` (not shipped in rosbags' ROS 1 store)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        ts.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
    return ts


def write_realsense_bag(
    seq: Any,
    out: Path | str,
    fmt: str = "ros2-mcap",
    options: RealsenseBagOptions | None = None,
    *,
    split: SplitImu | None = None,
) -> Path:
    """Write a `SequenceSource` (an ASL folder, a synthetic sequence) as a realsense-ros style
    bag (module docstring); returns the path. `split`: the accelerometer and gyroscope streams
    for `imu="split"` (default: from the sequence's united rows)."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    opt = options or RealsenseBagOptions()
    opt.check()
    if fmt not in BAG_FORMATS:
        raise DatasetError(f"bag format '{fmt}' unknown (expected {', '.join(BAG_FORMATS)})")
    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out}: already exists")
    if fmt == "ros1" and out.suffix != ".bag":
        raise DatasetError(f"{out}: a ROS 1 bag's name must end in .bag")
    rig: StereoRig = seq.rig
    has_imu = len(seq.imu) > 0 and rig.imu is not None
    ros1 = fmt == "ros1"
    ts = _ros1_typestore() if ros1 else get_typestore(Stores.ROS2_HUMBLE)
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    T = ts.types
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    cal = _published_calibration(rig, opt)
    f = opt.frame

    def hdr(t: int, frame: str) -> Any:
        stamp = T["builtin_interfaces/msg/Time"](sec=t // NS_PER_S, nanosec=t % NS_PER_S)
        if ros1:
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def image_msg(t: int, img: U8, frame: str) -> Any:
        if opt.compressed:
            ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
            if not ok:
                raise DatasetError(f"cannot encode the image at {t} as PNG")
            return T["sensor_msgs/msg/CompressedImage"](
                header=hdr(t, frame), format="mono8; png compressed ",
                data=np.frombuffer(buf.tobytes(), np.uint8),
            )  # fmt: skip
        h, w = img.shape
        if opt.encoding == "mono16":
            data, step = (img.astype(">u2") * 257).view(np.uint8).reshape(-1), 2 * w
        else:
            data, step = np.ascontiguousarray(img).reshape(-1), w
        return T["sensor_msgs/msg/Image"](
            header=hdr(t, frame), height=h, width=w, encoding=opt.encoding,
            is_bigendian=1 if opt.encoding == "mono16" else 0, step=step, data=data,
        )  # fmt: skip

    def info_msg(t: int, cam: int) -> Any:
        c = rig.cam0 if cam == 0 else rig.cam1
        arrays = {"d": cal.D[cam], "k": cal.K[cam].reshape(-1), "r": cal.R[cam].reshape(-1),
                  "p": cal.P[cam].reshape(-1)}  # fmt: skip
        if ros1:
            arrays = {k.upper(): v for k, v in arrays.items()}
        roi = T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return T["sensor_msgs/msg/CameraInfo"](
            header=hdr(t, f(f"infra{cam + 1}_optical_frame")), height=c.height, width=c.width,
            distortion_model=cal.model, binning_x=0, binning_y=0, roi=roi,
            **{k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()},
        )  # fmt: skip

    z9 = np.zeros(9)
    no_orientation = np.array([-1.0, *[0.0] * 8])

    def imu_msg(t: int, frame: str, g: F64 | None, a: F64 | None) -> Any:
        g = np.zeros(3) if g is None else g
        a = np.zeros(3) if a is None else a
        return T["sensor_msgs/msg/Imu"](
            header=hdr(t, frame), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=no_orientation,
            angular_velocity=V3(x=g[0], y=g[1], z=g[2]), angular_velocity_covariance=z9,
            linear_acceleration=V3(x=a[0], y=a[1], z=a[2]), linear_acceleration_covariance=z9,
        )  # fmt: skip

    def tf_msg(t: int) -> Any:
        trs = []
        for parent, child, Tpc in _static_transforms(rig, cal, opt):
            q = rot_to_quat_wxyz(Tpc[:3, :3])
            p = Tpc[:3, 3]
            tr = T["geometry_msgs/msg/Transform"](
                translation=V3(x=p[0], y=p[1], z=p[2]), rotation=Q(x=q[1], y=q[2], z=q[3], w=q[0])
            )
            trs.append(
                T["geometry_msgs/msg/TransformStamped"](
                    header=hdr(t, parent), child_frame_id=child, transform=tr
                )
            )
        return T["tf2_msgs/msg/TFMessage"](transforms=trs)

    image_type = "sensor_msgs/msg/CompressedImage" if opt.compressed else "sensor_msgs/msg/Image"
    channels: list[tuple[str, str]] = [
        (opt.image_topic(0), image_type),
        (opt.image_topic(1), image_type),
        (f"{opt.ns}/infra1/camera_info", "sensor_msgs/msg/CameraInfo"),
        (f"{opt.ns}/infra2/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/tf_static", "tf2_msgs/msg/TFMessage"),
    ]
    streams: list[Iterator[tuple[int, int, Any]]] = []

    def frames_stream() -> Iterator[tuple[int, int, Any]]:
        for k, fr in enumerate(seq.frames(include_incomplete=True)):
            if opt.max_frames is not None and k >= opt.max_frames:
                return
            if k == 0:
                yield fr.t_ns, 4, tf_msg(fr.t_ns)  # the static tree first
            for side, img in ((0, fr.left), (1, fr.right)):
                if img is None:
                    continue
                if cal.maps is not None:
                    m = cal.maps[side]
                    img = np.asarray(cv2.remap(img, m[0], m[1], cv2.INTER_LINEAR))
                frame = f(f"infra{side + 1}_optical_frame")
                yield fr.t_ns, side, image_msg(fr.t_ns, img, frame)
                yield fr.t_ns, 2 + side, info_msg(fr.t_ns, side)

    def add_stream(topic: str, typ: str, t_ns: Any, make: Any) -> None:
        k = len(channels)
        channels.append((topic, typ))
        streams.append((int(t_ns[i]), k, make(i)) for i in range(len(t_ns)))

    streams.append(frames_stream())
    imu_type = "sensor_msgs/msg/Imu"
    if has_imu and opt.imu == "united":
        imu = seq.imu
        add_stream(f"{opt.ns}/imu", imu_type, imu.t_ns,
                   lambda i: imu_msg(int(imu.t_ns[i]), f("imu_optical_frame"), imu.gyro[i],
                                     imu.accel[i]))  # fmt: skip
    elif has_imu:
        sp = split_streams(seq, opt, split)
        add_stream(f"{opt.ns}/accel/sample", imu_type, sp.accel_t_ns,
                   lambda i: imu_msg(int(sp.accel_t_ns[i]), f("accel_optical_frame"), None,
                                     sp.accel[i]))  # fmt: skip
        add_stream(f"{opt.ns}/gyro/sample", imu_type, sp.gyro_t_ns,
                   lambda i: imu_msg(int(sp.gyro_t_ns[i]), f("gyro_optical_frame"), sp.gyro[i],
                                     None))  # fmt: skip
    gt = seq.groundtruth
    if opt.groundtruth and gt is not None and len(gt):
        Pose, Point = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Point"]

        def gt_msg(i: int) -> Any:
            p, q = gt.p[i], gt.q_wxyz[i]
            pose = Pose(position=Point(x=p[0], y=p[1], z=p[2]),
                        orientation=Q(x=q[1], y=q[2], z=q[3], w=q[0]))  # fmt: skip
            return T["geometry_msgs/msg/PoseStamped"](header=hdr(int(gt.t_ns[i]), "world"),
                                                      pose=pose)  # fmt: skip

        add_stream("/groundtruth/pose", "geometry_msgs/msg/PoseStamped", gt.t_ns, gt_msg)

    merged = heapq.merge(*streams, key=lambda x: (x[0], x[1]))
    if ros1:
        writer: Any = Writer1(out)
    else:
        plugin = StoragePlugin.MCAP if fmt == "ros2-mcap" else StoragePlugin.SQLITE3
        writer = Writer2(out, version=9, storage_plugin=plugin)
    latched = Qos(
        QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
        QosTime(0, 0), QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False,
    )  # fmt: skip
    with writer:
        conns = []
        for topic, typ in channels:
            if topic == "/tf_static":
                kw: dict[str, Any] = (
                    {"latching": 1} if ros1 else {"offered_qos_profiles": [latched]}
                )
            else:
                kw = {}
            conns.append(writer.add_connection(topic, typ, typestore=ts, **kw))
        for t, k, msg in merged:
            writer.write(conns[k], t, ser(msg, channels[k][1]))
    return out
