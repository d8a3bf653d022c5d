"""Evaluate an estimate against a reference: associate, align, ATE, RPE, per segment.

A run with resets writes a segment id per pose (see `trajectory`). Each segment lives in its
own world frame, so each is associated and aligned **on its own**; the overall figures pool the
per-pose (ATE) and per-pair (RPE) errors of every evaluated segment. Coverage is the fraction of
the ground-truth time span during which the estimate has poses (gaps longer than
`coverage_gap_s` between consecutive poses of a segment do not count).

RPE over distance uses lengths that are fractions of the ground-truth path length over the
matched poses (all segments together); for a single segment this is rpg's "10..50 % of the
trajectory length", from 0.1 m up (shorter ones measure noise, not drift). Explicit lengths in
metres override the fractions.

An se3/sim3 alignment is evo's fit of positions wherever the positions decide it; where they do
not (a platform at rest, `align` says when) its rotation comes from the orientations, and the
result carries the ATE under the position-only fit too (`ate_trans_position_fit`), so a report
can give both.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from eurocslam.errors import EvalError
from eurocslam.eval.align import Alignment, align, rotation_fit_sigma_deg
from eurocslam.eval.associate import Association, associate
from eurocslam.eval.metrics import (
    RpeLength,
    Stats,
    ate_errors,
    cumulative_distance,
    delta_pairs,
    pool_lengths,
    relative_errors,
    rpe_length,
)
from eurocslam.geometry import F64, make_T
from eurocslam.timebase import NS_PER_S
from eurocslam.trajectory import Trajectory

I64 = NDArray[np.int64]
DEFAULT_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5)
# RPE lengths taken as fractions of the path are kept only from this length up: over shorter
# distances the per-pose noise (millimetres), not drift, is the error (a drone at rest: "drift"
# of 44 % over 2 mm)
MIN_FRACTION_LENGTH_M = 0.1


@dataclass(frozen=True)
class EvalConfig:
    align: str = "se3"
    align_first: int | None = None  # fit the alignment on the first N matched poses
    max_diff_s: float = 0.01  # evo's default
    offset_s: float = 0.0  # added to the estimate's stamps
    rpe_delta: int = 1  # frames
    rpe_fractions: tuple[float, ...] = DEFAULT_FRACTIONS
    rpe_lengths_m: tuple[float, ...] | None = None  # overrides rpe_fractions
    rpe_tol: float = 0.1  # accepted |travelled - L| / L
    coverage_gap_s: float = 1.0

    def associate(self, ref: Trajectory, est: Trajectory) -> Association:
        """Pairs of `ref` and `est` poses under this configuration's window and offset."""
        return associate(
            ref.t_ns,
            est.t_ns,
            round(self.max_diff_s * NS_PER_S),
            round(self.offset_s * NS_PER_S),
            ref.name or "reference",
            est.name or "estimate",
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "align": self.align,
            "align_first": self.align_first,
            "max_diff_s": self.max_diff_s,
            "offset_s": self.offset_s,
            "rpe_delta_frames": self.rpe_delta,
            "rpe_fractions": list(self.rpe_fractions) if self.rpe_lengths_m is None else None,
            "rpe_lengths_m": list(self.rpe_lengths_m) if self.rpe_lengths_m else None,
            "rpe_tol": self.rpe_tol,
            "coverage_gap_s": self.coverage_gap_s,
        }


@dataclass(frozen=True)
class SegmentEval:
    """One segment: matched poses (aligned estimate), errors and alignment."""

    segment: int
    association: Association
    alignment: Alignment
    t_ns: I64  # reference stamps of the matched pairs
    p_ref: F64
    R_ref: F64
    p_est: F64  # aligned
    R_est: F64  # aligned
    ate_t: F64  # per pose [m]
    ate_r: F64  # per pose [deg]
    rpe_t: F64  # per delta pair [m]
    rpe_r: F64  # per delta pair [deg]
    rpe_t_time_ns: I64  # end stamp of each delta pair
    gt_length_m: float
    lengths: list[RpeLength] = field(default_factory=list)
    # per pose [m] under the position-only (evo) fit, where the alignment took its rotation from
    # the orientations and a position fit exists (`Alignment.position_fit`)
    ate_t_position_fit: F64 | None = None

    def summary(self) -> dict[str, object]:
        return {
            "segment": self.segment,
            "association": self.association.summary(),
            "alignment": self.alignment.summary(),
            "gt_length_m": self.gt_length_m,
            "duration_s": float(self.t_ns[-1] - self.t_ns[0]) / NS_PER_S,
            "ate_trans_m": Stats.of(self.ate_t).to_dict(),
            **(
                {"ate_trans_position_fit_m": Stats.of(self.ate_t_position_fit).to_dict()}
                if self.ate_t_position_fit is not None
                else {}
            ),
            "ate_rot_deg": Stats.of(self.ate_r).to_dict(),
            "rpe_delta_trans_m": Stats.of(self.rpe_t).to_dict(),
            "rpe_delta_rot_deg": Stats.of(self.rpe_r).to_dict(),
            "rpe_lengths": [x.to_dict() for x in self.lengths],
        }

    def rotation_fit_sigma_deg(self) -> float:
        """How well the positions pin down the alignment's rotation (`align.
        rotation_fit_sigma_deg` with this segment's ATE): large on a (nearly) straight path,
        where an SE(3) or Sim(3) fit may turn the estimate about the path."""
        return rotation_fit_sigma_deg(self.p_ref, float(np.sqrt(np.mean(self.ate_t**2))))


