"""The converted EuRoC sensor streams as ROS 2 messages, written in log-time order in one pass.

Used by `eurocslam convert` and by `eurocslam run` (which interleaves its own SLAM messages and
reuses the images it has already decoded, or in png mode their 8-bit grey PNG files). How to use it:

    streams = SensorStreams(source, StreamOptions(...))   # any SequenceSource
    streams.write_static(sink)              # /tf_static at streams.t0_ns (first message time)
    for frame in source.frames(include_incomplete=True, ...):
        streams.write_frame(sink, frame)    # IMU/GT/leica up to frame.t_ns, then the images
        ... write your own messages stamped frame.t_ns (they may follow directly) ...
    streams.finish(sink)                    # the rest of IMU / ground truth up to the end

`write_frame` first calls `write_until(sink, frame.t_ns)`, so everything this object writes is in
non-decreasing log time and a caller that writes its per-frame outputs at times >= frame.t_ns
right after `write_frame` needs no reordering. Producers whose outputs lag behind (e.g. a
smoother publishing older poses) should write through `io.sink.ReorderBuffer` instead.
`encode_frame` / `encode_files` build a frame's image messages without writing them (thread-safe,
for a decode/encode thread pool) and `write_frame` accepts their `EncodedFrame` too.

Topics and frames (also in README "MCAP topics"):

| topic | type | frame_id |
|---|---|---|
| /tf_static | tf2_msgs/TFMessage | body -> imu0, cam0, cam1 (T_BS of each sensor.yaml) |
| /cam0/image_raw, /cam1/image_raw | sensor_msgs/Image mono8 | cam0 / cam1 |
| /cam0/image_raw/compressed, ... | sensor_msgs/CompressedImage (png/jpeg mode) | cam0 / cam1 |
| /cam0/camera_info, /cam1/camera_info | sensor_msgs/CameraInfo (K, D, stereo R/P) | cam0 / cam1 |
| /imu0 | sensor_msgs/Imu | imu0 |
| /groundtruth/pose | geometry_msgs/PoseStamped (pose of the body) | gt_world |
| /groundtruth/path | nav_msgs/Path, 1 Hz, poses at 10 Hz | gt_world |
| /tf | tf2_msgs/TFMessage gt_world -> gt_body | gt_world |
| /leica0 | geometry_msgs/PointStamped (prism position) | gt_world |

`gt_body` is the ground-truth pose of `body` (the IMU frame); it is a separate tree from the SLAM
`world -> body`, so both can live in one file. A stereo-only source (no IMU rows or no IMU
calibration) has no /imu0 topic and no imu0 in /tf_static.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.dataset.images import read_image
from eurocslam.dataset.types import SequenceSource, StereoFrame, has_imu
from eurocslam.errors import OutputError
from eurocslam.io import ros2, ros2_batch, ros2_calib
from eurocslam.io.sink import Sink

IMAGE_MODES = ("raw", "png", "jpeg")
FRAME_BODY = "body"
FRAME_GT_WORLD = "gt_world"
FRAME_GT_BODY = "gt_body"

TF_STATIC = "/tf_static"
TF = "/tf"
IMU_TOPIC = "/imu0"
GT_POSE = "/groundtruth/pose"
GT_PATH = "/groundtruth/path"
LEICA = "/leica0"
CAMS = ("cam0", "cam1")
WINDOW_NS = 2_000_000_000  # high-rate streams are encoded in batches of at most this much time


def image_topic(cam: str, mode: str) -> str:
    return f"/{cam}/image_raw" if mode == "raw" else f"/{cam}/image_raw/compressed"


def all_topics(mode: str = "raw", imu: bool = True) -> tuple[str, ...]:
    """Every topic of a conversion (`imu`: the source has an IMU)."""
    return (
        TF_STATIC,
        *(image_topic(c, mode) for c in CAMS),
        *(f"/{c}/camera_info" for c in CAMS),
        *((IMU_TOPIC,) if imu else ()),
        GT_POSE,
        GT_PATH,
        TF,
        LEICA,
    )


@dataclass(frozen=True)
class StreamOptions:
    """`topics`: None for all, else a subset of `all_topics(images)` (in png/jpeg mode
    '/camN/image_raw' also selects '/camN/image_raw/compressed'). Times are int64 ns, inclusive.
    `rectify_alpha`, `rectify_fov_deg`, `rectify_size`: the stereo rectification the CameraInfo
    R/P describe (a SLAM run passes the frontend's, so they match the images it tracked)."""

    topics: frozenset[str] | None = None
    images: str = "raw"
    jpeg_quality: int = 95
    t_start_ns: int | None = None
    t_end_ns: int | None = None
    gt_path_period_ns: int = 1_000_000_000
    gt_path_pose_period_ns: int = 100_000_000
    rectify_alpha: float = 0.0
    rectify_fov_deg: float | None = None  # None: camera.DEFAULT_RECTIFY_FOV_DEG
    rectify_size: str = "image"


@dataclass(frozen=True)
class EncodedFrame:
    """A stereo frame's image messages, CDR-encoded (None when that image is absent/skipped)."""

    t_ns: int
    cam0: bytes | None
    cam1: bytes | None


def _png_is_mono8(data: bytes) -> bool:
    """True for a PNG whose IHDR says 8-bit greyscale, non-interlaced (pass through as is)."""
    return (
        len(data) > 33
        and data[:8] == b"\x89PNG\r\n\x1a\n"
        and data[12:16] == b"IHDR"
        and data[24] == 8
        and data[25] == 0
        and data[28] == 0
    )


class SensorStreams:
    def __init__(self, source: SequenceSource, options: StreamOptions | None = None) -> None:
        opt = options or StreamOptions()
        if opt.images not in IMAGE_MODES:
            raise OutputError(f"image mode '{opt.images}' unknown; choose raw, png or jpeg")
        self.source = source
        self.opt = opt
        self.mode = opt.images
        self.has_imu = has_imu(source)
        known = set(all_topics(opt.images, self.has_imu))
        if opt.topics is None:
            self.topics = frozenset(known)
        else:
            sel = set()
            for t in opt.topics:
                if opt.images != "raw" and t in ("/cam0/image_raw", "/cam1/image_raw"):
                    t = t + "/compressed"
                if t not in known:
                    raise OutputError(
                        f"unknown topic '{t}'; topics of this conversion: "
                        + ", ".join(sorted(known))
                    )
                sel.add(t)
            self.topics = frozenset(sel)
        lo = opt.t_start_ns if opt.t_start_ns is not None else np.iinfo(np.int64).min
        hi = opt.t_end_ns if opt.t_end_ns is not None else np.iinfo(np.int64).max
        self._lo, self._hi = int(lo), int(hi)

        rig = source.rig
        self.infos = dict(
            zip(
                CAMS,
                ros2_calib.stereo_camera_infos(
                    rig, opt.rectify_alpha, opt.rectify_fov_deg, opt.rectify_size
                ),
                strict=True,
            )
        )
        self.static_transforms = [
            (FRAME_BODY, "cam0", rig.cam0.T_body_cam),
            (FRAME_BODY, "cam1", rig.cam1.T_body_cam),
        ]
        self.gyro_cov, self.accel_cov = np.zeros((3, 3)), np.zeros((3, 3))
        if self.has_imu:
            assert rig.imu is not None
            self.gyro_cov, self.accel_cov = ros2_calib.imu_covariances(rig.imu)
            self.static_transforms.insert(0, (FRAME_BODY, "imu0", rig.imu.T_body_imu))

        # time series, cropped to [lo, hi]
        def crop(t: np.ndarray) -> slice:
            return slice(int(np.searchsorted(t, lo, "left")), int(np.searchsorted(t, hi, "right")))

        imu = source.imu
        s = crop(imu.t_ns) if IMU_TOPIC in self.topics else slice(0, 0)
        self._imu_t, self._imu_g, self._imu_a = imu.t_ns[s], imu.gyro[s], imu.accel[s]
        gt = source.groundtruth
        want_gt = bool({GT_POSE, GT_PATH, TF} & self.topics)
        if gt is not None and len(gt) and want_gt:
            s = crop(gt.t_ns)
            self._gt_t = gt.t_ns[s]
            self._gt_pose7 = (
                np.concatenate([gt.p[s], gt.q_wxyz[s][:, [1, 2, 3, 0]]], axis=1)
                if self._gt_t.size
                else np.zeros((0, 7))
            )
        else:
            self._gt_t, self._gt_pose7 = np.zeros(0, np.int64), np.zeros((0, 7))
        le = source.leica
        if le is not None and LEICA in self.topics:
            s = crop(le.t_ns)
            self._le_t, self._le_p = le.t_ns[s], le.p[s]
        else:
            self._le_t, self._le_p = np.zeros(0, np.int64), np.zeros((0, 3))
        ft = np.asarray(source.frame_times, dtype=np.int64)
        ft = ft[(ft >= lo) & (ft <= hi)]
        firsts = [int(a[0]) for a in (self._imu_t, self._gt_t, self._le_t, ft) if a.size]
        lasts = [int(a[-1]) for a in (self._imu_t, self._gt_t, self._le_t, ft) if a.size]
        if not firsts:
            lo_txt = "start" if opt.t_start_ns is None else opt.t_start_ns
            hi_txt = "end" if opt.t_end_ns is None else opt.t_end_ns
            raise OutputError(
                f"{source.name}: no data in the selected time range / topics "
                f"({lo_txt} .. {hi_txt} ns)"
            )
        self.t0_ns = min(firsts)
        self.t_last_ns = max(lasts)
        self.n_frames = int(ft.size)

        # cursors
        self._i_imu = self._i_gt = self._i_le = 0
        self._path_t: list[int] = []
        self._path_p: list[np.ndarray] = []
        self._next_path_ns = int(self._gt_t[0]) if self._gt_t.size else 0
        self._next_path_pose_ns = self._next_path_ns
        self._static_written = False
        self._written_until: int | None = None

    # ---- images -------------------------------------------------------------------------------
    def _image_msg(self, cam: str, t_ns: int, img: np.ndarray | None, raw: bytes | None) -> bytes:
        import cv2

        if self.mode == "raw":
            assert img is not None
            return ros2.image(t_ns, cam, img)
        if self.mode == "png":
            if raw is not None and _png_is_mono8(raw):
                return ros2.compressed_image(t_ns, cam, "png", raw)
            assert img is not None
            ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
            if not ok:
                raise OutputError(f"PNG encoding failed for {cam} at t={t_ns} ns")
            return ros2.compressed_image(t_ns, cam, "png", buf.tobytes())
        assert img is not None
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.opt.jpeg_quality])
        if not ok:
            raise OutputError(f"JPEG encoding failed for {cam} at t={t_ns} ns")
        return ros2.compressed_image(t_ns, cam, "jpeg", buf.tobytes())

    def _wants(self, cam: str) -> bool:
        return image_topic(cam, self.mode) in self.topics

    def _file_bytes(self, path: Path | None) -> bytes | None:
        """An image file's bytes where png mode may pass them through (None: not png mode, no
        file, or unreadable)."""
        if self.mode != "png" or path is None:
            return None
        try:
            return path.read_bytes()
        except OSError:
            return None

    def encode_frame(self, frame: StereoFrame) -> EncodedFrame:
        """Image messages of an already-decoded frame (thread-safe). In png mode an 8-bit grey
        PNG file is passed through as it is, not encoded again (7 ms per EuRoC image)."""
        msgs = []
        for cam, img, path in (
            ("cam0", frame.left, frame.left_path),
            ("cam1", frame.right, frame.right_path),
        ):
            msgs.append(
                self._image_msg(cam, frame.t_ns, img, self._file_bytes(path))
                if img is not None and self._wants(cam)
                else None
            )
        return EncodedFrame(frame.t_ns, msgs[0], msgs[1])

    def encode_files(
        self, t_ns: int, left: Path | None, right: Path | None
    ) -> tuple[EncodedFrame, list[Path]]:
        """Read/decode a frame's image files and build its messages (thread-safe; for a pool).
        Returns the messages and the files that could not be read (the caller counts them).
        In png mode an 8-bit grey PNG is passed through without decoding."""
        msgs: list[bytes | None] = []
        bad: list[Path] = []
        for cam, p in (("cam0", left), ("cam1", right)):
            if p is None or not self._wants(cam):
                msgs.append(None)
                continue
            raw = self._file_bytes(p)
            if raw is not None and _png_is_mono8(raw):
                msgs.append(ros2.compressed_image(t_ns, cam, "png", raw))
                continue
            img = read_image(p)
            if img is None:
                bad.append(p)
                msgs.append(None)
                continue
            msgs.append(self._image_msg(cam, t_ns, img, None))
        return EncodedFrame(t_ns, msgs[0], msgs[1]), bad

    # ---- writing ------------------------------------------------------------------------------
    def write_static(self, sink: Sink) -> None:
        """/tf_static, stamped and logged at t0_ns (at or before every other message)."""
        if self._static_written:
            return
        self._static_written = True
        if TF_STATIC in self.topics:
            trs = [ros2.Transform(self.t0_ns, p, c, T) for p, c, T in self.static_transforms]
            sink.write(TF_STATIC, ros2.TF_MESSAGE, self.t0_ns, ros2.tf_message(trs))

    def write_frame(self, sink: Sink, frame: StereoFrame | EncodedFrame) -> None:
        """Everything up to the frame's time, then its images and camera_info."""
        t = int(frame.t_ns)
        if t < self._lo or t > self._hi:
            return
        enc = frame if isinstance(frame, EncodedFrame) else self.encode_frame(frame)
        self.write_until(sink, t)
        for cam, msg in (("cam0", enc.cam0), ("cam1", enc.cam1)):
            if msg is None:
                continue
            topic = image_topic(cam, self.mode)
            sink.write(topic, ros2.IMAGE if self.mode == "raw" else ros2.COMPRESSED_IMAGE, t, msg)
            if f"/{cam}/camera_info" in self.topics:
                sink.write(
                    f"/{cam}/camera_info",
                    ros2.CAMERA_INFO,
                    t,
                    ros2_calib.camera_info(t, cam, self.infos[cam]),
                )

    def write_until(self, sink: Sink, t_ns: int) -> None:
        """IMU, ground truth, path and leica messages with log time <= t_ns, merged in order.
        Encoded in vectorised batches of at most `WINDOW_NS` of data (bounded memory)."""
        self.write_static(sink)
        t_ns = min(int(t_ns), self._hi)
        while True:
            nxt = self._next_pending_ns()
            if nxt is None or nxt > t_ns:
                break
            self._write_window(sink, min(t_ns, nxt + WINDOW_NS))
        self._written_until = t_ns

    def _next_pending_ns(self) -> int | None:
        c = [
            int(a[i])
            for a, i in (
                (self._imu_t, self._i_imu),
                (self._gt_t, self._i_gt),
                (self._le_t, self._i_le),
            )
            if i < a.size
        ]
        return min(c) if c else None

    def _write_window(self, sink: Sink, t_ns: int) -> None:
        i0, g0, l0 = self._i_imu, self._i_gt, self._i_le
        i1 = int(np.searchsorted(self._imu_t, t_ns, "right"))
        g1 = int(np.searchsorted(self._gt_t, t_ns, "right"))
        l1 = int(np.searchsorted(self._le_t, t_ns, "right"))
        self._i_imu, self._i_gt, self._i_le = max(i0, i1), max(g0, g1), max(l0, l1)
        imu_msgs = (
            ros2_batch.imu_batch(
                self._imu_t[i0:i1],
                "imu0",
                self._imu_g[i0:i1],
                self._imu_a[i0:i1],
                self.gyro_cov,
                self.accel_cov,
            )
            if i1 > i0
            else []
        )
        gt_t, gt_p = self._gt_t[g0:g1], self._gt_pose7[g0:g1]
        pose_msgs = (
            ros2_batch.pose_stamped_batch(gt_t, FRAME_GT_WORLD, gt_p)
            if g1 > g0 and GT_POSE in self.topics
            else []
        )
        tf_msgs = (
            ros2_batch.tf_batch(gt_t, FRAME_GT_WORLD, FRAME_GT_BODY, gt_p)
            if g1 > g0 and TF in self.topics
            else []
        )
        # merge the three streams by time (stable: IMU, then ground truth, then leica)
        times = np.concatenate([self._imu_t[i0:i1], gt_t, self._le_t[l0:l1]])
        kinds = np.concatenate(
            [np.zeros(i1 - i0, np.int8), np.ones(g1 - g0, np.int8), np.full(l1 - l0, 2, np.int8)]
        )
        local = np.concatenate([np.arange(i1 - i0), np.arange(g1 - g0), np.arange(l1 - l0)])
        order = np.lexsort((kinds, times))
        for t, kind, k in zip(
            times[order].tolist(), kinds[order].tolist(), local[order].tolist(), strict=True
        ):
            if kind == 0:
                sink.write(IMU_TOPIC, ros2.IMU, t, imu_msgs[k])
            elif kind == 1:
                if pose_msgs:
                    sink.write(GT_POSE, ros2.POSE_STAMPED, t, pose_msgs[k])
                if tf_msgs:
                    sink.write(TF, ros2.TF_MESSAGE, t, tf_msgs[k])
                if GT_PATH in self.topics:
                    self._path_step(sink, t, gt_p[k])
            else:
                sink.write(
                    LEICA,
                    ros2.POINT_STAMPED,
                    t,
                    ros2.point_stamped(t, FRAME_GT_WORLD, self._le_p[l0 + k]),
                )

    def _path_step(self, sink: Sink, t: int, p7: np.ndarray) -> None:
        """Collect path poses at `gt_path_pose_period_ns`; publish at most once per period."""
        if t >= self._next_path_pose_ns:
            self._path_t.append(t)
            self._path_p.append(p7)
            self._next_path_pose_ns = t + self.opt.gt_path_pose_period_ns
        if t >= self._next_path_ns:
            if self._path_t[-1] != t:
                self._path_t.append(t)
                self._path_p.append(p7)
            sink.write(
                GT_PATH,
                ros2.PATH,
                t,
                ros2.path(t, FRAME_GT_WORLD, self._path_t, np.array(self._path_p)),
            )
            self._next_path_ns = t + self.opt.gt_path_period_ns

    def finish(self, sink: Sink) -> None:
        """Write the remaining IMU / ground truth / leica messages up to the end."""
        self.write_until(sink, self._hi)
