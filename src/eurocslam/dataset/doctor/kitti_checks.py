"""The doctor on a KITTI odometry sequence (`sequences/NN`): files, `calib.txt`, `times.txt`,
images (one per row of times.txt, every PNG header, a decoded sample), the ground truth
`poses/NN.txt`, and the reader's own verdict. Same report and finding type as an ASL folder's;
each check is guarded so one failure never hides the others' findings."""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.calib import CameraCalib
from eurocslam.dataset.doctor.calib_checks import check_camera, check_stereo_pair
from eurocslam.dataset.doctor.csv_scan import MAX_EXAMPLES
from eurocslam.dataset.doctor.image_checks import (
    ImageState,
    decode_sample,
    format_message,
    is_format_kind,
    read_png_header,
)
from eurocslam.dataset.doctor.report import (
    ERROR,
    INFO,
    WARNING,
    DoctorReport,
    Findings,
    StreamStats,
)
from eurocslam.dataset.kitti import KittiSequence, kitti_rig
from eurocslam.dataset.kitti_files import (
    CALIB,
    IMAGE_DIRS,
    TIMES,
    KittiCalib,
    frame_image_name,
    poses_path_of,
    read_calib,
    read_poses,
    read_times,
)
from eurocslam.dataset.types import I64
from eurocslam.errors import EurocSlamError
from eurocslam.timebase import NS_PER_S

GAP_PERIODS = 1.5  # a step longer than this many median steps is a gap
_LOCATED = re.compile(r"^:(\d+)(?: \(([^)]*)\))?: (.*)$", re.S)


