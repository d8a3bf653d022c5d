"""`BagSequence`: a ROS 1 bag, ROS 2 bag (folder, `.db3`) or MCAP as a `SequenceSource`.

One pass at opening indexes the bag (IMU, ground truth and Leica decoded into arrays; camera
messages give only their stamps); `frames()` streams the camera messages again and decodes each
pair as it completes. See the package docstring for stamps, calibration and ground truth.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.bag.bag_rig import BagCamera, rig_from_camera_infos
from eurocslam.dataset.bag.calibration import (
    BUILTIN,
    bag_calibration_name,
    gt_sensor_extrinsic,
    imu_calibration,
    resolve_calibration,
)
from eurocslam.dataset.bag.camera_info import CameraInfo, camera_info_from_msg
from eurocslam.dataset.bag.discovery import camera_info_topic, discover_imu, discover_stereo
from eurocslam.dataset.bag.files import bag_kind, is_bag_path, open_reader
from eurocslam.dataset.bag.imu_union import unite_imu
from eurocslam.dataset.bag.messages import (
    check_encoding,
    compressed_msg_to_mono,
    fast_values,
    header_stamp_ns,
    image_msg_to_mono,
    message_values,
    stamp_of,
)
from eurocslam.dataset.bag.pairing import BagEntry, camera_map, join_cameras, snap_cam1
from eurocslam.dataset.bag.tf_tree import TF_STATIC_TOPIC, TF_TYPE, TfTree, edges_from_tf_message
from eurocslam.dataset.bag.topics import (
    IMU_ROLES,
    INFO_ROLES,
    ROLE_TYPES,
    ROLES,
    TopicMap,
)
from eurocslam.dataset.calib import StereoRig, calib_folder
from eurocslam.dataset.imu_noise import ImuNoise, with_imu_noise
from eurocslam.dataset.types import (
    I64,
    U8,
    GroundTruth,
    ImuData,
    PositionData,
    SkipReport,
    StereoFrame,
    empty_imu,
)
from eurocslam.errors import CalibrationError, DatasetError
from eurocslam.geometry import (
    F64,
    inv_T,
    make_T,
    normalize_quat,
    quat_wxyz_to_rot,
    rot_to_quat_wxyz,
    xyzw_to_wxyz,
)


def _swap(d: dict[str, Any], k0: str, k1: str) -> None:
    """Exchange two keys' values (either may be absent)."""
    v0, v1 = d.pop(k0, None), d.pop(k1, None)
    if v1 is not None:
        d[k0] = v1
    if v0 is not None:
        d[k1] = v0


def _rate_hz(stamps: I64) -> float:
    """Rate of a stream from the median period of its sorted unique stamps (0: fewer than 2)."""
    t = np.unique(np.asarray(stamps, dtype=np.int64))
    if t.size < 2:
        return 0.0
    return round(1e9 / float(np.median(np.diff(t))), 3)


@dataclass
class TopicStats:
    """Stamps of one role's topic in the order the bag stores them (log-time order)."""

    role: str
    topic: str
    msgtype: str
    header_ns: list[int] | I64 = field(default_factory=list)  # lists while scanning,
    log_ns: list[int] | I64 = field(default_factory=list)  # int64 arrays after `freeze`

    def freeze(self) -> None:
        """Turn the stamp lists into int64 arrays (a quarter of the memory)."""
        self.header_ns = np.asarray(self.header_ns, dtype=np.int64)
        self.log_ns = np.asarray(self.log_ns, dtype=np.int64)

    @property
    def count(self) -> int:
        return len(self.log_ns)

    def header_array(self) -> I64:
        return np.asarray(self.header_ns, dtype=np.int64)

    def log_array(self) -> I64:
        return np.asarray(self.log_ns, dtype=np.int64)

    def unset_stamps(self) -> NDArray[np.bool_]:
        """Messages whose header stamp is zero though they were logged later: the stamp was never
        set (a stamp and log time both 0, as a sequence whose times start at 0 has, is real)."""
        unset: NDArray[np.bool_] = (self.header_array() == 0) & (self.log_array() != 0)
        return unset

    @property
    def zero_stamps(self) -> int:
        return int(np.count_nonzero(self.unset_stamps()))


@dataclass(frozen=True)
class ImageInfo:
    """What the first message of a camera topic says about its images."""

    topic: str
    msgtype: str
    encoding: str  # Image encoding, or CompressedImage format
    width: int
    height: int


