"""What the pipeline hands out: one `FrameOutput` per frame to its observers (the MCAP writer,
the live view), one `RunResult` at the end."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from eurocslam.backend.types import NavEstimate
from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.types import FrontendResult
from eurocslam.geometry import F64


class PlaceKind(str, Enum):
    LOOP = "loop"
    RELOCALIZATION = "relocalization"
    MERGE = "merge"


@dataclass(frozen=True)
class PlaceEvent:
    """A loop closed, a relocalization or a merge, for the summary and the MCAP."""

    kind: PlaceKind
    t_ns: int
    segment: int
    query_key: int  # the keyframe that asked (-1: a lost frame)
    match_key: int  # the keyframe it recognised
    n_inliers: int
    p_query: F64  # the query's position and ...
    p_match: F64  # ... the matched keyframe's, in the world frame of the outputs
    correction_m: float = 0.0  # how far the estimate was moved (loop, merge)
    correction_deg: float = 0.0
    # a loop large enough to correct: its gate statistic (`loop_gate`), and whether the gate
    # refused it (then the drift it measured is in `drift_m`/`drift_deg`, nothing moved)
    gate_chi2: float = float("nan")
    refused: bool = False
    drift_m: float = 0.0
    drift_deg: float = 0.0

    def to_dict(self) -> dict[str, object]:
        d: dict[str, object] = {
            "kind": self.kind.value,
            "t_ns": self.t_ns,
            "segment": self.segment,
            "query_keyframe": self.query_key,
            "match_keyframe": self.match_key,
            "inliers": self.n_inliers,
            "correction_m": round(self.correction_m, 4),
            "correction_deg": round(self.correction_deg, 3),
        }
        if self.gate_chi2 == self.gate_chi2:  # not NaN: the gate was asked
            d.update(
                gate_chi2=round(self.gate_chi2, 2),
                refused=self.refused,
                drift_m=round(self.drift_m, 4),
                drift_deg=round(self.drift_deg, 3),
            )
        return d


class PipelineState(str, Enum):
    INIT = "INIT"
    TRACKING = "TRACKING"
    LOST = "LOST"


STATE_CODE = {PipelineState.INIT: 0, PipelineState.TRACKING: 1, PipelineState.LOST: 2}


@dataclass(frozen=True)
class KeyframePath:
    """The current segment's keyframes: times and latest smoothed poses."""

    t_ns: NDArray[np.int64]  # (K,)
    T_world_body: F64  # (K, 4, 4)


@dataclass(frozen=True)
class FrameOutput:
    """What the pipeline produced for one stereo frame: everything a sink needs."""

    t_ns: int
    state: PipelineState
    T_world_body: F64 | None  # online pose (None: no estimate for this frame)
    segment: int
    is_keyframe: bool
    frontend: FrontendResult | None  # None: not tracked (before the init, or track_every)
    nav: NavEstimate | None  # latest backend state (velocity, biases)
    reset_reason: str = ""  # non-empty when this frame ended a segment
    n_keyframes: int = 0  # keyframes of the current segment so far
    n_resets: int = 0  # resets of the run so far
    n_active_landmarks: int = 0  # landmarks the smoother holds after this frame
    # at keyframes: the segment's keyframe path and the smoother's landmarks (world, (N, 3))
    keyframe_path: KeyframePath | None = None
    landmarks: F64 | None = None
    frame: int = 0  # the world frame of the poses (a segment index: its own, or where it merged)
    places: tuple[PlaceEvent, ...] = ()  # loops, relocalizations, merges found at this frame
    left_out: bool = False  # not extracted nor tracked (`frontend.track_every`): no counts


class FrameObserver(Protocol):
    def on_frame(self, frame: StereoFrame, out: FrameOutput) -> None: ...