class _KittiDoctor:
    def __init__(
        self, path: Path, *, full: bool, sample: int, progress: Callable[[int, str], Any] | None
    ) -> None:
        self.path = path
        # files are named from the dataset root (sequences/NN/..., poses/NN.txt) when there is one
        self.found = Findings(path.parent.parent if path.parent.name == "sequences" else path)
        self.add = self.found.add
        self.guard = self.found.guard
        self.images = ImageState(full, sample, progress)
        self.streams: list[StreamStats] = []
        self.calib: KittiCalib | None = None
        self.t_ns: I64 | None = None
        self.lines: I64 | None = None
        self.size: tuple[int, int] | None = None
        self.stereo_pairs = 0

    def located(self, e: EurocSlamError, check: str, file: Path) -> None:
        """An error finding from a parser's 'file:row (key): message'."""
        msg = str(e)
        rest = msg[len(str(file)) :] if msg.startswith(str(file)) else None
        m = _LOCATED.match(rest) if rest is not None else None
        if m is not None:
            self.add(ERROR, check, m.group(3), file, int(m.group(1)), m.group(2))
        elif rest is not None and rest.startswith(": "):
            self.add(ERROR, check, rest[2:], file)
        else:
            self.add(ERROR, check, msg)

    # ---- run --------------------------------------------------------------------------------
    def run(self) -> DoctorReport:
        t0 = time.perf_counter()
        self.check_files()
        with self.guard("calibration", self.path / CALIB):
            self.check_calib()
        with self.guard("timestamps", self.path / TIMES):
            self.check_times()
        for k, d in enumerate(IMAGE_DIRS):
            with self.guard("images", self.path / d):
                self.check_images(k)
        with self.guard("calibration"):
            self.check_calib_values()
        with self.guard("groundtruth", poses_path_of(self.path)):
            self.check_poses()
        self.check_reader()
        return DoctorReport(
            sequence=str(self.path),
            mav0=None,
            findings=self.found.sorted(),
            streams=tuple(self.streams),
            stereo_pairs=self.stereo_pairs,
            image_headers_read=self.images.headers_read,
            images_decoded=self.images.decoded,
            elapsed_s=time.perf_counter() - t0,
        )

    # ---- checks -------------------------------------------------------------------------------
    def check_files(self) -> None:
        for name in (CALIB, TIMES):
            if not (self.path / name).is_file():
                self.add(ERROR, "files", "file missing", self.path / name)
        for d in IMAGE_DIRS:
            if not (self.path / d).is_dir():
                self.add(ERROR, "files", "image folder missing", self.path / d)
        poses = poses_path_of(self.path)
        if not poses.is_file():
            self.add(INFO, "files", "no ground truth: evaluation needs an external file", poses)
        self.add(INFO, "files", "no IMU (KITTI): a stereo-only sequence, runs visual-only")

    def check_calib(self) -> None:
        path = self.path / CALIB
        if not path.is_file():
            return
        try:
            self.calib = read_calib(path)
        except EurocSlamError as e:
            self.located(e, "calibration", path)

    def check_times(self) -> None:
        path = self.path / TIMES
        if not path.is_file():
            return
        try:
            self.t_ns, self.lines = read_times(path)
        except EurocSlamError as e:
            self.located(e, "timestamps", path)
            return
        t = self.t_ns
        rate = None
        if t.size > 1:
            d = np.diff(t)
            med = float(np.median(d))
            rate = NS_PER_S / med
            gaps = np.flatnonzero(d > GAP_PERIODS * med)
            if gaps.size:
                big = int(gaps[np.argmax(d[gaps])])
                self.add(
                    WARNING,
                    "timestamps",
                    f"{gaps.size} gap(s) longer than {GAP_PERIODS:g} median steps "
                    f"({med / 1e6:.1f} ms); largest {d[big] / 1e6:.1f} ms ends at this line",
                    path,
                    int(self.lines[big + 1]),
                )
        self.streams.append(
            StreamStats("frames", TIMES, int(t.size), int(t[0]), int(t[-1]), rate, None)
        )

    def check_images(self, k: int) -> None:
        folder = self.path / IMAGE_DIRS[k]
        cam = f"cam{k}"
        if not folder.is_dir() or self.t_ns is None or self.lines is None:
            return
        present = {n for n in os.listdir(folder) if n.lower().endswith(".png")}
        names = [frame_image_name(i) for i in range(int(self.t_ns.size))]
        missing = [
            (int(li), n) for li, n in zip(self.lines, names, strict=True) if n not in present
        ]
        extra = sorted(present - set(names))
        if missing or extra:
            ex = (
                ", ".join(f"{n} (row {li})" for li, n in missing[:MAX_EXAMPLES])
                if missing
                else ", ".join(extra[:MAX_EXAMPLES])
            )
            what = "missing" if missing else "without a row in times.txt"
            self.add(
                ERROR,
                "images",
                f"{len(present)} images but {TIMES} has {len(names)} rows; {what}: {ex} "
                "(the reader refuses the sequence)",
                folder,
            )
        probs: dict[str, list[str]] = {}
        usable: list[str] = []
        for name in names:
            if name not in present:
                continue
            h = read_png_header(folder / name)
            self.images.headers_read += 1
            if h.problem is not None:
                probs.setdefault(h.problem, []).append(name)
                continue
            if self.size is None:
                self.size = (h.width, h.height)
            if (h.width, h.height) != self.size:
                probs.setdefault(f"size {h.width}x{h.height}", []).append(name)
                continue
            for kind in h.format_kinds():
                probs.setdefault(kind, []).append(name)
            usable.append(name)
        for kind, bad in probs.items():
            ex = ", ".join(bad[:MAX_EXAMPLES])
            if kind.startswith("size "):
                assert self.size is not None
                width, height = self.size
                sev = ERROR if len(bad) == len(names) - len(missing) else WARNING
                self.add(
                    sev,
                    "images",
                    f"{len(bad)} image(s) are {kind[5:]} but the first image is {width}x{height}: "
                    f"{ex}; "
                    "the reader skips them",
                    folder,
                )
            elif is_format_kind(kind):  # colour is how KITTI's image_2/3 come: a note
                sev = WARNING if kind.endswith("-bit") else INFO
                self.add(sev, "images", format_message(kind, bad), folder)
            else:
                self.add(
                    WARNING,
                    "images",
                    f"{len(bad)} unreadable image(s), {kind}: {ex}; the reader skips them",
                    folder,
                )
        if names and not usable:
            self.add(ERROR, "images", f"no usable image among {len(names)}", folder)
        self.images.usable[cam] = set(usable)
        decode_sample(self.found, self.images, cam, folder, usable)
        if k == 1:
            both = self.images.usable.get("cam0", set()) & self.images.usable["cam1"]
            self.stereo_pairs = len(both)
            if not both:
                self.add(ERROR, "images", "no stereo pair has both images usable")

    def check_calib_values(self) -> None:
        """Intrinsics and the stereo pair of the rig the reader builds (warnings: implausible)."""
        if self.calib is None or self.size is None:
            return
        rate = (
            NS_PER_S / float(np.median(np.diff(self.t_ns)))
            if self.t_ns is not None and self.t_ns.size > 1
            else 10.0
        )
        try:
            rig = kitti_rig(self.calib, self.size[0], self.size[1], rate)
        except EurocSlamError as e:
            self.located(e, "calibration", self.path / CALIB)
            return
        path = self.path / CALIB
        cams: list[tuple[CameraCalib, int, str]] = [
            (rig.cam0, self.calib.row_P0, "P0"),
            (rig.cam1, self.calib.row_P1, "P1"),
        ]
        for cam, row, key in cams:
            for i in check_camera(cam):
                if i.key != "rate_hz":
                    self.add(i.severity, "calibration", i.message, path, row, key)
        for i in check_stereo_pair(rig.cam0, rig.cam1):
            self.add(i.severity, "calibration", "stereo: " + i.message, path, self.calib.row_P1)

    def check_poses(self) -> None:
        path = poses_path_of(self.path)
        if not path.is_file():
            return
        n = int(self.t_ns.size) if self.t_ns is not None else None
        try:
            T = read_poses(path, n, self.path / TIMES)
        except EurocSlamError as e:
            self.located(e, "groundtruth", path)
            return
        step = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
        t = self.t_ns
        self.streams.append(
            StreamStats(
                "groundtruth",
                self.found.rel(path) or "",
                int(T.shape[0]),
                int(t[0]) if t is not None else None,
                int(t[-1]) if t is not None else None,
                None,
                None,
            )
        )
        self.add(
            INFO,
            "groundtruth",
            f"{T.shape[0]} poses, {float(step.sum()):.1f} m of path",
            path,
        )

    def check_reader(self) -> None:
        """Open the sequence with the reader the pipeline uses: anything it refuses is an error."""
        self.found.reader_verdict(lambda: KittiSequence(self.path), self.path)


def diagnose_kitti(
    path: Path | str,
    *,
    full: bool = False,
    sample: int = 24,
    progress: Callable[[int, str], Any] | None = None,
) -> DoctorReport:
    """Check a KITTI odometry sequence folder. Never raises on bad data: every problem is a
    `Finding`. `sample` images per camera are decoded (all of them with `full`)."""
    return _KittiDoctor(Path(path), full=full, sample=sample, progress=progress).run()