class BagSequence:
    """A ROS 1 bag, ROS 2 bag (folder, `.db3`) or MCAP. Implements `SequenceSource`."""

    def __init__(
        self,
        path: Path | str,
        rig: StereoRig | None = None,
        *,
        calib: Path | str | None = None,
        topics: TopicMap | Mapping[str, str] | None = None,
        imu_noise: ImuNoise | None = None,
        show_progress: bool | None = None,
    ) -> None:
        self.path = Path(path)
        if self.path.name == "metadata.yaml" and self.path.is_file():
            self.path = self.path.parent
        if not self.path.exists():
            raise DatasetError(f"{self.path}: no such file or folder")
        if not is_bag_path(self.path):
            raise DatasetError(
                f"{self.path}: not a ROS bag or MCAP (expected .bag, .db3, .mcap or a ROS 2 bag "
                "folder with metadata.yaml)"
            )
        self.kind = bag_kind(self.path)
        self.root = self.path  # what convert and run record as the source
        self.name = (
            self.path.name.removesuffix(self.path.suffix)
            if self.path.is_file()
            else (self.path.name)
        )
        if topics is None:
            topics = TopicMap()
        elif not isinstance(topics, TopicMap):
            topics = TopicMap().with_topics(topics)
        self.topic_map: TopicMap = topics
        self.skips = SkipReport()
        self.notes: list[str] = []
        self.calib_dir = calib_folder(calib) if calib is not None else None
        self.stats: dict[str, TopicStats] = {}
        self.image_info: dict[str, ImageInfo] = {}
        self.bag_topics: dict[str, tuple[str, int]] = {}  # topic -> (type, count)
        self.ros2 = False
        self._conn_role: dict[int, str] = {}
        self._cam1_alias: dict[int, int] = {}  # cam1 stamp -> the cam0 stamp it pairs with
        self._unordered_pair = False  # cam0/cam1 found by type, left/right not yet decided
        # what the bag says about its calibration (read in `_static_pass`)
        self.info_topics: dict[str, str] = {}  # cam0_info / cam1_info -> topic
        self.camera_infos: dict[str, CameraInfo] = {}  # cam0 / cam1 -> its first CameraInfo
        self.frame_ids: dict[str, str] = {}  # cam0, cam1, imu, accel, gyro -> header.frame_id
        self.tf = TfTree()
        explicit, self.calib_source = resolve_calibration(
            self.path, rig, self.calib_dir, self.notes
        )
        self.T_body_gtsensor: F64 = np.eye(4)
        self._scan(show_progress)
        self.rig: StereoRig = explicit if explicit is not None else self._rig_from_bag()
        self._apply_imu_noise(imu_noise, from_bag=explicit is None)
        self.stamp_source = self._choose_camera_stamps()
        self.frame_index = self._join_cameras()
        self._check_image_sizes()

    # ---- the index pass -------------------------------------------------------------------
    def _resolve_topics(self, reader: Any) -> dict[str, list[Any]]:
        """Each role's connections: the user's topic, else the first default present, else found
        by message type (`discovery`); CameraInfo beside each camera."""
        available = {name: info for name, info in reader.topics.items()}
        self.bag_topics = {n: (str(i.msgtype), int(i.msgcount)) for n, i in available.items()}
        types = {n: t for n, (t, _) in self.bag_topics.items()}
        listing = ", ".join(f"{n} ({t}, {c})" for n, (t, c) in sorted(self.bag_topics.items()))
        where = str(self.path)
        chosen: dict[str, str] = {}
        for role in ROLES:
            cands = self.topic_map.candidates(role)
            found = next((t for t in cands if t in available), None)
            if found is not None:
                chosen[role] = found
            elif role in self.topic_map.explicit:
                raise DatasetError(
                    f"{self.path}: no topic for {role} (looked for {', '.join(cands)}; map "
                    f"one with --topic {role}=TOPIC). The bag has: {listing or 'no topics'}"
                )
        if "cam0" not in chosen or "cam1" not in chosen:
            missing = "cam0" if "cam0" not in chosen else "cam1"
            try:
                pair = discover_stereo(types, chosen.get("cam0"), chosen.get("cam1"), where)
            except DatasetError as e:
                reason = str(e).removeprefix(f"{where}: ")
                raise DatasetError(
                    f"{self.path}: no topic for {missing} (looked for "
                    f"{', '.join(self.topic_map.candidates(missing))}, then by message type: "
                    f"{reason}; or --topic {missing}=TOPIC). The bag has: "
                    f"{listing or 'no topics'}"
                ) from None
            chosen["cam0"], chosen["cam1"] = pair.left, pair.right
            self._unordered_pair = not pair.ordered
            if pair.ordered:
                self.notes.append(
                    f"stereo pair found by {pair.how}: left {pair.left}, right {pair.right}"
                )
        if not any(r in chosen for r in IMU_ROLES):
            found_imu = discover_imu(types, where)
            for role in IMU_ROLES:
                t = getattr(found_imu, role)
                if t is not None:
                    chosen[role] = t
            if found_imu.how:
                picked = ", ".join(f"{r} {chosen[r]}" for r in IMU_ROLES if r in chosen)
                self.notes.append(f"IMU found by message type ({found_imu.how}): {picked}")
        if "imu" in chosen and ("accel" in chosen or "gyro" in chosen):
            raise DatasetError(
                f"{self.path}: an IMU topic ({chosen['imu']}) and separate accel/gyro topics "
                "were both given; use one or the other"
            )
        if ("accel" in chosen) != ("gyro" in chosen):
            have, need = ("accel", "gyro") if "accel" in chosen else ("gyro", "accel")
            raise DatasetError(
                f"{self.path}: {have} topic {chosen[have]} without a {need} topic (add "
                f"--topic {need}=TOPIC)"
            )
        for cam, info_role in INFO_ROLES.items():
            if info_role not in chosen:
                t = camera_info_topic(chosen[cam], types)
                if t is not None:
                    chosen[info_role] = t
        out: dict[str, list[Any]] = {}
        for role, found in chosen.items():
            conns = list(available[found].connections)
            bad = sorted({c.msgtype for c in conns} - set(ROLE_TYPES[role]))
            if bad:
                raise DatasetError(
                    f"{self.path}: topic {found} ({role}) has message type {', '.join(bad)}; "
                    f"expected {' or '.join(ROLE_TYPES[role])}"
                )
            if role in INFO_ROLES.values():
                self.info_topics[role] = found
            out[role] = conns
            if role not in INFO_ROLES.values():
                self.stats[role] = TopicStats(role, found, conns[0].msgtype)
        if chosen["cam0"] == chosen["cam1"]:
            raise DatasetError(f"{self.path}: cam0 and cam1 both map to {chosen['cam0']}")
        return out

    def _first_message(self, reader: Any, conns: list[Any]) -> Any | None:
        for conn, log_ns, raw in reader.messages(connections=conns):
            return self._deserialize(reader, raw, conn, log_ns)
        return None

    def _static_pass(self, reader: Any, role_conns: dict[str, list[Any]]) -> None:
        """What the bag says about its calibration, read before the index pass: every
        `/tf_static` message, the first CameraInfo of each camera, and the `header.frame_id` of
        the first camera and IMU messages; then cam0/cam1 put in order if discovery could not."""
        tf_conns = [c for c in reader.connections if c.topic == TF_STATIC_TOPIC]
        tf_conns = [c for c in tf_conns if c.msgtype == TF_TYPE]
        if tf_conns:
            for conn, log_ns, raw in reader.messages(connections=tf_conns):
                msg = self._deserialize(reader, raw, conn, log_ns)
                for edge in edges_from_tf_message(msg, TF_STATIC_TOPIC):
                    self.tf.add(edge)
        for cam, info_role in INFO_ROLES.items():
            if info_role in role_conns:
                msg = self._first_message(reader, role_conns[info_role])
                if msg is not None:
                    self.camera_infos[cam] = camera_info_from_msg(msg, self.info_topics[info_role])
        for role in ("cam0", "cam1", *IMU_ROLES):
            if role in role_conns:
                msg = self._first_message(reader, role_conns[role])
                if msg is not None:
                    self.frame_ids[role] = str(msg.header.frame_id).strip().lstrip("/")
        if self._unordered_pair:
            self._order_pair(role_conns)

    def _order_pair(self, role_conns: dict[str, list[Any]]) -> None:
        """cam0 is the left camera: decided by the tf tree (cam1 at +x in cam0's optical
        frame), else by the CameraInfo P (the right camera's P[0, 3] is negative)."""
        a, b = self.stats["cam0"].topic, self.stats["cam1"].topic
        fa, fb = self.frame_ids.get("cam0", ""), self.frame_ids.get("cam1", "")
        x: float | None = None
        how = ""
        if fa and fb and fa != fb and self.tf.connected(fa, fb):
            x = float(self.tf.lookup(fa, fb)[0, 3])  # b's origin in a's frame
            how = "the /tf_static baseline"
        elif "cam0" in self.camera_infos and "cam1" in self.camera_infos:
            x = self.camera_infos["cam0"].Tx - self.camera_infos["cam1"].Tx
            how = "the CameraInfo P[0, 3]"
        if not x:
            raise DatasetError(
                f"{self.path}: cannot tell the left camera from the right between {a} and {b} "
                "(no tf baseline, no P[0, 3]); name them with --topic left=TOPIC "
                "--topic right=TOPIC"
            )
        if x < 0:  # b is on the left: swap the roles
            _swap(self.stats, "cam0", "cam1")
            _swap(self.frame_ids, "cam0", "cam1")
            _swap(self.camera_infos, "cam0", "cam1")
            _swap(role_conns, "cam0", "cam1")
            _swap(self.info_topics, "cam0_info", "cam1_info")
            for role in ("cam0", "cam1"):
                self.stats[role].role = role
            a, b = b, a
        self.notes.append(f"stereo pair: left {a}, right {b} (decided by {how})")

    def _scan(self, show_progress: bool | None) -> None:
        from eurocslam.progress import bar

        imu_t: list[int] = []
        imu_v: list[tuple[float, ...]] = []
        gt_t: list[int] = []
        gt_v: list[tuple[float, ...]] = []
        le_t: list[int] = []
        le_v: list[tuple[float, float, float]] = []
        ac_t: list[int] = []
        ac_v: list[tuple[float, ...]] = []
        gy_t: list[int] = []
        gy_v: list[tuple[float, ...]] = []
        with open_reader(self.path) as reader:
            self.ros2 = bool(reader.is2)
            role_conns = self._resolve_topics(reader)
            self._static_pass(reader, role_conns)
            for info_role in INFO_ROLES.values():  # CameraInfo is read once, not indexed
                role_conns.pop(info_role, None)
            self._conn_role = {id(c): r for r, cs in role_conns.items() for c in cs}
            conns = [c for cs in role_conns.values() for c in cs]
            fast: dict[int, bool] = {}  # connection -> raw fast path verified on its first message
            total = sum(int(c.msgcount) for c in conns)
            pb = bar(total=total or None, desc=f"indexing {self.path.name}", unit="msg",
                     enabled=show_progress)  # fmt: skip
            try:
                for conn, log_ns, raw in reader.messages(connections=conns):
                    pb.update(1)
                    role = self._conn_role[id(conn)]
                    st = self.stats[role]
                    if role in ("cam0", "cam1"):
                        stamp = self._raw_stamp(raw, st.topic, log_ns)
                        if role not in self.image_info:
                            self._first_image(reader, conn, raw, stamp)
                        st.header_ns.append(stamp)  # type: ignore[union-attr]
                        st.log_ns.append(int(log_ns))  # type: ignore[union-attr]
                        continue
                    stamp, vals = self._values(reader, conn, raw, log_ns, fast)
                    st.header_ns.append(stamp)  # type: ignore[union-attr]
                    st.log_ns.append(int(log_ns))  # type: ignore[union-attr]
                    if role == "imu":
                        imu_t.append(stamp)
                        imu_v.append(vals)
                    elif role == "accel":
                        ac_t.append(stamp)
                        ac_v.append(vals)
                    elif role == "gyro":
                        gy_t.append(stamp)
                        gy_v.append(vals)
                    elif role == "groundtruth":
                        gt_t.append(stamp)
                        gt_v.append(vals)
                    else:
                        le_t.append(stamp)
                        le_v.append(vals)  # type: ignore[arg-type]
            finally:
                pb.close()
        for st in self.stats.values():
            st.freeze()
        if "accel" in self.stats:
            self.imu = self._unite_imu(ac_t, ac_v, gy_t, gy_v)
        else:
            self.imu = self._build_imu(imu_t, imu_v)
        self.groundtruth = self._build_groundtruth(gt_t, gt_v)
        self.leica = self._build_leica(le_t, le_v)

    def _values(
        self, reader: Any, conn: Any, raw: bytes | memoryview, log_ns: int, fast: dict[int, bool]
    ) -> tuple[int, tuple[float, ...]]:
        """(header stamp, numbers) of an IMU, ground-truth or Leica message. The raw parser is
        used once it reproduced rosbags' full decoding of the connection's first message."""
        ok = fast.get(id(conn))
        if ok:
            try:
                return fast_values(raw, self.ros2, conn.msgtype)
            except (struct.error, IndexError):
                pass  # a malformed message: the full decoder names the problem
        msg = self._deserialize(reader, raw, conn, log_ns)
        out = stamp_of(msg), message_values(msg, conn.msgtype)
        if ok is None:
            try:
                fast[id(conn)] = fast_values(raw, self.ros2, conn.msgtype) == out
            except (struct.error, IndexError, KeyError):
                fast[id(conn)] = False
        return out

    def _raw_stamp(self, raw: bytes | memoryview, topic: str, log_ns: int) -> int:
        try:
            return header_stamp_ns(raw, self.ros2)
        except (struct.error, IndexError):
            raise DatasetError(
                f"{self.path}: {topic}: message at log time {log_ns} is too short to hold a header"
            ) from None

    def _deserialize(self, reader: Any, raw: bytes | memoryview, conn: Any, log_ns: int) -> Any:
        try:
            return reader.deserialize(raw, conn.msgtype)
        except Exception as e:  # rosbags' serde errors on corrupt messages
            raise DatasetError(
                f"{self.path}: {conn.topic}: cannot decode the {conn.msgtype} message at log time "
                f"{log_ns}: {type(e).__name__}: {e}"
            ) from None

    def _first_image(self, reader: Any, conn: Any, raw: bytes | memoryview, stamp: int) -> None:
        role = self._conn_role[id(conn)]
        msg = self._deserialize(reader, raw, conn, stamp)
        if stamp_of(msg) != stamp:  # guards the raw stamp parser
            raise DatasetError(
                f"{self.path}: {conn.topic}: header stamp parsed from the raw message "
                f"({stamp}) differs from the decoded one ({stamp_of(msg)})"
            )
        if conn.msgtype.endswith("/CompressedImage"):
            img = compressed_msg_to_mono(msg)
            if img is None:
                raise DatasetError(
                    f"{self.path}: {conn.topic}: first image (format '{msg.format}') cannot be "
                    "decoded"
                )
            info = ImageInfo(conn.topic, conn.msgtype, str(msg.format), img.shape[1], img.shape[0])
        else:
            check_encoding(str(msg.encoding), conn.topic)
            info = ImageInfo(conn.topic, conn.msgtype, str(msg.encoding), int(msg.width),
                             int(msg.height))  # fmt: skip
        self.image_info[role] = info

    # ---- arrays ---------------------------------------------------------------------------
    def _stamps(self, role: str, header: list[int]) -> I64:
        """Header stamps, or the log times when any header stamp is unset (zero; with a note)."""
        st = self.stats[role]
        h = np.asarray(header, dtype=np.int64)
        unset = (h == 0) & (st.log_array() != 0)
        if h.size and np.any(unset):
            self.notes.append(
                f"{st.topic}: {int(np.count_nonzero(unset))} of {h.size} messages have a zero "
                "header stamp; using the bag's log time for this topic"
            )
            return st.log_array()
        return h

    def _sorted_unique(self, t: I64, role: str) -> I64:
        topic = self.stats[role].topic
        if t.size and np.any(np.diff(t) < 0):
            self.skips.add("out-of-order timestamps (sorted)", topic)
        order = np.argsort(t, kind="stable")
        ts = t[order]
        keep = np.ones(ts.size, dtype=bool)
        keep[1:] = ts[1:] != ts[:-1]
        for i in np.flatnonzero(~keep)[:1000]:
            self.skips.add(f"duplicate {role} timestamp (dropped)", f"{topic}: {ts[i]}")
        return order[keep]

    def _build_imu(self, t: list[int], v: list[tuple[float, ...]]) -> ImuData:
        if "imu" not in self.stats:  # no IMU topic: a stereo-only input
            cands = ", ".join(self.topic_map.candidates("imu"))
            self.notes.append(
                f"no IMU topic (looked for {cands}): a stereo-only input, runs visual-only"
            )
            return empty_imu()
        topic = self.stats["imu"].topic
        if not t:
            raise DatasetError(f"{self.path}: {topic}: no IMU messages")
        ts = self._stamps("imu", t)
        vals = np.asarray(v, dtype=np.float64)
        if not np.all(np.isfinite(vals)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(vals), axis=1))[0])
            raise DatasetError(f"{self.path}: {topic}: non-finite IMU value at stamp {ts[bad]}")
        idx = self._sorted_unique(ts, "imu")
        vals = vals[idx]
        return ImuData(
            ts[idx], np.ascontiguousarray(vals[:, :3]), np.ascontiguousarray(vals[:, 3:])
        )

    def _unite_imu(
        self,
        ac_t: list[int],
        ac_v: list[tuple[float, ...]],
        gy_t: list[int],
        gy_v: list[tuple[float, ...]],
    ) -> ImuData:
        """Separate accelerometer and gyroscope streams united on the gyro stamps
        (`imu_union`); the accelerometer rotated into the gyro's frame when the tf tree
        relates two different frames."""
        streams = {}
        for role, t, v, cols in (("accel", ac_t, ac_v, slice(3, 6)), ("gyro", gy_t, gy_v,
                                                                      slice(0, 3))):  # fmt: skip
            topic = self.stats[role].topic
            if not t:
                raise DatasetError(f"{self.path}: {topic}: no IMU messages")
            ts = self._stamps(role, t)
            vals = np.asarray(v, dtype=np.float64)[:, cols]
            if not np.all(np.isfinite(vals)):
                bad = int(np.flatnonzero(~np.all(np.isfinite(vals), axis=1))[0])
                raise DatasetError(f"{self.path}: {topic}: non-finite IMU value at stamp {ts[bad]}")
            idx = self._sorted_unique(ts, role)
            streams[role] = (ts[idx], vals[idx])
        fa, fg = self.frame_ids.get("accel", ""), self.frame_ids.get("gyro", "")
        R_gyro_accel = None
        if fa and fg and fa != fg:
            if self.tf.connected(fg, fa):
                T = self.tf.lookup(fg, fa)
                if not np.allclose(T[:3, :3], np.eye(3), atol=1e-12):
                    R_gyro_accel = T[:3, :3]
                if float(np.linalg.norm(T[:3, 3])) > 0.01:
                    self.notes.append(
                        f"accelerometer frame '{fa}' is {np.linalg.norm(T[:3, 3]) * 100:.1f} cm "
                        f"from the gyro's '{fg}': the lever arm is ignored"
                    )
            else:
                self.notes.append(
                    f"accelerometer frame '{fa}' and gyro frame '{fg}' are not related in "
                    "/tf_static: taken as aligned"
                )
        united = unite_imu(*streams["accel"], *streams["gyro"], R_gyro_accel=R_gyro_accel)
        a_t, g_t = streams["accel"][0], streams["gyro"][0]
        self.notes.append(
            f"IMU united from {self.stats['accel'].topic} ({_rate_hz(a_t):.1f} Hz) and "
            f"{self.stats['gyro'].topic} ({_rate_hz(g_t):.1f} Hz): the accelerometer linearly "
            f"interpolated onto the gyro's {len(united.imu)} stamps"
            + (f" ({united.dropped} gyro samples outside the accelerometer's span dropped)"
               if united.dropped else "")
        )  # fmt: skip
        if len(united.imu) == 0:
            raise DatasetError(
                f"{self.path}: {self.stats['accel'].topic} and {self.stats['gyro'].topic} do "
                "not overlap in time"
            )
        return united.imu

    def _rig_from_bag(self) -> StereoRig:
        """The rig from the bag's CameraInfo and /tf_static; EuRoC's built in when the bag
        has no CameraInfo (the image size check then guards against a foreign camera)."""
        have = [c for c in ("cam0", "cam1") if c in self.camera_infos]
        if not have:
            self.calib_source = BUILTIN
            from eurocslam.dataset.calib import default_rig

            return default_rig()
        if len(have) == 1:
            other = "cam1" if have[0] == "cam0" else "cam0"
            raise CalibrationError(
                f"{self.path}: {self.camera_infos[have[0]].topic} gives {have[0]}'s calibration "
                f"but {self.stats[other].topic} has no CameraInfo beside it (name it with "
                f"--topic {other}_info=TOPIC, or pass --calib DIR)"
            )
        cams = []
        for role in ("cam0", "cam1"):
            info = self.image_info.get(role)
            cams.append(
                BagCamera(
                    role=role,
                    image_topic=self.stats[role].topic,
                    frame_id=self.frame_ids.get(role, ""),
                    image_size=(info.width, info.height) if info is not None else None,
                    rate_hz=_rate_hz(self.stats[role].header_array()),
                    info=self.camera_infos[role],
                )
            )
        imu_role = "gyro" if "gyro" in self.stats else "imu"
        imu_frame = None
        imu = None
        if imu_role in self.stats and len(self.imu):
            imu_frame = self.frame_ids.get(imu_role, "")
            if not imu_frame:
                raise CalibrationError(
                    f"{self.path}: {self.stats[imu_role].topic}: the IMU messages have no "
                    "header.frame_id, so the cameras cannot be placed relative to the IMU "
                    "(pass --calib DIR)"
                )
            imu = imu_calibration(_rate_hz(self.imu.t_ns))
        rig = rig_from_camera_infos(cams[0], cams[1], self.tf, imu_frame, imu, self.notes)
        self.calib_source = bag_calibration_name(self.path, imu_frame is not None)
        return rig

    def _apply_imu_noise(self, noise: ImuNoise | None, from_bag: bool) -> None:
        """IMU noise figures from outside the bag (`--imu-calib`, the config's `imu:`) replace
        the calibration's; a rig from the bag's CameraInfo takes EuRoC's for the ones not
        given, with a note."""
        if self.rig.imu is None:
            return
        from eurocslam.dataset.imu_noise import default_imu_noise

        given = noise if noise is not None else ImuNoise()
        if from_bag and self.calib_source != BUILTIN:
            if not given.complete:
                which = "none given" if given.empty else "some not given"
                self.notes.append(
                    f"IMU noise: the bag carries no figures ({which}): using "
                    f"{default_imu_noise().source} (give yours with --imu-calib imu.yaml or "
                    "the imu: section of --config)"
                )
            self.rig = with_imu_noise(self.rig, given.over(default_imu_noise()), self.calib_source)
        elif not given.empty:
            self.rig = with_imu_noise(self.rig, given, given.source)
        if not given.empty:
            self.notes.append(f"IMU noise figures from {given.source}")

    def _build_groundtruth(self, t: list[int], v: list[tuple[float, ...]]) -> GroundTruth | None:
        if "groundtruth" not in self.stats or not t:
            return None
        st = self.stats["groundtruth"]
        ts = self._stamps("groundtruth", t)
        vals = np.asarray(v, dtype=np.float64)
        idx = self._sorted_unique(ts, "groundtruth")
        ts, vals = ts[idx], vals[idx]
        p = vals[:, :3]
        try:
            q_wxyz = normalize_quat(xyzw_to_wxyz(vals[:, 3:7]))
        except ValueError:
            bad = int(np.argmin(np.linalg.norm(vals[:, 3:7], axis=1)))
            raise DatasetError(
                f"{self.path}: {st.topic}: zero quaternion at stamp {ts[bad]}"
            ) from None
        if st.msgtype.endswith("/TransformStamped"):
            self.T_body_gtsensor = gt_sensor_extrinsic(self.calib_dir, st.topic, self.notes)
            if not np.allclose(self.T_body_gtsensor, np.eye(4)):
                # T_gtworld_body = T_gtworld_sensor @ inv(T_body_sensor)
                T = make_T(quat_wxyz_to_rot(q_wxyz), p) @ inv_T(self.T_body_gtsensor)
                p = T[:, :3, 3].copy()
                q_wxyz = rot_to_quat_wxyz(T[:, :3, :3])
        return GroundTruth(t_ns=ts, p=np.ascontiguousarray(p), q_wxyz=q_wxyz)

    def _build_leica(
        self, t: list[int], v: list[tuple[float, float, float]]
    ) -> PositionData | None:
        if "leica" not in self.stats or not t:
            return None
        ts = self._stamps("leica", t)
        vals = np.asarray(v, dtype=np.float64)
        idx = self._sorted_unique(ts, "leica")
        return PositionData(ts[idx], vals[idx].copy())

    # ---- cameras --------------------------------------------------------------------------
    def _choose_camera_stamps(self) -> str:
        c0, c1 = self.stats["cam0"], self.stats["cam1"]
        if c0.count == 0 or c1.count == 0:
            empty = c0.topic if c0.count == 0 else c1.topic
            raise DatasetError(f"{self.path}: {empty}: no image messages")
        zeros = c0.zero_stamps + c1.zero_stamps
        if zeros:
            self.notes.append(
                f"{zeros} camera messages have a zero header stamp; stereo pairs are joined on "
                "the bag's log time instead"
            )
            return "log time"
        return "header stamp"

    def camera_stamps(self, role: str) -> I64:
        """A camera's stamps in bag order, from the stamp source the pairing uses."""
        st = self.stats[role]
        return st.log_array() if self.stamp_source == "log time" else st.header_array()

    def _camera_map(self, role: str) -> dict[int, int]:
        st = self.stats[role]
        return camera_map(role, st.topic, self.camera_stamps(role), st.log_array(), self.skips)

    def _join_cameras(self) -> list[BagEntry]:
        c0, c1 = self._camera_map("cam0"), self._camera_map("cam1")
        c1, self._cam1_alias, note = snap_cam1(c0, c1, self.rig.cam0.rate_hz)
        if note is not None:
            self.notes.append(note)
        return join_cameras(c0, c1, self.skips)

    def _check_image_sizes(self) -> None:
        for role in ("cam0", "cam1"):
            info = self.image_info.get(role)
            cam = getattr(self.rig, role)
            if info is None or (info.width, info.height) == (cam.width, cam.height):
                continue
            if self.calib_source == BUILTIN:
                raise CalibrationError(
                    f"{self.path}: {info.topic}: images are {info.width}x{info.height} and the bag "
                    f"carries no calibration; the built-in EuRoC calibration is for "
                    f"{cam.width}x{cam.height}. Pass --calib DIR (a folder with cam0/, cam1/, "
                    "imu0/ sensor.yaml files)"
                )
            raise CalibrationError(
                f"{self.path}: {info.topic}: images are {info.width}x{info.height} but the "
                f"calibration ({self.calib_source}) says {cam.width}x{cam.height}"
            )
        if self.calib_source == BUILTIN:
            self.notes.append(
                f"{self.path.name} carries no calibration: using the built-in EuRoC cam0/cam1/imu0 "
                "calibration (pass --calib DIR for another)"
            )

    # ---- SequenceSource -------------------------------------------------------------------
    @property
    def frame_times(self) -> I64:
        return np.array([e.t_ns for e in self.frame_index], dtype=np.int64)

    def frames(
        self,
        *,
        include_incomplete: bool = False,
        t_start_ns: int | None = None,
        t_end_ns: int | None = None,
    ) -> Iterator[StereoFrame]:
        """Yield stereo frames in stamp order, decoding each image when its pair is complete."""
        sel = [
            e
            for e in self.frame_index
            if (t_start_ns is None or e.t_ns >= t_start_ns)
            and (t_end_ns is None or e.t_ns <= t_end_ns)
            and (include_incomplete or (e.has_left and e.has_right))
        ]
        if not sel:
            return
        pos = {e.t_ns: i for i, e in enumerate(sel)}
        start = min(e.log_ns for e in sel)
        use_log = self.stamp_source == "log time"
        pending: dict[int, list[Any]] = {}
        next_i = 0
        with open_reader(self.path) as reader:
            cam_conns = [c for c in reader.connections if self._role_of(c) in ("cam0", "cam1")]
            for conn, log_ns, raw in reader.messages(connections=cam_conns, start=start):
                side = 0 if self._role_of(conn) == "cam0" else 1
                t = int(log_ns) if use_log else header_stamp_ns(raw, self.ros2)
                if side == 1:
                    t = self._cam1_alias.get(t, t)
                i = pos.get(t)
                if i is None or i < next_i:
                    continue  # outside the selection, or a dropped duplicate
                slot = pending.setdefault(t, [None, None])
                if slot[side] is None:
                    slot[side] = (conn, raw)
                while next_i < len(sel):
                    e = sel[next_i]
                    s = pending.get(e.t_ns)
                    if s is None or (e.has_left and s[0] is None) or (e.has_right and s[1] is None):
                        break
                    del pending[e.t_ns]
                    next_i += 1
                    frame = self._make_frame(reader, e, s, include_incomplete)
                    if frame is not None:
                        yield frame
                if next_i == len(sel):
                    return
            # messages the index saw but this pass did not (a bag changed on disk)
            for e in sel[next_i:]:
                s = pending.pop(e.t_ns, [None, None])
                self.skips.add("camera message not found on re-read", str(e.t_ns))
                frame = self._make_frame(reader, e, s, include_incomplete)
                if frame is not None:
                    yield frame

    def _role_of(self, conn: Any) -> str | None:
        topic = conn.topic
        for role in ("cam0", "cam1"):
            if self.stats[role].topic == topic:
                return role
        return None

    def _make_frame(
        self, reader: Any, e: BagEntry, slot: list[Any], include_incomplete: bool
    ) -> StereoFrame | None:
        left = self._decode(reader, slot[0], e.t_ns) if slot[0] is not None else None
        right = self._decode(reader, slot[1], e.t_ns) if slot[1] is not None else None
        if (left is None or right is None) and not include_incomplete:
            return None
        return StereoFrame(e.t_ns, left, right)

    def _decode(self, reader: Any, item: tuple[Any, bytes], t_ns: int) -> U8 | None:
        conn, raw = item
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:  # a corrupt message: count it, like an unreadable PNG
            self.skips.add("undecodable image message", f"{conn.topic}: {t_ns}")
            return None
        if conn.msgtype.endswith("/CompressedImage"):
            img = compressed_msg_to_mono(msg)
        else:
            img = image_msg_to_mono(msg, conn.topic)
        if img is None:
            self.skips.add("unreadable image message", f"{conn.topic}: {t_ns}")
        return img
