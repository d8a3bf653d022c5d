"""Trajectory segments: the frames of each segment as the pipeline tracked them, and, once the
segment's final batch has run, the final trajectory and map of the run.

A segment is the span between two resets; each has its own world frame. A frame's final pose is
its IMU-bridged pose where the estimator gave one, else its online pose moved with the final
correction of the keyframe it hangs from.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from eurocslam.backend.types import SegmentSolution
from eurocslam.geometry import F64, extrapolate, inv_T


@dataclass
class FrameRecord:
    t_ns: int
    T_chain: F64  # pose in the segment's frame used to attach it to its reference keyframe
    ref_kf: int  # keyframe index (in the segment) this frame hangs from; -1: the first one


@dataclass
class Segment:
    index: int
    records: list[FrameRecord] = field(default_factory=list)
    kf_T_chain: dict[int, F64] = field(default_factory=dict)
    solution: SegmentSolution | None = None

    def frame_refs(self) -> list[tuple[int, int]]:
        """(t_ns, reference keyframe) of every frame, as the estimator's `finish` takes them."""
        return [(r.t_ns, r.ref_kf) for r in self.records]

    def final_poses(self) -> list[F64]:
        """Every frame's final pose (its online chain pose before the final batch)."""
        sol = self.solution
        out = []
        for i, rec in enumerate(self.records):
            ref = rec.ref_kf if rec.ref_kf >= 0 else 0
            if sol is not None and i in sol.frames:
                T = sol.frames[i]
            elif sol is not None and ref in sol.keyframes and ref in self.kf_T_chain:
                T = sol.keyframes[ref] @ inv_T(self.kf_T_chain[ref]) @ rec.T_chain
            else:
                T = rec.T_chain
            out.append(T)
        return out

    @property
    def landmarks(self) -> F64:
        return self.solution.landmarks if self.solution is not None else np.zeros((0, 3))

    def landmark_positions(self, ids: NDArray[np.int64]) -> F64:
        """The final batch's positions (N, 3) of landmarks by id (NaN: not in its map, or the
        segment has not ended)."""
        out = np.full((len(ids), 3), np.nan)
        sol = self.solution
        if sol is not None and len(sol.landmark_ids):
            order = np.argsort(sol.landmark_ids)
            sid = sol.landmark_ids[order]
            j = np.clip(np.searchsorted(sid, ids), 0, len(sid) - 1)
            hit = sid[j] == ids
            out[hit] = sol.landmarks[order[j[hit]]]
        return out


@dataclass(frozen=True)
class FinalTrajectory:
    t_ns: np.ndarray
    T: F64  # (N, 4, 4)
    segment: np.ndarray
    landmarks: F64  # (M, 3)
    landmark_segment: np.ndarray


def assemble(
    segments: list[Segment], frame_of: list[int], T_frame_seg: list[F64]
) -> FinalTrajectory:
    """The final trajectory of all segments in time order, and the map, each segment in its
    world frame (`frame_of`: a segment merged into another's frame is moved there by
    `T_frame_seg`, and carries that frame's id)."""
    ft, fT, fs, lm, ls = [], [], [], [], []
    for seg in segments:
        if not seg.records:
            continue
        C = T_frame_seg[seg.index]
        for rec, T in zip(seg.records, seg.final_poses(), strict=True):
            ft.append(rec.t_ns)
            fT.append(C @ T)
            fs.append(frame_of[seg.index])
        lm.append(seg.landmarks @ C[:3, :3].T + C[:3, 3])
        ls.append(np.full(len(seg.landmarks), frame_of[seg.index], np.int64))
    order = np.argsort(np.array(ft, dtype=np.int64), kind="stable")
    return FinalTrajectory(
        np.array(ft, dtype=np.int64)[order],
        np.array(fT).reshape(-1, 4, 4)[order],
        np.array(fs, dtype=np.int64)[order],
        np.concatenate(lm) if lm else np.zeros((0, 3)),
        np.concatenate(ls) if ls else np.zeros(0, np.int64),
    )


def interpolate_between(records: list[FrameRecord], a: tuple[int, F64], b: tuple[int, F64]) -> None:
    """Give the records strictly between two tracked poses `a` and `b` (time, pose; `b`'s record
    last) poses interpolated between them (constant body-frame twist)."""
    (ta, Ta), (tb, Tb) = a, b
    for rec in reversed(records[:-1]):
        if rec.t_ns <= ta:
            break
        rec.T_chain = extrapolate(Ta, Tb, (rec.t_ns - ta) / (tb - ta) - 1.0)
