"""Place recognition in the pipeline: which keyframes may match, and what a match means.

The pipeline keeps one `PlaceRecognizer` over every keyframe of the run and asks it three
questions, each answered with a verified match and turned here into a pose in a world frame:

* **loop** (each keyframe): a keyframe of the same world frame, at least `loop_min_age_s` old.
  The match says where the query is in that frame; the difference with where the estimate puts
  it is the drift, a `LoopFix`. It is acted on once `loop_consistency` consecutive keyframes
  agree on it, it is larger than what map reuse's projection search corrects by itself, and it
  passes the gate: the drift is one the estimator's own uncertainty allows (`loop_gate`) and one
  the match tells from its own error (`loop_significance`).
* **relocalization** (a lost frame): a keyframe of the segment's frame: the frame's pose there.
* **merge** (each keyframe of a segment started after a reset): a keyframe of another frame: the
  transform that puts this segment's frame into that one, once `loop_consistency` consecutive
  keyframes agree on it.

Frames: every segment has its own world until it is merged; `FrameBook` says which frame a
segment is in and its pose there, and where every keyframe is (the pipeline updates the poses
as the smoother and the final batch refine them).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from eurocslam.camera import RectifiedStereo
from eurocslam.config import PlacesConfig
from eurocslam.geometry import (
    F64,
    inv_T,
    make_T,
    rot_z,
    se3_adjoint,
    se3_log,
    so3_log,
    yaw_of,
)
from eurocslam.maps.store import MapKeyframe
from eurocslam.places.recognizer import CandidatePoints, PlaceMatch, PlaceRecognizer, PlaceView
from eurocslam.places.vocabulary import BowVector, Vocabulary, default_vocabulary


@dataclass(frozen=True)
class PlaceEvent:
    """A loop closed, a relocalization or a merge, for the summary and the MCAP."""

    kind: str  # loop | relocalization | merge
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
            "kind": self.kind,
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


@dataclass
class KeyframeRef:
    segment: int
    index: int  # keyframe index in the segment
    t_ns: int
    T_seg_body: F64  # latest pose in its segment's world
    # the estimator's covariance of that pose when it was filed (6, 6: a left perturbation in
    # the segment's world, [rotation, translation]); None where it was not sampled
    cov_seg: F64 | None = None


@dataclass
class FrameBook:
    """Which world frame each segment is in, and every keyframe's pose."""

    frame_of: list[int] = field(default_factory=list)  # segment -> frame (a segment index)
    T_frame_seg: list[F64] = field(default_factory=list)  # segment -> its pose in that frame
    keyframes: dict[int, KeyframeRef] = field(default_factory=dict)

    def new_segment(self) -> None:
        self.frame_of.append(len(self.frame_of))
        self.T_frame_seg.append(np.eye(4))

    def merge(self, root: int, frame: int, T_frame_root: F64) -> None:
        """Put the frame of segment `root` (and every segment in it) into frame `frame`."""
        for s, f in enumerate(self.frame_of):
            if f == root:
                self.frame_of[s] = frame
                self.T_frame_seg[s] = T_frame_root @ self.T_frame_seg[s]

    def in_frame(self, key: int) -> F64:
        """A keyframe's pose in its segment's frame."""
        ref = self.keyframes[key]
        return self.T_frame_seg[ref.segment] @ ref.T_seg_body


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


def loop_gate(D: F64, cov_query: F64, cov_cand: F64, cov_match: F64) -> float:
    """The chi-square (6 DoF) of a loop's drift `D` against what the estimate allows.

    With the query's and the recognised keyframe's estimated poses perturbed on the left by
    xi_q and xi_c (world frame), the loop measures D ~ exp(xi_q - xi_c) plus the match's own
    error. The drift accumulated between the two keyframes is the part of the query's
    covariance the recognised keyframe did not already have (`cov_query - cov_cand`: both come
    from the same estimator, whose uncertainty only grows in the directions nothing observes:
    with an IMU, yaw and position; roll and pitch stay as small as gravity makes them), and the
    match adds its own (`cov_match`). A correction of degrees in roll or pitch, or of decimetres
    where the estimate is sure to centimetres, gives a large value."""
    S = _psd(cov_query - cov_cand) + cov_match
    xi = se3_log(D)
    try:
        return float(xi @ np.linalg.solve(S, xi))
    except np.linalg.LinAlgError:
        return float("inf")


