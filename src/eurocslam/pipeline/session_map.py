"""Maps across sessions: an earlier session's map (`--map`) checked and made the first segment of
a run, and the run's map as a `SavedMap` (maps/store.py) for later sessions.

An earlier map enters the run as segment 0, a segment without frames: its keyframes are filed
in the place database with their saved poses, its landmarks answer `map_points` (they are not
optimised again: the old map stays fixed). The session itself starts as segment 1 in its own
world, exactly as a segment after a reset, and place recognition merges it into the map's frame
once its keyframes recognise the map consistently (`PlaceStage.merge`); every later place of the
map it recognises refines where it sits there (`PlaceStage.refine_frames`). Its trajectory, map
and MCAP then come out in the old map's frame.

The saved map holds the keyframes of one world frame (the map's frame when one was given, else
the frame of the most keyframes): each with its pose in that frame, its stereo observations and
bag-of-words vector, and the landmarks those observations see, renumbered uniquely across
segments, with their positions in the frame and the descriptor of one observation.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from eurocslam.backend.types import SegmentSolution
from eurocslam.dataset.calib import StereoRig
from eurocslam.errors import MapError
from eurocslam.geometry import F64
from eurocslam.maps.store import (
    MapKeyframe,
    SavedMap,
    load_map,
    rig_mismatch,
    rig_record,
    session_record,
)
from eurocslam.pipeline.places import PlaceStage

MAP_SEGMENT = 0  # the segment an earlier map is filed as


@dataclass(frozen=True)
class PriorMap:
    """An earlier session's map, as `run --map DIR` loads it."""

    path: Path
    map: SavedMap
    load_s: float  # seconds to read it from disk

    @classmethod
    def load(cls, path: Path | str) -> PriorMap:
        t0 = time.perf_counter()
        m = load_map(path)
        return cls(Path(path), m, time.perf_counter() - t0)

    def check(self, rig: StereoRig, vocabulary_id: str) -> None:
        """A one-line `MapError` when the map cannot serve this run: another vocabulary (the
        database's words would mean other things) or another camera rig."""
        meta = self.path / "map.json"
        if self.map.vocabulary_id != vocabulary_id:
            raise MapError(
                f"{meta}: made with vocabulary {self.map.vocabulary_id}, this run uses "
                f"{vocabulary_id} (places.vocabulary)"
            )
        why = rig_mismatch(self.map.rig, rig)
        if why is not None:
            raise MapError(f"{meta}: built with another camera rig ({why})")

    def summary(self) -> dict[str, object]:
        """What the run's summary says of the map it started from."""
        return {
            "path": str(self.path),
            "keyframes": len(self.map.keyframes),
            "landmarks": int(self.map.landmark_id.size),
            "load_s": round(self.load_s, 3),
        }

    def solution(self) -> SegmentSolution:
        """The map's landmarks as the map segment's solution (what `map_points` reads)."""
        m = self.map
        return SegmentSolution({}, m.landmark_xyz, m.landmark_id, {}, None)


def _main_frame(places: PlaceStage, n_segments: int) -> int:
    counts = [len(places.keyframes_in(f)) for f in range(n_segments)]
    return int(np.argmax(counts)) if counts else 0


def build_map(
    places: PlaceStage,
    n_segments: int,
    points_in_frame: Callable[[int, NDArray[np.int64]], F64],
    prior: PriorMap | None,
    session_name: str,
    rig: StereoRig,
    mode: str,
) -> SavedMap:
    """The run's map in one world frame (the prior map's, else the one with the most
    keyframes); `points_in_frame(segment, ids)`: landmark positions in that frame (NaN: none)."""
    frame = MAP_SEGMENT if prior is not None else _main_frame(places, n_segments)
    entries = places.keyframes_in(frame)
    prior_kfs = prior.map.keyframes if prior is not None else []
    this_session = len(prior.map.sessions) if prior is not None else 0
    # landmarks: every (segment, id) a saved keyframe observes that has a position
    empty_i = np.zeros(0, np.int64)
    seg = np.concatenate([np.full(len(v.desc), s, np.int64) for v, s, _ in entries] or [empty_i])
    lid = np.concatenate([v.landmark_ids for v, _, _ in entries] or [empty_i])
    desc = np.concatenate([v.desc for v, _, _ in entries] or [np.zeros((0, 32), np.uint8)])
    octave = np.concatenate([v.octave for v, _, _ in entries] or [np.zeros(0, np.int32)])
    new_id = np.full(lid.size, -1, np.int64)
    xyz_parts: list[F64] = []
    first_parts: list[NDArray[np.intp]] = []
    base = 0
    for s in np.unique(seg[lid >= 0]):
        rows = np.flatnonzero((seg == s) & (lid >= 0))
        ids, first = np.unique(lid[rows], return_index=True)
        xyz = points_in_frame(int(s), ids)
        ok = np.isfinite(xyz).all(axis=1)
        num = np.full(ids.size, -1, np.int64)
        num[ok] = base + np.arange(int(ok.sum()))
        base += int(ok.sum())
        new_id[rows] = num[np.searchsorted(ids, lid[rows])]
        xyz_parts.append(xyz[ok])
        first_parts.append(rows[first[ok]])
    first_obs = np.concatenate(first_parts or [np.zeros(0, np.int64)])
    keyframes, off = [], 0
    for key, (v, s, T) in enumerate(entries):
        n = len(v.desc)
        session = prior_kfs[key].session if s == MAP_SEGMENT and prior is not None else this_session
        keyframes.append(
            MapKeyframe(
                key,
                v.t_ns,
                session,
                T,
                v.stereo_uv,
                v.desc,
                new_id[off : off + n],
                v.octave,
                v.p_body,
                v.bow.words,
                v.bow.weights,
            )
        )
        off += n
    n_lm = int(first_obs.size)
    sessions = [*(prior.map.sessions if prior is not None else [])]
    n_new = sum(1 for kf in keyframes if kf.session == this_session)
    sessions.append(session_record(session_name, n_new, n_lm))
    return SavedMap(
        keyframes,
        np.arange(n_lm, dtype=np.int64),
        np.concatenate(xyz_parts or [np.zeros((0, 3))]),
        desc[first_obs],
        octave[first_obs],
        places.vocabulary_id,
        rig_record(rig),
        mode,
        sessions,
    )


def localized_after_s(
    first_t_ns: list[int], places: PlaceStage | None, frame_of: list[int]
) -> float | None:
    """Seconds from a session's first frame (the earliest of its segments' `first_t_ns`) to its
    first merge into the earlier map's frame; None if it never merged."""
    merges = [
        e.t_ns
        for e in (places.events if places is not None else [])
        if e.kind == "merge" and frame_of[e.segment] == MAP_SEGMENT
    ]
    return round((min(merges) - min(first_t_ns)) * 1e-9, 3) if merges and first_t_ns else None
