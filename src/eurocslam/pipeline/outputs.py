"""What the pipeline hands out, in the world frame each segment is in.

Poses, paths and landmarks are produced in their segment's own world; a segment that place
recognition merged into another's frame has its outputs moved there (`WorldFrames`). `RunOutputs`
builds one `FrameOutput` per frame, with the place events found at that frame, keeps the online
trajectory (every pose as it was output), and assembles the `RunResult` at the end.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from eurocslam.backend.types import NavEstimate
from eurocslam.frontend.types import FrontendResult
from eurocslam.geometry import F64
from eurocslam.pipeline.frames import WorldFrames
from eurocslam.pipeline.records import (
    FrameOutput,
    KeyframePath,
    PipelineState,
    PlaceEvent,
)
from eurocslam.pipeline.segments import Segment, assemble
from eurocslam.pipeline.summary import RunSummary
from eurocslam.trajectory import Trajectory


class RunOutputs:
    """Frame outputs, the online trajectory and the place events of one run."""

    def __init__(self, frames: WorldFrames) -> None:
        self.frames = frames
        self.events: list[PlaceEvent] = []  # every place event of the run
        self._events_out = 0  # those already handed out
        self._online: list[tuple[int, F64, int]] = []  # (t, T in the segment's world, segment)

    def add_events(self, events: Iterable[PlaceEvent]) -> None:
        """Place events found at the frame being processed (handed out with its output)."""
        self.events += events

    def last_online(self, segment: int, n: int) -> list[tuple[int, F64]]:
        """(t, pose in the segment's world) of the last `n` online poses that are of
        `segment` (fewer where the last `n` include another segment's)."""
        return [(t, T) for t, T, s in self._online[-n:] if s == segment]

    def frame(
        self,
        t: int,
        state: PipelineState,
        T: F64 | None,
        segment: int,
        fr: FrontendResult | None,
        nav: NavEstimate | None,
        path: KeyframePath | None,
        landmarks: F64 | None,
        *,
        reset_reason: str,
        left_out: bool,
        n_keyframes: int,
        n_resets: int,
        n_active_landmarks: int,
    ) -> FrameOutput:
        """One frame's output, in the world frame its segment is in (`T`, the path and the
        landmarks are in the segment's own world; a merged segment's are moved)."""
        if T is not None:
            self._online.append((t, T, segment))
        C = self.frames.T_frame_seg(segment)
        if not np.array_equal(C, np.eye(4)):
            T = None if T is None else C @ T
            if path is not None:
                path = KeyframePath(path.t_ns, C @ path.T_world_body)
            if landmarks is not None:
                landmarks = landmarks @ C[:3, :3].T + C[:3, 3]
        events = tuple(self.events[self._events_out :])
        self._events_out = len(self.events)
        return FrameOutput(
            t,
            state,
            T,
            segment,
            path is not None,
            fr,
            nav,
            reset_reason,
            n_keyframes=n_keyframes,
            n_resets=n_resets,
            n_active_landmarks=n_active_landmarks,
            keyframe_path=path,
            landmarks=landmarks,
            frame=self.frames.frame_of(segment),
            places=events,
            left_out=left_out,
        )

    def result(self, segments: list[Segment], summary: RunSummary) -> RunResult:
        """The run's trajectories and map, each segment in its frame (after the final batch
        and the frames' last refinement)."""
        frames = self.frames
        final = assemble(segments, frames.frames, frames.poses)
        online = self._online
        on_t = np.array([o[0] for o in online], dtype=np.int64)
        on_T = np.array([frames.T_frame_seg(o[2]) @ o[1] for o in online]).reshape(-1, 4, 4)
        on_s = np.array([frames.frame_of(o[2]) for o in online], dtype=np.int64)
        return RunResult(
            Trajectory.from_poses(on_t, on_T, on_s, "online"),
            Trajectory.from_poses(final.t_ns, final.T, final.segment, "final"),
            final.landmarks,
            final.landmark_segment,
            summary,
        )


@dataclass
class RunResult:
    """A run's trajectories (every frame's pose, with the world frame it is in as its segment
    id: online, as each frame was processed; final, after the final batch), the final map (with
    each landmark's frame) and the summary."""

    online: Trajectory
    final: Trajectory
    landmarks: F64  # (M, 3) batch-optimised map
    landmark_segment: NDArray[np.int64]
    summary: RunSummary