def loop_significance(D: F64, cov_match: F64) -> float:
    """The chi-square (6 DoF) of a loop's drift `D` against the match's own error alone: how
    far the measured drift is from none. The gate (`loop_gate`) asks whether the estimate could
    have drifted that much; this asks whether the loop saw a drift at all. A blurred view or
    few, far points measure a pose to degrees: a drift of a degree is then noise, and acting on
    it moves a good estimate away (V1_03 motion with blur, development world 1: a 56-inlier
    loop measured 1.0 deg / 4 cm where the truth was 0.16 deg / 1 cm, its own sigma 5 deg /
    25 cm; online ATE 8.4 -> 13.8 mm)."""
    xi = se3_log(D)
    try:
        return float(xi @ np.linalg.solve(cov_match, xi))
    except np.linalg.LinAlgError:  # a match without error: any drift is seen
        return float("inf")


def _psd(M: F64) -> F64:
    """The nearest positive semi-definite matrix (negative eigenvalues set to 0)."""
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    return np.asarray((V * np.maximum(w, 0.0)) @ V.T, dtype=np.float64)


def yaw_and_translation(D: F64, p: F64) -> F64:
    """The part of a world-frame correction `D` an IMU leaves open: the rotation about world z
    (gravity) that D gives, and the translation that takes the point `p` where D takes it
    (roll and pitch are observed: a loop does not move them)."""
    R = rot_z(yaw_of(D[:3, :3]))
    return make_T(R, D[:3, :3] @ p + D[:3, 3] - R @ p)


# covisible keyframes (`PlaceStage._covisible_floor`): among the segment's last 10 keyframes,
# those sharing at least 15 landmarks with the query (ORB-SLAM's covisibility graph edge)
COVISIBLE_LOOKBACK = 10
COVISIBLE_MIN_SHARED = 15


def _size(D: F64) -> tuple[float, float]:
    return float(np.linalg.norm(D[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(D[:3, :3]))))


