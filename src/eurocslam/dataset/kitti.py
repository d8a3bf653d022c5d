"""KITTI odometry sequence reader: `sequences/NN/{image_0,image_1,calib.txt,times.txt}`, with
the ground truth in `poses/NN.txt` beside `sequences/` when it exists.

A stereo-only source: no IMU (`imu` empty, `rig.imu` None), so it runs visual-only. The body
frame is cam0 (`T_body_cam0` = I, cam1 at +baseline along x): KITTI's poses are cam0 poses, so
the ground truth and the run's trajectory are in the same body frame. The cameras are the
rectified grey pair: pinhole from `P0`/`P1`, no distortion (the frontend does not rectify them
again). The resolution is that of the first readable image of image_0; the frame rate comes
from the times. Images are `image_0/NNNNNN.png` and `image_1/NNNNNN.png`, one per row of
`times.txt` (grey or colour; colour becomes grey); unreadable ones are skipped and counted in
`skips`. Bad files (see `kitti_files`) raise one-line `DatasetError`s naming file and row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eurocslam.dataset.asl import FrameEntry, ImageFileFrames
from eurocslam.dataset.calib import CameraCalib, StereoRig
from eurocslam.dataset.calib_yaml import camera_yaml_text
from eurocslam.dataset.doctor.calib_checks import check_stereo
from eurocslam.dataset.images import decode_image
from eurocslam.dataset.kitti_files import (
    CALIB,
    IMAGE_DIRS,
    TIMES,
    KittiCalib,
    frame_image_name,
    is_kitti_root,
    poses_path_of,
    read_calib,
    read_poses,
    read_times,
)
from eurocslam.dataset.types import (
    I64,
    GroundTruth,
    ImuData,
    PositionData,
    SkipReport,
    empty_imu,
)
from eurocslam.errors import CalibrationError, DatasetError
from eurocslam.geometry import make_T, rot_to_quat_wxyz
from eurocslam.timebase import NS_PER_S

DEFAULT_RATE_HZ = 10.0  # KITTI odometry's rate, for a sequence of one frame


def kitti_rig(calib: KittiCalib, width: int, height: int, rate_hz: float) -> StereoRig:
    """The stereo-only rig of a KITTI sequence: body = cam0, cam1 at `calib.t_cam0_cam1`."""

    def cam(name: str, P: np.ndarray, T_body_cam: np.ndarray) -> CameraCalib:
        return CameraCalib(
            name=name,
            T_body_cam=T_body_cam,
            rate_hz=rate_hz,
            width=width,
            height=height,
            fx=float(P[0, 0]),
            fy=float(P[1, 1]),
            cx=float(P[0, 2]),
            cy=float(P[1, 2]),
            distortion=(0.0, 0.0, 0.0, 0.0),
            distortion_model="none",
        )

    cam0 = cam("cam0", calib.P0, np.eye(4))
    cam1 = cam("cam1", calib.P1, make_T(np.eye(3), calib.t_cam0_cam1))
    texts = {
        "cam0": camera_yaml_text(cam0, f"KITTI image_0 (P0 of {calib.path.name})"),
        "cam1": camera_yaml_text(cam1, f"KITTI image_1 (P1 of {calib.path.name})"),
    }
    rig = StereoRig(cam0, cam1, None, tuple(sorted(texts.items())))
    for issue in check_stereo(rig):
        if issue.severity == "error":
            raise CalibrationError(f"{calib.path}:{calib.row_P1} (P1): {issue.message}")
    return rig


class KittiSequence(ImageFileFrames):
    """A KITTI odometry sequence folder (`sequences/NN`). Implements `SequenceSource`."""

    SIZE_PROBLEM = "{cam} image size differs from the sequence's (skipped)"
    SIZE_EXPECTED = "the first image is {w}x{h}"

    def __init__(self, path: Path | str) -> None:
        self.root = Path(path)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: no such folder")
        if is_kitti_root(self.root):
            raise DatasetError(
                f"{self.root}: a KITTI dataset root; give one sequence folder "
                f"(e.g. {self.root / 'sequences' / 'NN'})"
            )
        self.name = self.root.name
        self.skips = SkipReport()
        self.calib_path = self.root / CALIB
        self.times_path = self.root / TIMES
        self.calib = read_calib(self.calib_path)
        if not self.times_path.is_file():
            raise DatasetError(
                f"{self.times_path}: file not found (a KITTI sequence stamps its frames in "
                f"{TIMES}, one time in seconds per image)"
            )
        self.t_ns, self.time_lines = read_times(self.times_path)
        self.entries = self._entries()
        width, height = self._resolution()
        self.rig = kitti_rig(self.calib, width, height, self._rate_hz())
        self.imu: ImuData = empty_imu()
        self.leica: PositionData | None = None
        self.poses_path = poses_path_of(self.root)
        self.groundtruth = self._read_groundtruth()

    # ---- files ------------------------------------------------------------------------------
    def _entries(self) -> list[FrameEntry]:
        n = int(self.t_ns.size)
        for d in IMAGE_DIRS:
            folder = self.root / d
            if not folder.is_dir():
                raise DatasetError(f"{folder}: image folder not found")
            try:
                present = {p.name for p in folder.iterdir() if p.suffix.lower() == ".png"}
            except OSError as e:
                raise DatasetError(f"{folder}: cannot list: {e.strerror or e}") from None
            expected = [frame_image_name(i) for i in range(n)]
            missing = [i for i, name in enumerate(expected) if name not in present]
            extra = sorted(present - set(expected))
            if missing or extra:
                first = (
                    f"{frame_image_name(missing[0])} missing (row {self.time_lines[missing[0]]} "
                    f"of {TIMES})"
                    if missing
                    else f"{extra[0]} has no row in {TIMES}"
                )
                raise DatasetError(
                    f"{folder}: {len(present)} images but {self.times_path} has {n} rows "
                    f"(one image per row: {first})"
                )
        return [
            FrameEntry(
                int(t),
                self.root / IMAGE_DIRS[0] / frame_image_name(i),
                self.root / IMAGE_DIRS[1] / frame_image_name(i),
            )
            for i, t in enumerate(self.t_ns.tolist())
        ]

    def _resolution(self) -> tuple[int, int]:
        """Width and height of the first readable image of image_0 (image_1's must match)."""
        sizes: list[tuple[int, int, Path]] = []
        for k in range(2):
            for e in self.entries:
                path = e.left if k == 0 else e.right
                assert path is not None
                dec = decode_image(path)
                if dec.image is not None:
                    h, w = dec.image.shape[:2]
                    sizes.append((w, h, path))
                    break
            else:
                raise DatasetError(f"{self.root / IMAGE_DIRS[k]}: no readable image")
        (w0, h0, p0), (w1, h1, p1) = sizes
        if (w0, h0) != (w1, h1):
            raise DatasetError(f"{p1}: {w1}x{h1}, but {p0} is {w0}x{h0} (one size for both)")
        return w0, h0

    def _rate_hz(self) -> float:
        if self.t_ns.size < 2:
            return DEFAULT_RATE_HZ
        return NS_PER_S / float(np.median(np.diff(self.t_ns)))

    def _read_groundtruth(self) -> GroundTruth | None:
        if not self.poses_path.is_file():
            return None
        T = read_poses(self.poses_path, int(self.t_ns.size), self.times_path)
        return GroundTruth(
            t_ns=self.t_ns.copy(),
            p=np.ascontiguousarray(T[:, :3, 3]),
            q_wxyz=rot_to_quat_wxyz(T[:, :3, :3]),
        )

    # ---- streams ----------------------------------------------------------------------------
    @property
    def frame_times(self) -> I64:
        return np.array(self.t_ns, dtype=np.int64)
