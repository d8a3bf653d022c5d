"""The arrays a bag's index pass builds from the messages it decoded: the IMU (one stream, or
accelerometer and gyroscope united by `imu_union`), the ground truth and the Leica positions.

Stamps are the header stamps, or a topic's log times when any of its header stamps is unset
(with a note); out-of-order messages are sorted and duplicate stamps dropped, both counted."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eurocslam.dataset.bag.calibration import gt_sensor_extrinsic
from eurocslam.dataset.bag.imu_union import unite_imu
from eurocslam.dataset.bag.stats import TopicStats, rate_hz
from eurocslam.dataset.bag.tf_tree import TfTree
from eurocslam.dataset.types import I64, GroundTruth, ImuData, PositionData, SkipReport
from eurocslam.errors import DatasetError
from eurocslam.geometry import (
    F64,
    inv_T,
    make_T,
    normalize_quat,
    quat_wxyz_to_rot,
    rot_to_quat_wxyz,
    xyzw_to_wxyz,
)

Rows = list[tuple[float, ...]]


class ArrayBuilder:
    """Builds a bag's arrays; notes and skips go to the reader's lists."""

    def __init__(
        self, path: Path, stats: dict[str, TopicStats], notes: list[str], skips: SkipReport
    ) -> None:
        self.path, self.stats, self.notes, self.skips = path, stats, notes, skips

    def stamps(self, role: str, header: list[int]) -> I64:
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

    def sorted_unique(self, t: I64, role: str) -> I64:
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

    def _imu_rows(self, role: str, t: list[int], v: Rows, cols: slice) -> tuple[I64, F64]:
        """Sorted unique stamps and the finite values (columns `cols`) of an IMU topic."""
        topic = self.stats[role].topic
        if not t:
            raise DatasetError(f"{self.path}: {topic}: no IMU messages")
        ts = self.stamps(role, t)
        vals = np.asarray(v, dtype=np.float64)[:, cols]
        if not np.all(np.isfinite(vals)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(vals), axis=1))[0])
            raise DatasetError(f"{self.path}: {topic}: non-finite IMU value at stamp {ts[bad]}")
        idx = self.sorted_unique(ts, role)
        return ts[idx], vals[idx]

    def imu(self, t: list[int], v: Rows) -> ImuData:
        """One IMU topic's (gyro, accel) rows."""
        ts, vals = self._imu_rows("imu", t, v, slice(0, 6))
        return ImuData(ts, np.ascontiguousarray(vals[:, :3]), np.ascontiguousarray(vals[:, 3:]))

    def united_imu(
        self,
        accel: tuple[list[int], Rows],
        gyro: tuple[list[int], Rows],
        frames: dict[str, str],
        tf: TfTree,
    ) -> ImuData:
        """Separate accelerometer and gyroscope topics united on the gyro stamps
        (`imu_union`); the accelerometer rotated into the gyro's frame when the tf tree
        relates two different frames (`frames`: the topics' header frame_ids)."""
        a_t, a_v = self._imu_rows("accel", *accel, slice(3, 6))
        g_t, g_v = self._imu_rows("gyro", *gyro, slice(0, 3))
        fa, fg = frames.get("accel", ""), frames.get("gyro", "")
        R_gyro_accel = None
        if fa and fg and fa != fg:
            if tf.connected(fg, fa):
                T = tf.lookup(fg, fa)
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
        united = unite_imu(a_t, a_v, g_t, g_v, R_gyro_accel=R_gyro_accel)
        at, gt = self.stats["accel"].topic, self.stats["gyro"].topic
        if len(united.imu) == 0:
            raise DatasetError(f"{self.path}: {at} and {gt} do not overlap in time")
        dropped = (
            f" ({united.dropped} gyro samples outside the accelerometer's span dropped)"
            if united.dropped
            else ""
        )
        self.notes.append(
            f"IMU united from {at} ({rate_hz(a_t):.1f} Hz) and {gt} ({rate_hz(g_t):.1f} Hz): "
            f"the accelerometer linearly interpolated onto the gyro's {len(united.imu)} "
            f"stamps{dropped}"
        )
        return united.imu

    def groundtruth(
        self, t: list[int], v: Rows, calib_dir: Path | None
    ) -> tuple[GroundTruth | None, F64]:
        """The body poses, and `T_body_gtsensor` (a raw Vicon marker pose is moved to the body
        frame with it; the identity for body poses)."""
        T_body_sensor: F64 = np.eye(4)
        if "groundtruth" not in self.stats or not t:
            return None, T_body_sensor
        st = self.stats["groundtruth"]
        ts = self.stamps("groundtruth", t)
        vals = np.asarray(v, dtype=np.float64)
        idx = self.sorted_unique(ts, "groundtruth")
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
            T_body_sensor = gt_sensor_extrinsic(calib_dir, st.topic, self.notes)
            if not np.allclose(T_body_sensor, np.eye(4)):
                # T_gtworld_body = T_gtworld_sensor @ inv(T_body_sensor)
                T = make_T(quat_wxyz_to_rot(q_wxyz), p) @ inv_T(T_body_sensor)
                p = T[:, :3, 3].copy()
                q_wxyz = rot_to_quat_wxyz(T[:, :3, :3])
        return GroundTruth(t_ns=ts, p=np.ascontiguousarray(p), q_wxyz=q_wxyz), T_body_sensor

    def leica(self, t: list[int], v: Rows) -> PositionData | None:
        if "leica" not in self.stats or not t:
            return None
        ts = self.stamps("leica", t)
        vals = np.asarray(v, dtype=np.float64)
        idx = self.sorted_unique(ts, "leica")
        return PositionData(ts[idx], vals[idx].copy())
