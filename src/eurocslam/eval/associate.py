"""Timestamp association between a reference (ground truth) and an estimate.

Same rule as evo's `associate_trajectories` (nearest time, `max_diff`, `offset` added to the
estimate's stamps), vectorised with `searchsorted` on integer nanoseconds:

* start from the trajectory with fewer poses, so none of its poses is lost;
* for each of its stamps take the nearest stamp of the other within `max_diff` (on a tie the
  earlier one, as evo does); a pose of the longer trajectory may be matched more than once;
* "possible" pairs are the poses of the shorter trajectory inside the common time span
  (widened by `max_diff`); "matched" are those that found a partner.

Errors name both inputs: no time overlap, zero matches, and time bases that differ by ~1e9
(one file in seconds, the other in nanoseconds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from eurocslam.errors import EvalError
from eurocslam.timebase import NS_PER_S, UNIT_MIX_ORDERS, magnitude, unit_hint

I64 = NDArray[np.int64]


@dataclass(frozen=True)
class Association:
    """Matched index pairs (`idx_ref[k]` <-> `idx_est[k]`), in increasing estimate time."""

    idx_ref: I64
    idx_est: I64
    dt_ns: I64  # (t_est + offset) - t_ref for each pair
    n_ref: int
    n_est: int
    possible: int
    max_diff_ns: int
    offset_ns: int
    span_ns: tuple[int, int]  # common time span (in the reference's time base)

    @property
    def matched(self) -> int:
        return int(self.idx_ref.shape[0])

    def summary(self) -> dict[str, object]:
        return {
            "matched": self.matched,
            "possible": self.possible,
            "n_ref": self.n_ref,
            "n_est": self.n_est,
            "max_diff_s": self.max_diff_ns / NS_PER_S,
            "offset_s": self.offset_ns / NS_PER_S,
            "mean_abs_dt_s": float(np.mean(np.abs(self.dt_ns))) / NS_PER_S
            if self.matched
            else None,
            "common_span_s": [self.span_ns[0] / NS_PER_S, self.span_ns[1] / NS_PER_S],
        }


def _span(t: I64) -> str:
    return f"[{t[0] / NS_PER_S:.3f}, {t[-1] / NS_PER_S:.3f}] s ({len(t)} poses)"


def check_time_bases(t_ref: I64, t_est: I64, ref_name: str, est_name: str) -> None:
    """Fail when the two time bases differ by orders of magnitude (seconds read as nanoseconds
    or the like: `timebase.UNIT_MIX_ORDERS`)."""
    a, b = magnitude(t_ref), magnitude(t_est)
    if a <= 0 or b <= 0 or abs(a - b) <= UNIT_MIX_ORDERS:
        return
    ratio = 10 ** abs(a - b)
    small, big = (ref_name, est_name) if a < b else (est_name, ref_name)
    raise EvalError(
        f"time bases differ by a factor ~{ratio:.2g} ({unit_hint(ratio)}): {small} looks like it "
        f"was read in a larger unit than {big}. TUM time is seconds, EuRoC CSV time is "
        "nanoseconds; pass --time-unit / --gt-time-unit to override"
    )


def associate(
    t_ref: I64,
    t_est: I64,
    max_diff_ns: int = 10_000_000,
    offset_ns: int = 0,
    ref_name: str = "reference",
    est_name: str = "estimate",
) -> Association:
    """Associate estimate stamps (+ `offset_ns`) with reference stamps. Both must be sorted."""
    t_ref = np.asarray(t_ref, dtype=np.int64)
    t_est_raw = np.asarray(t_est, dtype=np.int64)
    if max_diff_ns < 0:
        raise EvalError(f"max time difference must be >= 0, got {max_diff_ns / NS_PER_S} s")
    if len(t_ref) == 0:
        raise EvalError(f"{ref_name}: no poses")
    if len(t_est_raw) == 0:
        raise EvalError(f"{est_name}: no poses")
    check_time_bases(t_ref, t_est_raw, ref_name, est_name)
    t_est = t_est_raw + np.int64(offset_ns)
    lo = max(int(t_ref[0]), int(t_est[0]))
    hi = min(int(t_ref[-1]), int(t_est[-1]))
    if lo - hi > max_diff_ns:
        raise EvalError(
            f"no time overlap: {ref_name} spans {_span(t_ref)}, {est_name} spans "
            f"{_span(t_est_raw)}"
            + (f" shifted by offset {offset_ns / NS_PER_S:g} s" if offset_ns else "")
            + "; are they from the same sequence? (--offset shifts the estimate)"
        )

    est_shorter = len(t_est) <= len(t_ref)
    short, long_ = (t_est, t_ref) if est_shorter else (t_ref, t_est)
    idx_s, idx_l = _nearest(short, long_, max_diff_ns)

    in_span = (short >= lo - max_diff_ns) & (short <= hi + max_diff_ns)
    possible = int(np.count_nonzero(in_span))
    if idx_s.size == 0:
        raise EvalError(
            f"zero timestamp matches between {ref_name} {_span(t_ref)} and {est_name} "
            f"{_span(t_est_raw)} within max diff {max_diff_ns / NS_PER_S:g} s"
            + (f" and offset {offset_ns / NS_PER_S:g} s" if offset_ns else "")
            + " (raise --max-diff or set --offset)"
        )
    idx_est, idx_ref = (idx_s, idx_l) if est_shorter else (idx_l, idx_s)
    order = np.argsort(idx_est, kind="stable")
    idx_est, idx_ref = idx_est[order], idx_ref[order]
    return Association(
        idx_ref=idx_ref,
        idx_est=idx_est,
        dt_ns=t_est[idx_est] - t_ref[idx_ref],
        n_ref=len(t_ref),
        n_est=len(t_est),
        possible=possible,
        max_diff_ns=int(max_diff_ns),
        offset_ns=int(offset_ns),
        span_ns=(lo, hi),
    )


def _nearest(short: I64, long_: I64, max_diff: int) -> tuple[I64, I64]:
    """For each stamp of `short`, the nearest stamp of sorted `long_` within max_diff (evo's
    tie rule: the later one only when strictly closer)."""
    if np.any(np.diff(long_) < 0):
        raise EvalError("internal: association needs sorted timestamps")
    n = len(long_)
    j = np.searchsorted(long_, short, side="right")
    j = np.minimum(j, n - 1)
    diff_ub = long_[j] - short
    has_lb = j > 0
    diff_lb = np.where(has_lb, short - long_[np.maximum(j - 1, 0)], np.iinfo(np.int64).max)
    take_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    inside = (short >= long_[0] - max_diff) & (short <= long_[-1] + max_diff)
    ok = inside & (take_ub | take_lb)
    best = np.where(take_ub, j, j - 1)
    return np.flatnonzero(ok).astype(np.int64), best[ok].astype(np.int64)
