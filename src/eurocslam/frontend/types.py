"""Typed boundary between the frontend and the backend/pipeline.

The frontend works in the *rectified* cam0 frame (`rect0`): stereo measurements (uL, uR, v)
are rectified pixel coordinates, so the backend can use `gtsam.Cal3_S2Stereo` +
`GenericStereoFactor3D` with `body_P_sensor = T_body_rect0` (the geometry is
`eurocslam.camera.RectifiedStereo`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64


class TrackingState(str, Enum):
    INIT = "INIT"  # no map yet / first frame
    OK = "OK"  # tracked against the local map
    LOST = "LOST"  # images present but tracking failed (too few inliers, PnP failed)
    NO_IMAGE = "NO_IMAGE"  # blank, saturated or missing image(s)


class TrackPath(str, Enum):
    """How a frame's pose was found (summary.json `track_paths` counts them)."""

    PROJECTION = "projection"  # the map projected with the predicted pose
    PROJECTION_WIDE = "projection_wide"  # the same in a wider window
    DESCRIPTOR = "descriptor"  # descriptors against the whole local map, PnP RANSAC
    LOST = "lost"  # too few inliers
    IMU_BETWEEN = "imu_between"  # not tracked (frontend.track_every): the IMU's pose
    VO_BETWEEN = "vo_between"  # the same in a dynamic start's VO window: extrapolated VO


@dataclass(frozen=True)
class FrontendResult:
    """Everything the frontend knows about one stereo frame."""

    t_ns: int
    state: TrackingState
    # stereo observations of persistent landmarks, rows aligned
    landmark_ids: NDArray[np.int64]  # (N,)
    stereo_uv: F64  # (N, 3): uL, uR, v in rectified pixels (uR = NaN if mono-only)
    # the frontend's own pose estimate (PnP / VO), None when lost
    T_world_body: F64 | None
    is_keyframe: bool
    n_features: int  # ORB keypoints in the left image
    n_stereo: int  # of which stereo-matched
    n_tracked: int  # landmarks tracked (PnP inliers)
    n_reused: int = 0  # archived landmarks re-found at this keyframe (map reuse)
    # how the pose was found (None: not tracked against a map: the first frame, a new map, no
    # image)
    track_path: TrackPath | None = None
    # 2D points in *raw* (unrectified) cam0 pixels for drawing: (M, 2), and whether tracked
    draw_uv: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    draw_tracked: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    timings_ms: dict[str, float] = field(default_factory=dict)
    # (N,) pixel standard deviation of each stereo_uv row: the ORB octave scale of its keypoint
    # (1.0 at full resolution, 1.2**k at pyramid level k); multiply by a base sigma for factors
    stereo_sigma: F64 = field(default_factory=lambda: np.zeros(0))
    # (N, 32) ORB descriptors and (N,) pyramid octaves of the stereo_uv rows' keypoints (place
    # recognition files keyframes by them)
    descriptors: NDArray[np.uint8] = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    octaves: NDArray[np.int32] = field(default_factory=lambda: np.zeros(0, np.int32))


@dataclass(frozen=True)
class MapCorrection:
    """What the backend hands back to the tracker after a keyframe (or a rejected frame), in
    one record: the pose of the last tracked frame, optionally a rigid motion of the whole local
    map first (`T_new_old`: old world -> corrected world), then landmark positions by id."""

    T_world_body: F64
    T_new_old: F64 | None = None
    landmark_ids: NDArray[np.int64] | None = None
    landmark_xyz: F64 | None = None

    def then_move(self, T_new_old: F64, T_world_body: F64) -> MapCorrection:
        """This correction followed by a rigid move of everything (`T_new_old`: a loop
        closure), the last frame's pose ending at `T_world_body`."""
        first = self.T_new_old
        xyz = self.landmark_xyz
        return MapCorrection(
            T_world_body,
            T_new_old if first is None else T_new_old @ first,
            self.landmark_ids,
            None if xyz is None else xyz @ T_new_old[:3, :3].T + T_new_old[:3, 3],
        )