class PlaceStage:
    """Loops, relocalizations and merges of one run (see the module docstring)."""

    def __init__(
        self,
        recognizer: PlaceRecognizer,
        cfg: PlacesConfig,
        book: FrameBook,
        map_points: Callable[[int, NDArray[np.int64]], F64],
        min_disparity_px: float = 0.0,
    ) -> None:
        """`map_points(segment, landmark ids)`: the map's positions of landmarks in that
        segment's world (NaN where the map does not have them); `min_disparity_px`: a
        keyframe's own stereo points with less disparity are not used for verification."""
        self.recognizer = recognizer
        self.min_disparity_px = min_disparity_px
        self.cfg = cfg
        self.book = book
        self.map_points = map_points
        self.events: list[PlaceEvent] = []
        self._next_key = 0
        self._loop_votes: list[tuple[int, F64]] = []  # (inliers, D) of consecutive loops
        # (keyframe key, frame, T_frame_seg, sample) of consecutive matches
        self._merge_votes: list[tuple[int, int, F64, tuple[int, int, F64]]] = []
        self._key_of: dict[tuple[int, int], int] = {}  # (segment, keyframe index) -> key
        # per merged segment: (its keyframe, a keyframe of another segment it recognised, the
        # first seen from the second): where the segment sits in the frame, refined at the end
        self._samples: dict[int, list[tuple[int, int, F64]]] = {}
        self.n_queries = 0

    @classmethod
    def create(
        cls,
        cfg: PlacesConfig,
        geometry: RectifiedStereo,
        scales: F64,
        radius_px: float,
        book: FrameBook,
        map_points: Callable[[int, NDArray[np.int64]], F64],
    ) -> PlaceStage:
        """With the configured vocabulary (the shipped one by default); a missing or broken
        vocabulary file is a one-line `VocabularyError`."""
        vocab = Vocabulary.load(cfg.vocabulary) if cfg.vocabulary else default_vocabulary()
        recognizer = PlaceRecognizer(vocab, geometry, scales, radius_px, cfg)
        n = cfg.verify_max_depth_baselines
        return cls(recognizer, cfg, book, map_points, geometry.fx / n if n > 0 else 0.0)

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
    def view(
        self,
        t_ns: int,
        stereo_uv: F64,
        desc: np.ndarray,
        key: int = -1,
        landmark_ids: NDArray[np.int64] | None = None,
        octave: NDArray[np.int32] | None = None,
    ) -> PlaceView:
        return self.recognizer.view(key, t_ns, stereo_uv, desc, landmark_ids, octave)

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
        self.book.keyframes[view.key] = KeyframeRef(segment, index, view.t_ns, T_seg_body, cov_seg)
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
        book = self.book
        return [
            (self.recognizer.get(key), ref.segment, book.in_frame(key))
            for key, ref in book.keyframes.items()
            if book.frame_of[ref.segment] == frame
        ]

    def update_pose(self, segment: int, index: int, T_seg_body: F64) -> None:
        """A keyframe's refined pose (the smoother's, the final batch's)."""
        key = self._key_of.get((segment, index))
        if key is not None:
            self.book.keyframes[key].T_seg_body = T_seg_body

    def _find(
        self, view: PlaceView, accept: Callable[[int], bool], min_score: float = 0.0
    ) -> PlaceMatch | None:
        """A verified match, its pose in the candidate's world frame."""
        self.n_queries += 1
        return self.recognizer.find(view, accept, self._points, min_score=min_score)

    def _covisible_floor(self, view: PlaceView, segment: int, index: int) -> float:
        """The least appearance score of the query against its covisible keyframes: the
        segment's last `COVISIBLE_LOOKBACK` keyframes that share at least
        `COVISIBLE_MIN_SHARED` landmarks with it (0 where none does). A loop candidate that
        looks less like the query than those neighbours do is no evidence of a revisit; DBoW2 /
        ORB-SLAM normalise loop scores this way, and most queries then verify no candidate."""
        ids = view.landmark_ids[view.landmark_ids >= 0]
        floor = float("inf")
        for i in range(max(index - COVISIBLE_LOOKBACK, 0), index):
            key = self._key_of.get((segment, i))
            if key is None:
                continue
            other = self.recognizer.get(key)
            if np.intersect1d(ids, other.landmark_ids).size >= COVISIBLE_MIN_SHARED:
                floor = min(floor, self.recognizer.db.score(key, view.bow))
        return floor if floor != float("inf") else 0.0

    def _points(self, cand: PlaceView) -> CandidatePoints:
        """A keyframe's points in its world frame: the map's positions of its landmarks, its
        own close stereo points (moved with its pose) where the map has none, NaN otherwise."""
        ref = self.book.keyframes[cand.key]
        T_seg_kf = ref.T_seg_body
        own = cand.p_body @ T_seg_kf[:3, :3].T + T_seg_kf[:3, 3]
        far = cand.stereo_uv[:, 0] - cand.stereo_uv[:, 1] < self.min_disparity_px
        own[far] = np.nan
        mapped = self.map_points(ref.segment, cand.landmark_ids)
        pts = np.where(np.isfinite(mapped).all(axis=1, keepdims=True), mapped, own)
        C = self.book.T_frame_seg[ref.segment]
        return CandidatePoints(pts @ C[:3, :3].T + C[:3, 3], C @ T_seg_kf)

    def _sampled_cov(self, key: int) -> F64 | None:
        """A keyframe's pose covariance: its own, else that of the next keyframe of its segment
        that has one (the larger: the gate errs on the side of a smaller allowed drift)."""
        ref = self.book.keyframes[key]
        index = ref.index
        while True:
            k = self._key_of.get((ref.segment, index))
            if k is None:
                return None
            cov = self.book.keyframes[k].cov_seg
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
    ) -> LoopFix | None:
        """A consistent loop large enough to correct at this keyframe that passes the gate, or
        None. `cov_query()`: the estimator's covariance of the query's pose (segment frame, as
        `KeyframeRef.cov_seg`; None: not available, the loop is refused); asked only for a loop
        that reaches the gate. Without `cov_query` there is no gate (no estimator). `index`:
        the query's keyframe index in the segment (its covisible neighbours set the least
        appearance score a candidate needs, `_covisible_floor`; -1: none)."""
        c, book = self.cfg, self.book
        frame = book.frame_of[segment]
        t_max = view.t_ns - round(c.loop_min_age_s * 1e9)

        def accept(key: int) -> bool:
            # the recent past of this segment always looks like the present; another
            # segment's keyframes (an earlier session's map among them) are never that
            ref = book.keyframes.get(key)
            return (
                ref is not None
                and book.frame_of[ref.segment] == frame
                and (ref.t_ns <= t_max or ref.segment != segment)
            )

        floor = self._covisible_floor(view, segment, index) if index >= 0 else 0.0
        m = self._find(view, accept, floor)
        if m is None:
            self._loop_votes = []
            return None
        T_frame_seg = book.T_frame_seg[segment]
        T_frame_query = m.T_world_query
        if book.keyframes[m.key].segment != segment and frame != segment:
            # a place of another segment of this frame: evidence for where this segment sits in
            # the frame (`refine_frames`), not a drift within it
            self._samples.setdefault(segment, []).append(self._sample(view, m))
            self._loop_votes = []
            self._event("loop", view, segment, m, T_frame_query[:3, 3], 0.0, 0.0)
            return None
        D = inv_T(T_frame_seg) @ T_frame_query @ inv_T(T_seg_query)
        votes = [*self._loop_votes, (m.n_inliers, D)][-c.loop_consistency :]
        self._loop_votes = votes
        if len(votes) < c.loop_consistency or not self._agree([d for _, d in votes]):
            return None
        self._loop_votes = []
        dm, dd = _size(D)
        p_q = (T_frame_seg @ T_seg_query)[:3, 3]
        small = dm < c.loop_min_correction_m and dd < c.loop_min_correction_deg
        if small or not c.correct_loops_online:
            self._event("loop", view, segment, m, p_q, 0.0, 0.0)
            return None
        # the gate: is this drift one the estimate's own uncertainty allows? (segment frame)
        C_inv = inv_T(T_frame_seg)
        A = se3_adjoint(C_inv)
        cov_match = A @ m.cov_world @ A.T
        cov_cand = self._sampled_cov(m.key) if book.keyframes[m.key].segment == segment else None
        if cov_cand is None:  # another segment's keyframe: everything this one has drifted
            cov_cand = np.zeros((6, 6))
        chi2 = 0.0
        if cov_query is not None:
            cov_q = cov_query()
            chi2 = float("inf") if cov_q is None else loop_gate(D, cov_q, cov_cand, cov_match)
            if not chi2 <= c.loop_gate_chi2:
                self._event("loop", view, segment, m, p_q, 0.0, 0.0, chi2, True, dm, dd)
                return None
            if not loop_significance(D, cov_match) > c.loop_gate_chi2:
                # within the match's own error: the loop cannot tell this drift from none
                self._event("loop", view, segment, m, p_q, 0.0, 0.0, chi2, False, dm, dd)
                return None
        fix = LoopFix(m, D, inv_T(book.in_frame(m.key)) @ T_frame_query, _psd(cov_cand) + cov_match)
        self._event("loop", view, segment, m, p_q, dm, dd, chi2, False, dm, dd)
        return fix

    def _agree(self, Ds: list[F64]) -> bool:
        ref = Ds[-1]
        for D in Ds[:-1]:
            dm, dd = _size(inv_T(ref) @ D)
            if dm > self.cfg.loop_agree_m or dd > self.cfg.loop_agree_deg:
                return False
        return True

    # ---- relocalization -----------------------------------------------------------------------
    def relocalize(self, view: PlaceView, segment: int) -> F64 | None:
        """The lost frame's pose in its segment's world, found by appearance, or None."""
        book = self.book
        frame = book.frame_of[segment]

        def accept(key: int) -> bool:
            ref = book.keyframes.get(key)
            return ref is not None and book.frame_of[ref.segment] == frame

        m = self._find(view, accept)
        if m is None:
            return None
        T_seg_query = inv_T(book.T_frame_seg[segment]) @ m.T_world_query
        self._event("relocalization", view, segment, m, m.T_world_query[:3, 3], 0.0, 0.0)
        return T_seg_query

    # ---- merging ------------------------------------------------------------------------------
    def merge(self, view: PlaceView, segment: int, T_seg_query: F64) -> tuple[int, F64] | None:
        """(frame, T_frame_seg) once the segment has recognised another frame consistently."""
        book = self.book
        frame = book.frame_of[segment]
        # a segment merges only as its frame's root, and only into another frame
        if not self.cfg.merge or frame != segment or len(set(book.frame_of)) < 2:
            self._merge_votes = []
            return None

        def accept(key: int) -> bool:
            ref = book.keyframes.get(key)
            return ref is not None and book.frame_of[ref.segment] != frame

        m = self._find(view, accept)
        if m is None:
            self._merge_votes = []
            return None
        other = book.frame_of[book.keyframes[m.key].segment]
        T_frame_seg = m.T_world_query @ inv_T(T_seg_query)
        votes = [v for v in self._merge_votes if v[1] == other]
        n = self.cfg.loop_consistency
        self._merge_votes = [*votes, (view.key, other, T_frame_seg, self._sample(view, m))][-n:]
        if len(self._merge_votes) < n or not self._agree([v[2] for v in self._merge_votes]):
            return None
        self._samples[segment] = [v[3] for v in self._merge_votes]
        self._merge_votes = []
        book.merge(segment, other, T_frame_seg)
        p_q = (T_frame_seg @ T_seg_query)[:3, 3]
        dm, dd = _size(T_frame_seg)
        self._event("merge", view, segment, m, p_q, dm, dd)
        return other, T_frame_seg

    def _sample(self, view: PlaceView, m: PlaceMatch) -> tuple[int, int, F64]:
        return view.key, m.key, inv_T(self.book.in_frame(m.key)) @ m.T_world_query

    def refine_frames(self) -> None:
        """Where each merged segment sits in its frame, from every place of another segment its
        keyframes recognised (at the merge and after it), with the final keyframe poses: the
        mean of the transforms they give, far ones dropped. One match measures it to a few
        centimetres, tens of them to millimetres. Older segments first: a segment merged into
        a merged one follows it."""
        book = self.book
        for seg in sorted(self._samples):
            Ts = np.array(
                [
                    book.in_frame(match) @ T_match_query @ inv_T(book.keyframes[query].T_seg_body)
                    for query, match, T_match_query in self._samples[seg]
                ]
            ).reshape(-1, 4, 4)
            t = Ts[:, :3, 3]
            dist = np.linalg.norm(t - np.median(t, axis=0), axis=1)
            keep = dist <= max(3.0 * float(np.median(dist)), 0.01)
            u, _, vt = np.linalg.svd(Ts[keep, :3, :3].sum(axis=0))
            R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
            book.T_frame_seg[seg] = make_T(R, t[keep].mean(axis=0))

    def _event(
        self,
        kind: str,
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
    ) -> None:
        p_match = self.book.in_frame(m.key)[:3, 3]
        self.events.append(
            PlaceEvent(
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
        )
