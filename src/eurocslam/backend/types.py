"""Typed boundary between the backend and the pipeline: states, keyframe updates, segments."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64


class EstimatorFailure(RuntimeError):
    """The smoother could not be updated (degenerate system, NaN); the caller must reset."""


@dataclass(frozen=True)
class NavEstimate:
    """State at one instant: pose, velocity and biases in the world frame."""

    t_ns: int
    T_world_body: F64
    v_world: F64
    bg: F64
    ba: F64


@dataclass(frozen=True)
class ImuCheck:
    """The final batch's variance check of the IMU factors against the stereo factors."""

    ratio: float  # (IMU chi-square / its redundancy) / (stereo chi-square / its redundancy)
    accel_scale: float = 1.0  # variance scale the final batch gave the accelerometer (1: none)
    ratio_after: float = math.nan  # the ratio with that scale (NaN: not re-weighted)


@dataclass(frozen=True)
class KeyframeUpdate:
    """What one smoother update changed: the new keyframe's state, the smoothed poses of every
    keyframe still in the smoother window, and the landmarks it holds."""

    index: int  # keyframe index in the segment (0: the first)
    nav: NavEstimate  # the new keyframe's smoothed state
    window: tuple[tuple[int, F64], ...]  # (keyframe index, smoothed T_world_body)
    landmark_ids: NDArray[np.int64]  # frontend ids of the landmarks in the window ...
    landmark_xyz: F64  # ... and their smoothed world positions (N, 3)


@dataclass(frozen=True)
class SegmentSolution:
    """A segment after its final batch: keyframe poses, the map, and the poses of the frames
    between keyframes that the IMU bridges (by the caller's frame index)."""

    keyframes: dict[int, F64]  # keyframe index -> T_world_body
    landmarks: F64  # (M, 3)
    landmark_ids: NDArray[np.int64]  # (M,) their frontend ids
    frames: dict[int, F64]  # frame index (as given to `finish`) -> T_world_body
    imu_check: ImuCheck | None
