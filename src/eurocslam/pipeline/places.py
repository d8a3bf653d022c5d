"""Place recognition in the pipeline: which keyframes may match, and what a match means.

The pipeline keeps one `PlaceRecognizer` over every keyframe of the run and asks it three
questions, each answered with a verified match and turned here into a pose in a world frame:

* **loop** (each keyframe): a keyframe of the same world frame, at least `loop_min_age_s` old.
  The match says where the query is in that frame; the difference with where the estimate puts
  it is the drift, a `LoopFix`. It is acted on once `loop_consistency` consecutive keyframes
  agree on it, it is larger than what map reuse's projection search corrects by itself, and it
  passes the gate: the drift is one the estimator's own uncertainty allows (`loop_gate`) and one
  the match tells from its own error (`drift_significant`).
* **relocalization** (a lost frame): a keyframe of the segment's frame: the frame's pose there.
* **merge** (each keyframe of a segment started after a reset): a keyframe of another frame: the
  transform that puts this segment's frame into that one, once `loop_consistency` consecutive
  keyframes agree on it.

Frames: every segment has its own world until it is merged (`frames.WorldFrames`, which the
pipeline owns: the stage reads it and its answers say what changes). Every question returns a
`PlaceAnswer`: the events to report and what was found. The stage keeps every keyframe it was
given (`file`) with its latest pose, which the pipeline updates as the smoother and the final
batch refine them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from eurocslam.camera import RectifiedStereo
from eurocslam.config import PlacesConfig
from eurocslam.frontend.extraction import FrameFeatures
from eurocslam.frontend.types import FrontendResult
from eurocslam.geometry import (
    F64,
    inv_T,
    make_T,
    se3_adjoint,
    so3_log,
)
from eurocslam.maps.store import MapKeyframe
from eurocslam.pipeline.frames import FrameView
from eurocslam.pipeline.records import PlaceEvent, PlaceKind
from eurocslam.places.covisibility import COVISIBLE_LOOKBACK, Covisibility
from eurocslam.places.loop_gate import drift_significant, loop_gate, psd
from eurocslam.places.recognizer import CandidatePoints, PlaceMatch, PlaceRecognizer, PlaceView
from eurocslam.places.vocabulary import BowVector, Vocabulary, default_vocabulary
from eurocslam.timebase import s_to_ns


@dataclass
class KeyframeRef:
    segment: int
    index: int  # keyframe index in the segment
    t_ns: int
    T_seg_body: F64  # latest pose in its segment's world
    # the estimator's covariance of that pose when it was filed (6, 6: a left perturbation in
    # the segment's world, [rotation, translation]); None where it was not sampled
    cov_seg: F64 | None = None


@dataclass(frozen=True)
class LoopFix:
    """A verified loop that passed the gate: `D` moves the segment's estimate onto the old map
    (segment frame); `T_cand_query`: the query keyframe seen from the recognised one, as the
    loop puts it; `cov_after`: the query pose's covariance once moved (the recognised
    keyframe's and the match's; segment frame, as `KeyframeRef.cov_seg`)."""

    match: PlaceMatch
    D: F64
    T_cand_query: F64
    cov_after: F64
    cand_segment: int  # the recognised keyframe's segment and index there
    cand_index: int


@dataclass(frozen=True)
class PlaceAnswer:
    """What a question to the place stage found: the events to report, and per question the
    loop to correct (`loop`), the frame and pose a segment merges into (`merge`), or the lost
    frame's pose in its segment's world (`T_seg_query`)."""

    events: tuple[PlaceEvent, ...] = ()
    loop: LoopFix | None = None
    merge: tuple[int, F64] | None = None
    T_seg_query: F64 | None = None


def _size(D: F64) -> tuple[float, float]:
    return float(np.linalg.norm(D[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(D[:3, :3]))))


class PlaceStage:
    """Loops, relocalizations and merges of one run (see the module docstring)."""

    def __init__(
        self,
        recognizer: PlaceRecognizer,
        cfg: PlacesConfig,
        frames: FrameView,
        map_points: Callable[[int, NDArray[np.int64]], F64],
        min_disparity_px: float = 0.0,
    ) -> None:
        """`frames`: the world frame of each segment (read; the pipeline changes it as the
        answers say); `map_points(segment, landmark ids)`: the map's positions of landmarks in
        that segment's world (NaN where the map does not have them); `min_disparity_px`: a
        keyframe's own stereo points with less disparity are not used for verification."""
        self.recognizer = recognizer
        self.min_disparity_px = min_disparity_px
        self.cfg = cfg
        self.frames = frames
        self.map_points = map_points
        self._keyframes: dict[int, KeyframeRef] = {}  # every keyframe filed, by key
        self._next_key = 0
        self._loop_votes: list[tuple[int, F64]] = []  # (inliers, D) of consecutive loops
        # (keyframe key, frame, T_frame_seg, sample) of consecutive matches
        self._merge_votes: list[tuple[int, int, F64, tuple[int, int, F64]]] = []
        self._key_of: dict[tuple[int, int], int] = {}  # (segment, keyframe index) -> key
        # per merged segment: (its keyframe, a keyframe of another segment it recognised, the
        # first seen from the second): where the segment sits in the frame, refined at the end
        self._samples: dict[int, list[tuple[int, int, F64]]] = {}
        self._covisibility = Covisibility(recognizer)
        self.n_queries = 0

    @classmethod
    def create(
        cls,
        cfg: PlacesConfig,
        geometry: RectifiedStereo,
        scales: F64,
        radius_px: float,
        frames: FrameView,
        map_points: Callable[[int, NDArray[np.int64]], F64],
    ) -> PlaceStage:
        """With the configured vocabulary (the shipped one by default); a missing or broken
        vocabulary file is a one-line `VocabularyError`."""
        vocab = Vocabulary.load(cfg.vocabulary) if cfg.vocabulary else default_vocabulary()
        recognizer = PlaceRecognizer(vocab, geometry, scales, radius_px, cfg)
        n = cfg.verify_max_depth_baselines
        return cls(recognizer, cfg, frames, map_points, geometry.fx / n if n > 0 else 0.0)

    @property
    def vocabulary_id(self) -> str:
        return self.recognizer.vocabulary.id

    def stats(self) -> dict[str, float]:
        """The database's size and cost, for the summary."""
        r = self.recognizer
        db = r.db
        n = len(r)
        return {
            "keyframes": n,
            "memory_mb": r.memory_bytes / 1e6,
            "memory_kb_per_keyframe": r.memory_bytes / 1e3 / max(n, 1),
            "queries": db.n_queries,
            "query_ms_mean": db.total_query_ms / max(db.n_queries, 1),
            "verifications": r.n_verified,
            "verify_ms_mean": r.verify_ms / max(r.n_verified, 1),
        }

    # ---- keyframes ----------------------------------------------------------------------------
    def keyframe_view(self, t_ns: int, fr: FrontendResult) -> PlaceView:
        """A keyframe as the stage files it (under a new key): its stereo observations."""
        return self.recognizer.view(
            self.new_key(), t_ns, fr.stereo_uv, fr.descriptors, fr.landmark_ids, fr.octaves
        )

    def frame_view(self, ff: FrameFeatures) -> PlaceView:
        """A lost frame's stereo keypoints, to look it up (no key: it is not filed)."""
        ok = ff.stereo.valid
        uv = np.column_stack([ff.left.uv[ok, 0], ff.stereo.uR[ok], ff.left.uv[ok, 1]])
        return self.recognizer.view(-1, ff.t_ns, uv, ff.left.desc[ok], None, ff.left.octave[ok])

    def new_key(self) -> int:
        self._next_key += 1
        return self._next_key - 1

    def file(
        self,
        view: PlaceView,
        segment: int,
        index: int,
        T_seg_body: F64,
        cov_seg: F64 | None = None,
    ) -> None:
        """Add a keyframe (after it has asked its questions, so it does not find itself), with
        the estimator's covariance of its pose where it was sampled (`KeyframeRef.cov_seg`)."""
        self._keyframes[view.key] = KeyframeRef(segment, index, view.t_ns, T_seg_body, cov_seg)
        self._key_of[(segment, index)] = view.key
        self.recognizer.add(view)

    def file_saved(self, keyframes: Iterable[MapKeyframe], segment: int) -> None:
        """An earlier session's keyframes (a saved map), as keyframes 0.. of `segment`."""
        for i, kf in enumerate(keyframes):
            view = PlaceView(
                self.new_key(),
                kf.t_ns,
                kf.uv,
                kf.desc,
                kf.landmark_id,
                kf.octave,
                kf.p_body,
                BowVector(kf.bow_word, kf.bow_weight),
            )
            self.file(view, segment, i, kf.T_world_body)

    def keyframes_in(self, frame: int) -> list[tuple[PlaceView, int, F64]]:
        """(view, segment, pose in the frame) of every keyframe in world frame `frame`, in the
        order they were filed."""
        return [
            (self.recognizer.get(key), ref.segment, self._in_frame(key))
            for key, ref in self._keyframes.items()
            if self.frames.frame_of(ref.segment) == frame
        ]

    def update_pose(self, segment: int, index: int, T_seg_body: F64) -> None:
        """A keyframe's refined pose (the smoother's, the final batch's)."""
        key = self._key_of.get((segment, index))
        if key is not None:
            self._keyframes[key].T_seg_body = T_seg_body

    def _in_frame(self, key: int) -> F64:
        """A keyframe's pose in its segment's frame."""
        ref = self._keyframes[key]
        return self.frames.T_frame_seg(ref.segment) @ ref.T_seg_body

    def _find(
        self, view: PlaceView, accept: Callable[[int], bool], min_score: float = 0.0
    ) -> PlaceMatch | None:
        """A verified match, its pose in the candidate's world frame."""
        self.n_queries += 1
        return self.recognizer.find(view, accept, self._points, min_score=min_score)

    def _covisible_floor(self, view: PlaceView, segment: int, index: int) -> float:
        """The least score a loop candidate of the segment's keyframe `index` needs
        (`places/covisibility.py`)."""
        lookback = range(max(index - COVISIBLE_LOOKBACK, 0), index)
        return self._covisibility.floor(view, (self._key_of.get((segment, i)) for i in lookback))

    def _points(self, cand: PlaceView) -> CandidatePoints:
        """A keyframe's points in its world frame: the map's positions of its landmarks, its
        own close stereo points (moved with its pose) where the map has none, NaN otherwise."""
        ref = self._keyframes[cand.key]
        T_seg_kf = ref.T_seg_body
        own = cand.p_body @ T_seg_kf[:3, :3].T + T_seg_kf[:3, 3]
        far = cand.stereo_uv[:, 0] - cand.stereo_uv[:, 1] < self.min_disparity_px
        own[far] = np.nan
        mapped = self.map_points(ref.segment, cand.landmark_ids)
        pts = np.where(np.isfinite(mapped).all(axis=1, keepdims=True), mapped, own)
        C = self.frames.T_frame_seg(ref.segment)
        return CandidatePoints(pts @ C[:3, :3].T + C[:3, 3], C @ T_seg_kf)

    def _sampled_cov(self, key: int) -> F64 | None:
        """A keyframe's pose covariance: its own, else that of the next keyframe of its segment
        that has one (the larger: the gate errs on the side of a smaller allowed drift)."""
        ref = self._keyframes[key]
        index = ref.index
        while True:
            k = self._key_of.get((ref.segment, index))
            if k is None:
                return None
            cov = self._keyframes[k].cov_seg
            if cov is not None:
                return cov
            index += 1

    # ---- loops --------------------------------------------------------------------------------
    def loop(
        self,
        view: PlaceView,
        segment: int,
        T_seg_query: F64,
        cov_query: Callable[[], F64 | None] | None = None,
        index: int = -1,
        inertial: bool = False,
    ) -> PlaceAnswer:
        """`loop`: a consistent loop large enough to correct at this keyframe that passes the
        gate (None: none). `cov_query()`: the estimator's covariance of the query's pose
        (segment frame, as `KeyframeRef.cov_seg`; None: not available, the loop is refused);
        asked only for a loop that reaches the gate. Without `cov_query` there is no gate (no
        estimator). `index`: the query's keyframe index in the segment (its covisible
        neighbours set the least appearance score a candidate needs, `_covisible_floor`; -1:
        none). `inertial`: the run has an IMU (the correction applied is 4 DoF)."""
        c, frames, kfs = self.cfg, self.frames, self._keyframes
        frame = frames.frame_of(segment)
        t_max = view.t_ns - s_to_ns(c.loop_min_age_s)

        def accept(key: int) -> bool:
            # the recent past of this segment always looks like the present; another
            # segment's keyframes (an earlier session's map among them) are never that
            ref = kfs.get(key)
            return (
                ref is not None
                and frames.frame_of(ref.segment) == frame
                and (ref.t_ns <= t_max or ref.segment != segment)
            )

        floor = self._covisible_floor(view, segment, index) if index >= 0 else 0.0
        m = self._find(view, accept, floor)
        if m is None:
            self._loop_votes = []
            return PlaceAnswer()
        T_frame_seg = frames.T_frame_seg(segment)
        T_frame_query = m.T_world_query
        cand = kfs[m.key]
        if cand.segment != segment and frame != segment:
            # a place of another segment of this frame: evidence for where this segment sits in
            # the frame (`refined_frames`), not a drift within it
            self._samples.setdefault(segment, []).append(self._sample(view, m))
            self._loop_votes = []
            return PlaceAnswer(
                (self._event(PlaceKind.LOOP, view, segment, m, T_frame_query[:3, 3], 0.0, 0.0),)
            )
        D = inv_T(T_frame_seg) @ T_frame_query @ inv_T(T_seg_query)
        votes = [*self._loop_votes, (m.n_inliers, D)][-c.loop_consistency :]
        self._loop_votes = votes
        if len(votes) < c.loop_consistency or not self._agree([d for _, d in votes]):
            return PlaceAnswer()
        self._loop_votes = []
        dm, dd = _size(D)
        p_q = (T_frame_seg @ T_seg_query)[:3, 3]
        small = dm < c.loop_min_correction_m and dd < c.loop_min_correction_deg
        if small or not c.correct_loops_online:
            return PlaceAnswer((self._event(PlaceKind.LOOP, view, segment, m, p_q, 0.0, 0.0),))
        # the gate: is this drift one the estimate's own uncertainty allows? (segment frame)
        A = se3_adjoint(inv_T(T_frame_seg))
        cov_match = A @ m.cov_world @ A.T
        cov_cand = self._sampled_cov(m.key) if cand.segment == segment else None
        if cov_cand is None:  # another segment's keyframe: everything this one has drifted
            cov_cand = np.zeros((6, 6))
        chi2 = 0.0
        if cov_query is not None:
            cov_q = cov_query()
            chi2 = float("inf") if cov_q is None else loop_gate(D, cov_q, cov_cand, cov_match)
            if not chi2 <= c.loop_gate_chi2:
                refused = (chi2, True, dm, dd)
                return PlaceAnswer(
                    (self._event(PlaceKind.LOOP, view, segment, m, p_q, 0.0, 0.0, *refused),)
                )
            p_query = T_seg_query[:3, 3] if c.loop_significance_4dof and inertial else None
            if not drift_significant(D, cov_match, c.loop_gate_chi2, p_query):
                # within the match's own error: the loop cannot tell this drift from none
                kept = (chi2, False, dm, dd)
                return PlaceAnswer(
                    (self._event(PlaceKind.LOOP, view, segment, m, p_q, 0.0, 0.0, *kept),)
                )
        fix = LoopFix(
            m,
            D,
            inv_T(self._in_frame(m.key)) @ T_frame_query,
            psd(cov_cand) + cov_match,
            cand.segment,
            cand.index,
        )
        ev = self._event(PlaceKind.LOOP, view, segment, m, p_q, dm, dd, chi2, False, dm, dd)
        return PlaceAnswer((ev,), loop=fix)

    def _agree(self, Ds: list[F64]) -> bool:
        ref = Ds[-1]
        for D in Ds[:-1]:
            dm, dd = _size(inv_T(ref) @ D)
            if dm > self.cfg.loop_agree_m or dd > self.cfg.loop_agree_deg:
                return False
        return True

    # ---- relocalization -----------------------------------------------------------------------
    def relocalize(self, view: PlaceView, segment: int) -> PlaceAnswer:
        """`T_seg_query`: the lost frame's pose in its segment's world, found by appearance
        (None: not found)."""
        frames, kfs = self.frames, self._keyframes
        frame = frames.frame_of(segment)

        def accept(key: int) -> bool:
            ref = kfs.get(key)
            return ref is not None and frames.frame_of(ref.segment) == frame

        m = self._find(view, accept)
        if m is None:
            return PlaceAnswer()
        T_seg_query = inv_T(frames.T_frame_seg(segment)) @ m.T_world_query
        ev = self._event(
            PlaceKind.RELOCALIZATION, view, segment, m, m.T_world_query[:3, 3], 0.0, 0.0
        )
        return PlaceAnswer((ev,), T_seg_query=T_seg_query)

    # ---- merging ------------------------------------------------------------------------------
    def merge(self, view: PlaceView, segment: int, T_seg_query: F64) -> PlaceAnswer:
        """`merge`: (frame, T_frame_seg) once the segment has recognised another frame
        consistently (the caller puts the segment's frame there)."""
        frames, kfs = self.frames, self._keyframes
        frame = frames.frame_of(segment)
        # a segment merges only as its frame's root, and only into another frame
        if not self.cfg.merge or frame != segment or frames.n_frames() < 2:
            self._merge_votes = []
            return PlaceAnswer()

        def accept(key: int) -> bool:
            ref = kfs.get(key)
            return ref is not None and frames.frame_of(ref.segment) != frame

        m = self._find(view, accept)
        if m is None:
            self._merge_votes = []
            return PlaceAnswer()
        other = frames.frame_of(kfs[m.key].segment)
        T_frame_seg = m.T_world_query @ inv_T(T_seg_query)
        votes = [v for v in self._merge_votes if v[1] == other]
        n = self.cfg.loop_consistency
        self._merge_votes = [*votes, (view.key, other, T_frame_seg, self._sample(view, m))][-n:]
        if len(self._merge_votes) < n or not self._agree([v[2] for v in self._merge_votes]):
            return PlaceAnswer()
        self._samples[segment] = [v[3] for v in self._merge_votes]
        self._merge_votes = []
        p_q = (T_frame_seg @ T_seg_query)[:3, 3]
        dm, dd = _size(T_frame_seg)
        ev = self._event(PlaceKind.MERGE, view, segment, m, p_q, dm, dd)
        return PlaceAnswer((ev,), merge=(other, T_frame_seg))

    def _sample(self, view: PlaceView, m: PlaceMatch) -> tuple[int, int, F64]:
        return view.key, m.key, inv_T(self._in_frame(m.key)) @ m.T_world_query

    def refined_frames(self) -> dict[int, F64]:
        """Where each merged segment sits in its frame (segment -> T_frame_seg), from every
        place of another segment its keyframes recognised (at the merge and after it), with the
        final keyframe poses: the mean of the transforms they give, far ones dropped. One
        match measures it to a few centimetres, tens of them to millimetres. Older segments
        first: a segment merged into a merged one follows it."""
        kfs = self._keyframes
        placed: dict[int, F64] = {}

        def in_frame(key: int) -> F64:
            seg = kfs[key].segment
            T_frame_seg = placed[seg] if seg in placed else self.frames.T_frame_seg(seg)
            return T_frame_seg @ kfs[key].T_seg_body

        for seg in sorted(self._samples):
            Ts = np.array(
                [
                    in_frame(match) @ T_match_query @ inv_T(kfs[query].T_seg_body)
                    for query, match, T_match_query in self._samples[seg]
                ]
            ).reshape(-1, 4, 4)
            t = Ts[:, :3, 3]
            dist = np.linalg.norm(t - np.median(t, axis=0), axis=1)
            keep = dist <= max(3.0 * float(np.median(dist)), 0.01)
            u, _, vt = np.linalg.svd(Ts[keep, :3, :3].sum(axis=0))
            R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
            placed[seg] = make_T(R, t[keep].mean(axis=0))
        return placed

    def _event(
        self,
        kind: PlaceKind,
        view: PlaceView,
        segment: int,
        m: PlaceMatch,
        p_query: F64,
        dm: float,
        dd: float,
        chi2: float = float("nan"),
        refused: bool = False,
        drift_m: float = 0.0,
        drift_deg: float = 0.0,
    ) -> PlaceEvent:
        p_match = self._in_frame(m.key)[:3, 3]
        return PlaceEvent(
            kind,
            view.t_ns,
            segment,
            view.key,
            m.key,
            m.n_inliers,
            p_query,
            p_match,
            dm,
            dd,
            chi2,
            refused,
            drift_m,
            drift_deg,
        )
