"""World frames of a run's segments.

Every segment (the span between two resets) starts in a world frame of its own, numbered as the
segment. When place recognition finds that a segment's keyframes see places of another frame,
the segment's frame is put into that one (`merge`); at the end the places seen refine where each
merged segment sits (`place`). The pipeline owns the frames and changes them; the place stage
reads them (`FrameView`) and says what should change.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from eurocslam.geometry import F64


class FrameView(Protocol):
    """Reading the world frames."""

    def frame_of(self, segment: int) -> int: ...

    def T_frame_seg(self, segment: int) -> F64: ...

    def n_frames(self) -> int: ...


class WorldFrames:
    """Which world frame each segment is in (a segment index), and its pose there."""

    def __init__(self) -> None:
        self._frame_of: list[int] = []
        self._T_frame_seg: list[F64] = []

    def __len__(self) -> int:
        return len(self._frame_of)

    def new_segment(self) -> None:
        """The next segment, in a frame of its own at the identity."""
        self._frame_of.append(len(self._frame_of))
        self._T_frame_seg.append(np.eye(4))

    def frame_of(self, segment: int) -> int:
        return self._frame_of[segment]

    def T_frame_seg(self, segment: int) -> F64:
        return self._T_frame_seg[segment]

    def n_frames(self) -> int:
        """How many distinct frames the segments are in."""
        return len(set(self._frame_of))

    def to_frame(self, segment: int, p_seg: F64) -> F64:
        """Points (N, 3) of a segment's world in the frame it is in."""
        C = self._T_frame_seg[segment]
        return np.asarray(p_seg @ C[:3, :3].T + C[:3, 3], dtype=np.float64)

    def merge(self, root: int, frame: int, T_frame_root: F64) -> None:
        """Put the frame of segment `root` (and every segment in it) into frame `frame`."""
        for s, f in enumerate(self._frame_of):
            if f == root:
                self._frame_of[s] = frame
                self._T_frame_seg[s] = T_frame_root @ self._T_frame_seg[s]

    def place(self, segment: int, T_frame_seg: F64) -> None:
        """Where a segment sits in its frame, measured again."""
        self._T_frame_seg[segment] = T_frame_seg

    @property
    def frames(self) -> list[int]:
        """Every segment's frame, by segment."""
        return list(self._frame_of)

    @property
    def poses(self) -> list[F64]:
        """Every segment's pose in its frame, by segment."""
        return list(self._T_frame_seg)