@dataclass(frozen=True)
class EvalResult:
    label: str  # e.g. "final (smoothed)" / "online (causal)"
    est_name: str
    ref_name: str
    config: EvalConfig
    segments: list[SegmentEval]
    skipped: list[tuple[int, str]]  # (segment id, reason)
    ate_trans: Stats
    ate_rot: Stats
    rpe_delta_trans: Stats
    rpe_delta_rot: Stats
    lengths: list[RpeLength]
    coverage: float
    ref_span_s: float
    ref_length_m: float  # whole reference path length
    # where a segment's alignment took its rotation from the orientations: the ATE translation
    # with every segment under its position-only (evo) fit instead; None where no segment did,
    # or where one has no position fit (one side does not move: evo has no figure either)
    ate_trans_position_fit: Stats | None = None

    @property
    def from_orientations(self) -> bool:
        """Some segment's alignment took its rotation from the orientations."""
        return any(s.alignment.from_orientations for s in self.segments)

    @property
    def drift_pct(self) -> float | None:
        """Mean translation RPE in % of distance, averaged over the lengths (rpg style)."""
        vals = [x.trans_pct.mean for x in self.lengths if x.trans.n > 0]
        return float(np.mean(vals)) if vals else None

    @property
    def matched(self) -> int:
        return sum(s.association.matched for s in self.segments)

    @property
    def possible(self) -> int:
        return sum(s.association.possible for s in self.segments)

    def to_dict(self) -> dict[str, object]:
        return {
            "label": self.label,
            "estimate": self.est_name,
            "reference": self.ref_name,
            "config": self.config.to_dict(),
            "matched": self.matched,
            "possible": self.possible,
            "coverage": self.coverage,
            "reference_span_s": self.ref_span_s,
            "reference_length_m": self.ref_length_m,
            "ate_trans_m": self.ate_trans.to_dict(),
            "ate_basis": "orientations" if self.from_orientations else "positions",
            "ate_trans_position_fit_m": (
                None
                if self.ate_trans_position_fit is None
                else self.ate_trans_position_fit.to_dict()
            ),
            "ate_rot_deg": self.ate_rot.to_dict(),
            "rpe_delta_trans_m": self.rpe_delta_trans.to_dict(),
            "rpe_delta_rot_deg": self.rpe_delta_rot.to_dict(),
            "rpe_lengths": [x.to_dict() for x in self.lengths],
            "drift_pct": self.drift_pct,
            "segments": [s.summary() for s in self.segments],
            "skipped_segments": [{"segment": i, "reason": r} for i, r in self.skipped],
        }


def _eval_segment(
    sid: int, ref: Trajectory, R_ref_all: F64, est: Trajectory, cfg: EvalConfig
) -> SegmentEval:
    assoc = cfg.associate(ref, est)
    ir, ie = assoc.idx_ref, assoc.idx_est
    p_ref, R_ref = ref.p[ir], R_ref_all[ir]
    p_e, R_e = est.p[ie], est.rotations()[ie]
    al = align(
        cfg.align,
        p_ref,
        p_e,
        make_T(R_ref[0], p_ref[0]),
        make_T(R_e[0], p_e[0]),
        cfg.align_first,
        R_ref,
        R_e,
    )
    p_est, R_est = al.apply(p_e, R_e)
    ate_t, ate_r = ate_errors(p_ref, R_ref, p_est, R_est)
    ate_t_position_fit = None
    if al.position_fit is not None:
        p_pos = al.position_fit.apply_positions(p_e)
        ate_t_position_fit = np.linalg.norm(p_pos - p_ref, axis=1)
    i, j = delta_pairs(len(ir), cfg.rpe_delta)
    if i.size:
        rpe_t, rpe_r = relative_errors(p_ref, R_ref, p_est, R_est, i, j)
    else:
        rpe_t, rpe_r = np.zeros(0), np.zeros(0)
    return SegmentEval(
        segment=sid,
        association=assoc,
        alignment=al,
        t_ns=ref.t_ns[ir],
        p_ref=p_ref,
        R_ref=R_ref,
        p_est=p_est,
        R_est=R_est,
        ate_t=ate_t,
        ate_r=ate_r,
        rpe_t=rpe_t,
        rpe_r=rpe_r,
        rpe_t_time_ns=ref.t_ns[ir][j],
        gt_length_m=float(cumulative_distance(p_ref)[-1]),
        ate_t_position_fit=ate_t_position_fit,
    )


