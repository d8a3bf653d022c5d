"""Extraction, the first stage of the frontend: one `StereoFrame` in, one `FrameFeatures` out.

Per frame: the image check (missing / blank / saturated / wrong size: the frame is NO_IMAGE for
tracking), rectification, grid-bucketed ORB on both images, stereo matching. With
`frontend.track_every` N > 1 only every Nth frame of a stream is extracted; the others are
SKIPPED (the pipeline gives them the IMU's pose). Stateless and
thread-safe (one ORB detector per thread), so `frontend/workers.py` can run it in other
processes while the tracking stage works on the previous frame.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from eurocslam.camera import RectifiedStereo
from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.types import U8, StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.features import Features, OrbExtractor
from eurocslam.frontend.matching import StereoMatches, match_stereo
from eurocslam.frontend.projection import pyramid_scales
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.geometry import F64


class FrameProblem(str, Enum):
    """Why a frame has no features (`FrameFeatures.problem`)."""

    MISSING = "missing"  # an image is not there (or empty)
    BLACK = "black"  # mean below `image_dark_mean`
    SATURATED = "saturated"  # mean above `image_saturated_mean`
    BLANK = "blank"  # standard deviation below `image_min_std`
    SIZE = "size"  # not the rig's image size
    SKIPPED = "skipped"  # left out by `frontend.track_every` (not a fault: the IMU bridges it)


_CHECK_STRIDE = 4  # the image check looks at every 4th row and column


def image_problem(img: U8 | None, config: FrontendConfig) -> FrameProblem | None:
    """Why an image cannot be tracked (MISSING, BLACK, SATURATED, BLANK), or None."""
    if img is None:
        return FrameProblem.MISSING
    if img.ndim != 2 or img.size == 0:
        return FrameProblem.MISSING
    sub = img[::_CHECK_STRIDE, ::_CHECK_STRIDE]
    mean = float(sub.mean())
    if mean < config.image_dark_mean:
        return FrameProblem.BLACK
    if mean > config.image_saturated_mean:
        return FrameProblem.SATURATED
    if float(sub.std()) < config.image_min_std:
        return FrameProblem.BLANK
    return None


@dataclass(frozen=True)
class FrameFeatures:
    """Output of the extraction stage for one stereo frame (rectified cam0 pixels)."""

    t_ns: int
    problem: FrameProblem | None  # None: usable; SKIPPED; else why the frame is NO_IMAGE
    left: Features
    right: Features
    stereo: StereoMatches
    timings_ms: dict[str, float] = field(default_factory=dict)

    def stereo_uv(self, kps: NDArray[np.intp]) -> F64:
        """The stereo measurements (N, 3) = (uL, uR, v) of left keypoints `kps` (uR NaN: none)."""
        uv = self.left.uv
        return np.column_stack([uv[kps, 0], self.stereo.uR[kps], uv[kps, 1]]).reshape(-1, 3)


def _shape(img: U8 | None) -> tuple[int, ...]:
    return () if img is None else img.shape


def _unusable(t_ns: int, problem: FrameProblem) -> FrameFeatures:
    """The features of a frame not extracted: none, and why (`problem`)."""
    e = Features.empty()
    no_stereo = StereoMatches(np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.intp))
    return FrameFeatures(t_ns, problem, e, e, no_stereo, {})


class Extractor:
    """Rectification, ORB on both images and stereo matching for one rig and configuration."""

    def __init__(self, rectifier: StereoRectifier, config: FrontendConfig) -> None:
        """`rectifier`: the rig rectified as `config` asks (`StereoRectifier.for_config`)."""
        self.rig = rectifier.rig
        self.config = config
        self.rectifier = rectifier
        self.scale = pyramid_scales(config)
        self._local = threading.local()

    @classmethod
    def for_rig(cls, rig: StereoRig, config: FrontendConfig) -> Extractor:
        """An extractor with its own rectification of `rig`."""
        return cls(StereoRectifier.for_config(rig, config), config)

    @property
    def geometry(self) -> RectifiedStereo:
        return self.rectifier.geometry

    def _orb(self) -> OrbExtractor:
        ex = getattr(self._local, "orb", None)
        if ex is None:
            g = self.geometry
            ex = OrbExtractor(self.config, g.width, g.height)
            self._local.orb = ex
        return ex

    def frame_problem(self, frame: StereoFrame) -> FrameProblem | None:
        """Why a frame's images cannot be tracked (`image_problem` of either, or SIZE), or
        None."""
        c = self.config
        problem = image_problem(frame.left, c) or image_problem(frame.right, c)
        hw0 = (self.rig.cam0.height, self.rig.cam0.width)  # the raw images' size
        hw1 = (self.rig.cam1.height, self.rig.cam1.width)
        if problem is None and (_shape(frame.left) != hw0 or _shape(frame.right) != hw1):
            problem = FrameProblem.SIZE
        return problem

    def without_extraction(self, frame: StereoFrame, n: int) -> FrameFeatures | None:
        """The features of a stream's `n`th frame (from 0) where they need no extraction: a
        frame between two tracked ones (SKIPPED) or one that fails the image check; None for a
        frame to extract."""
        problem = FrameProblem.SKIPPED if n % self.config.track_every else self.frame_problem(frame)
        return None if problem is None else _unusable(frame.t_ns, problem)

    def extract(self, frame: StereoFrame, checked: bool = False) -> FrameFeatures:
        """Rectify, ORB on both images, stereo matching. `checked`: `without_extraction` has
        passed the frame already (the image check is not repeated)."""
        problem = None if checked else self.frame_problem(frame)
        if problem is not None or frame.left is None or frame.right is None:
            return _unusable(frame.t_ns, problem or FrameProblem.MISSING)
        t0 = time.perf_counter()
        left = self.rectifier.rectify_left(frame.left)
        right = self.rectifier.rectify_right(frame.right)
        t1 = time.perf_counter()
        orb = self._orb()
        fl = orb.extract(left)
        fr = orb.extract(right)
        t2 = time.perf_counter()
        sm = match_stereo(fl, fr, left, right, self.scale, self.config, self.geometry)
        t3 = time.perf_counter()
        timings = {
            "rectify": (t1 - t0) * 1e3,
            "orb": (t2 - t1) * 1e3,
            "stereo_matching": (t3 - t2) * 1e3,
        }
        return FrameFeatures(frame.t_ns, None, fl, fr, sm, timings)
