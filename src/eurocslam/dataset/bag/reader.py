"""`BagSequence`: a ROS 1 bag, ROS 2 bag (folder, `.db3`) or MCAP as a `SequenceSource`.

One pass at opening indexes the bag (IMU, ground truth and Leica decoded into arrays; camera
messages give only their stamps); `frames()` streams the camera messages again and decodes each
pair as it completes. See the package docstring for stamps, calibration and ground truth.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.bag.arrays import ArrayBuilder
from eurocslam.dataset.bag.calibration import (
    BUILTIN,
    apply_imu_noise,
    resolve_calibration,
    rig_from_bag,
)
from eurocslam.dataset.bag.files import bag_kind, is_bag_path, open_reader
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
from eurocslam.dataset.bag.roles import choose_roles
from eurocslam.dataset.bag.static import BagStatic, left_is_first, read_static, swap
from eurocslam.dataset.bag.stats import ImageInfo, TopicStats, rate_hz
from eurocslam.dataset.bag.topics import INFO_ROLES, ROLE_TYPES, TopicMap
from eurocslam.dataset.calib import StereoRig, calib_folder
from eurocslam.dataset.imu_noise import NoiseFigures
from eurocslam.dataset.types import I64, U8, SkipReport, StereoFrame, empty_imu
from eurocslam.errors import CalibrationError, DatasetError
from eurocslam.geometry import F64


class BagSequence:
    """A ROS 1 bag, ROS 2 bag (folder, `.db3`) or MCAP. Implements `SequenceSource`."""

    def __init__(
        self,
        path: Path | str,
        rig: StereoRig | None = None,
        *,
        calib: Path | str | None = None,
        topics: TopicMap | Mapping[str, str] | None = None,
        imu_noise: NoiseFigures | None = None,
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
        self.info_topics: dict[str, str] = {}  # cam0_info / cam1_info -> topic
        # what the bag says about its calibration: tf tree, CameraInfo, frame ids
        self.static = BagStatic()
        explicit, self.calib_source = resolve_calibration(
            self.path, rig, self.calib_dir, self.notes
        )
        self.T_body_gtsensor: F64 = np.eye(4)
        self._scan(show_progress)
        if explicit is None:
            explicit, self.calib_source = self._rig_from_bag()
        self.rig: StereoRig = apply_imu_noise(
            explicit, imu_noise, self.calib_source.startswith("CameraInfo"), self.calib_source,
            self.notes,
        )  # fmt: skip
        self.stamp_source = self._choose_camera_stamps()
        self.frame_index = self._join_cameras()
        self._check_image_sizes()

    # ---- the index pass -------------------------------------------------------------------
    def _resolve_topics(self, reader: Any) -> dict[str, list[Any]]:
        """Each role's connections (`roles.choose_roles`), their message types checked."""
        available = {name: info for name, info in reader.topics.items()}
        self.bag_topics = {n: (str(i.msgtype), int(i.msgcount)) for n, i in available.items()}
        choice = choose_roles(self.bag_topics, self.topic_map, str(self.path))
        self.notes.extend(choice.notes)
        self._unordered_pair = choice.unordered
        out: dict[str, list[Any]] = {}
        for role, found in choice.topics.items():
            conns = list(available[found].connections)
            bad = sorted({c.msgtype for c in conns} - set(ROLE_TYPES[role]))
            if bad:
                raise DatasetError(
                    f"{self.path}: topic {found} ({role}) has message type {', '.join(bad)}; "
                    f"expected {' or '.join(ROLE_TYPES[role])}"
                )
            out[role] = conns
            if role in INFO_ROLES.values():
                self.info_topics[role] = found
            else:
                self.stats[role] = TopicStats(role, found, conns[0].msgtype)
        return out

    def _read_static(self, reader: Any, role_conns: dict[str, list[Any]]) -> None:
        """The tf tree, CameraInfo and frame ids (`static`); left and right put in order when
        the pair was found by type alone."""
        topics = {**{r: st.topic for r, st in self.stats.items()}, **self.info_topics}
        self.static = read_static(
            reader, role_conns, topics, lambda raw, c, t: self._deserialize(reader, raw, c, t)
        )
        if not self._unordered_pair:
            return
        a, b = self.stats["cam0"].topic, self.stats["cam1"].topic
        first_is_left, how = left_is_first(self.static, a, b, str(self.path))
        if not first_is_left:
            swap(self.stats, "cam0", "cam1")
            swap(role_conns, "cam0", "cam1")
            swap(self.info_topics, "cam0_info", "cam1_info")
            self.static.swap_cameras()
            for role in ("cam0", "cam1"):
                self.stats[role].role = role
            a, b = b, a
        self.notes.append(f"stereo pair: left {a}, right {b} (decided by {how})")

    def _rig_from_bag(self) -> tuple[StereoRig, str]:
        cams = {
            r: (self.stats[r].topic, self.image_info.get(r), rate_hz(self.stats[r].header_array()))
            for r in ("cam0", "cam1")
        }
        role = "gyro" if "gyro" in self.stats else "imu"
        imu = (self.stats[role].topic, rate_hz(self.imu.t_ns)) if len(self.imu) else None
        return rig_from_bag(self.path, self.static, cams, imu, self.notes)

    def _scan(self, show_progress: bool | None) -> None:
        from eurocslam.progress import bar

        imu_t: list[int] = []
        imu_v: list[tuple[float, ...]] = []
        gt_t: list[int] = []
        gt_v: list[tuple[float, ...]] = []
        le_t: list[int] = []
        le_v: list[tuple[float, ...]] = []
        ac_t: list[int] = []
        ac_v: list[tuple[float, ...]] = []
        gy_t: list[int] = []
        gy_v: list[tuple[float, ...]] = []
        with open_reader(self.path) as reader:
            self.ros2 = bool(reader.is2)
            role_conns = self._resolve_topics(reader)
            self._read_static(reader, role_conns)
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
                        le_v.append(vals)
            finally:
                pb.close()
        for st in self.stats.values():
            st.freeze()
        arrays = ArrayBuilder(self.path, self.stats, self.notes, self.skips)
        if "accel" in self.stats:
            frames, tf = self.static.frame_ids, self.static.tf
            self.imu = arrays.united_imu((ac_t, ac_v), (gy_t, gy_v), frames, tf)
        elif "imu" in self.stats:
            self.imu = arrays.imu(imu_t, imu_v)
        else:  # no IMU topic: a stereo-only input
            cands = ", ".join(self.topic_map.candidates("imu"))
            self.notes.append(
                f"no IMU topic (looked for {cands}): a stereo-only input, runs visual-only"
            )
            self.imu = empty_imu()
        self.groundtruth, self.T_body_gtsensor = arrays.groundtruth(gt_t, gt_v, self.calib_dir)
        self.leica = arrays.leica(le_t, le_v)

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