def _position_fit_ate(segs: list[SegmentEval]) -> Stats | None:
    """The pooled ATE translation with every segment under its position-only fit, where some
    segment's headline came from the orientations (None otherwise, or without a position fit)."""
    if not any(s.alignment.from_orientations for s in segs):
        return None
    parts = []
    for s in segs:
        if not s.alignment.from_orientations:
            parts.append(s.ate_t)
        elif s.ate_t_position_fit is not None:
            parts.append(s.ate_t_position_fit)
        else:
            return None
    return Stats.of(np.concatenate(parts))


def _with_lengths(seg: SegmentEval, lengths: list[tuple[float | None, float]], tol: float) -> None:
    d = cumulative_distance(seg.p_ref)
    seg.lengths.extend(
        rpe_length(seg.p_ref, seg.R_ref, seg.p_est, seg.R_est, L, f, tol, d) for f, L in lengths
    )


def coverage(ref_t: I64, est: Trajectory, offset_ns: int, gap_ns: int) -> float:
    """Fraction of the reference time span covered by estimate poses (per segment, gaps longer
    than `gap_ns` excluded)."""
    lo, hi = int(ref_t[0]), int(ref_t[-1])
    if hi <= lo:
        return 0.0
    starts, ends = [], []
    for _, seg in est.segments():
        t = seg.t_ns + offset_ns
        if len(t) < 2:
            continue
        ok = np.diff(t) <= gap_ns
        starts.append(t[:-1][ok])
        ends.append(t[1:][ok])
    if not starts:
        return 0.0
    a = np.clip(np.concatenate(starts), lo, hi)
    b = np.clip(np.concatenate(ends), lo, hi)
    order = np.argsort(a)
    a, b = a[order], b[order]
    # merge overlapping intervals: running max of ends
    b_run = np.maximum.accumulate(b)
    new = np.concatenate([[True], a[1:] > b_run[:-1]])
    grp = np.cumsum(new) - 1
    seg_start = a[new]
    seg_end = np.zeros(seg_start.shape, dtype=np.int64)
    np.maximum.at(seg_end, grp, b)
    return float(np.sum(seg_end - seg_start)) / float(hi - lo)


def evaluate(
    ref: Trajectory, est: Trajectory, cfg: EvalConfig | None = None, label: str = "estimate"
) -> EvalResult:
    """Evaluate `est` against `ref` (see module docstring). Raises EvalError with both names
    when nothing can be evaluated."""
    cfg = cfg or EvalConfig()
    if cfg.rpe_delta < 1:
        raise EvalError(f"RPE delta must be >= 1 frame, got {cfg.rpe_delta}")
    if len(ref) < 2:
        raise EvalError(f"{ref.name or 'reference'}: needs at least 2 poses, has {len(ref)}")
    if ref.has_segments:
        order = np.argsort(ref.t_ns, kind="stable")
        ref = Trajectory(ref.t_ns[order], ref.p[order], ref.q_wxyz[order], None, ref.name)
    R_ref_all = ref.rotations()
    segs: list[SegmentEval] = []
    skipped: list[tuple[int, str]] = []
    parts = est.segments()
    for sid, part in parts:
        part = part.with_name(est.name or "estimate")
        if len(parts) == 1:
            try:
                segs.append(_eval_segment(sid, ref, R_ref_all, part, cfg))
            except EvalError as e:  # name the inputs when the message does not
                msg = str(e)
                if (est.name or "") in msg and est.name:
                    raise
                raise EvalError(
                    f"{est.name or 'estimate'} vs {ref.name or 'reference'}: {msg}"
                ) from None
            continue
        try:
            segs.append(_eval_segment(sid, ref, R_ref_all, part, cfg))
        except EvalError as e:
            skipped.append((sid, str(e)))
    if not segs:
        raise EvalError(
            f"no segment of {est.name} could be evaluated against {ref.name}: "
            + "; ".join(f"segment {i}: {r}" for i, r in skipped)
        )
    total_len = sum(s.gt_length_m for s in segs)
    if cfg.rpe_lengths_m:
        lengths: list[tuple[float | None, float]] = [(None, float(L)) for L in cfg.rpe_lengths_m]
    else:
        lengths = [
            (f, f * total_len) for f in cfg.rpe_fractions if f * total_len >= MIN_FRACTION_LENGTH_M
        ]
    for s in segs:
        _with_lengths(s, lengths, cfg.rpe_tol)
    pooled = [pool_lengths([s.lengths[k] for s in segs]) for k in range(len(lengths))]
    cat = np.concatenate
    return EvalResult(
        label=label,
        est_name=est.name,
        ref_name=ref.name,
        config=cfg,
        segments=segs,
        skipped=skipped,
        ate_trans=Stats.of(cat([s.ate_t for s in segs])),
        ate_rot=Stats.of(cat([s.ate_r for s in segs])),
        rpe_delta_trans=Stats.of(cat([s.rpe_t for s in segs])),
        rpe_delta_rot=Stats.of(cat([s.rpe_r for s in segs])),
        lengths=pooled,
        coverage=coverage(
            ref.t_ns,
            est,
            round(cfg.offset_s * NS_PER_S),
            round(cfg.coverage_gap_s * NS_PER_S),
        ),
        ref_span_s=ref.duration_s(),
        ref_length_m=ref.path_length(),
        ate_trans_position_fit=_position_fit_ate(segs),
    )
