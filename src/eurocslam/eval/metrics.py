"""ATE and RPE on associated, aligned pose arrays. Pure numpy, vectorised.

Definitions (identical to evo 1.38 where evo has the metric):

* ATE translation: `|p_est_i - p_ref_i|` after alignment (evo APE `translation_part`);
  ATE rotation: angle of `R_est_i^T R_ref_i` in degrees (evo APE `rotation_angle_deg`).
* RPE per frame (evo RPE, delta in frames, consecutive pairs `(0, d), (d, 2d), ...`):
  `E_i = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`; translation error `|trans(E_i)|` (evo
  `translation_part`), rotation error the angle of `rot(E_i)` in degrees.
* RPE over distance (rpg_trajectory_evaluation style): for every start pose i and each length L,
  the pose j whose ground-truth distance travelled from i is nearest to L (accepted within
  `tol * L`); same `E` as above; also translation error in % of L (drift) and rotation in deg/m.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64

I64 = NDArray[np.int64]


@dataclass(frozen=True)
class Stats:
    """Summary statistics of an error array (std is the population std, as evo)."""

    n: int
    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float

    @classmethod
    def of(cls, e: F64) -> Stats:
        e = np.asarray(e, dtype=np.float64)
        if e.size == 0:
            nan = float("nan")
            return cls(0, nan, nan, nan, nan, nan, nan)
        return cls(
            int(e.size),
            float(np.sqrt(np.mean(e * e))),
            float(np.mean(e)),
            float(np.median(e)),
            float(np.std(e)),
            float(np.min(e)),
            float(np.max(e)),
        )

    def to_dict(self) -> dict[str, float | int | None]:
        return {
            k: (None if isinstance(v, float) and np.isnan(v) else v)
            for k, v in asdict(self).items()
        }


def rotation_angles_deg(R: F64) -> F64:
    """Rotation angles (N,) in degrees of rotation matrices (N, 3, 3)."""
    # atan2(sin, cos) stays accurate near 0 and pi, where arccos of the trace loses digits
    tr = np.trace(R, axis1=-2, axis2=-1)
    v = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]],
        axis=-1,
    )
    return cast(F64, np.degrees(np.arctan2(0.5 * np.linalg.norm(v, axis=-1), 0.5 * (tr - 1.0))))


def ate_errors(p_ref: F64, R_ref: F64, p_est: F64, R_est: F64) -> tuple[F64, F64]:
    """Per-pose translation error [m] and rotation error [deg] of aligned poses."""
    e_t = np.linalg.norm(p_est - p_ref, axis=1)
    e_r = rotation_angles_deg(np.einsum("nji,njk->nik", R_est, R_ref))
    return e_t, e_r


def relative_errors(
    p_ref: F64, R_ref: F64, p_est: F64, R_est: F64, i: I64, j: I64
) -> tuple[F64, F64]:
    """Translation [m] and rotation [deg] parts of E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)."""
    Rq = np.einsum("nji,njk->nik", R_ref[i], R_ref[j])
    tq = np.einsum("nji,nj->ni", R_ref[i], p_ref[j] - p_ref[i])
    Rp = np.einsum("nji,njk->nik", R_est[i], R_est[j])
    tp = np.einsum("nji,nj->ni", R_est[i], p_est[j] - p_est[i])
    # E = Qrel^-1 Prel: R_E = Rq^T Rp, t_E = Rq^T (tp - tq)
    t_e = np.einsum("nji,nj->ni", Rq, tp - tq)
    R_e = np.einsum("nji,njk->nik", Rq, Rp)
    return np.linalg.norm(t_e, axis=1), rotation_angles_deg(R_e)


def delta_pairs(n: int, delta: int) -> tuple[I64, I64]:
    """evo's consecutive pairs for a delta in frames: (0, d), (d, 2d), ..."""
    ids = np.arange(0, n, max(int(delta), 1), dtype=np.int64)
    return ids[:-1], ids[1:]


def cumulative_distance(p: F64) -> F64:
    """Distance travelled from the first position, (N,)."""
    if len(p) == 0:
        return np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def distance_pairs(dist: F64, length: float, tol: float = 0.1) -> tuple[I64, I64]:
    """Every start i with the end j whose travelled distance from i is nearest to `length`
    (within `tol * length`). `dist` is cumulative distance (non-decreasing)."""
    n = dist.shape[0]
    if n < 2 or length <= 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    target = dist + length
    j_hi = np.searchsorted(dist, target, side="left")
    j_lo = j_hi - 1
    i = np.arange(n)
    j_hi_c = np.minimum(j_hi, n - 1)
    err_hi = np.where(j_hi < n, np.abs(dist[j_hi_c] - target), np.inf)
    err_lo = np.where(j_lo > i, np.abs(dist[np.maximum(j_lo, 0)] - target), np.inf)
    j = np.where(err_lo <= err_hi, j_lo, j_hi_c)
    err = np.minimum(err_lo, err_hi)
    ok = (err <= tol * length) & (j > i)
    return i[ok].astype(np.int64), j[ok].astype(np.int64)


@dataclass(frozen=True)
class RpeLength:
    """RPE over one sub-trajectory length."""

    fraction: float | None  # of the ground-truth length (None when given in metres)
    length_m: float
    trans: Stats
    trans_pct: Stats  # translation error in % of length_m (drift)
    rot: Stats  # degrees
    rot_deg_per_m: Stats
    trans_errors: F64  # per pair [m], for box plots and pooling
    rot_errors: F64  # per pair [deg]

    @classmethod
    def of(cls, fraction: float | None, length_m: float, e_t: F64, e_r: F64) -> RpeLength:
        """Statistics of per-pair translation [m] and rotation [deg] errors at one length."""
        L = float(length_m)
        return cls(
            fraction,
            L,
            Stats.of(e_t),
            Stats.of(100.0 * e_t / L),
            Stats.of(e_r),
            Stats.of(e_r / L),
            e_t,
            e_r,
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "fraction": self.fraction,
            "length_m": self.length_m,
            "pairs": self.trans.n,
            "trans_m": self.trans.to_dict(),
            "trans_pct": self.trans_pct.to_dict(),
            "rot_deg": self.rot.to_dict(),
            "rot_deg_per_m": self.rot_deg_per_m.to_dict(),
        }


def rpe_length(
    p_ref: F64,
    R_ref: F64,
    p_est: F64,
    R_est: F64,
    length_m: float,
    fraction: float | None = None,
    tol: float = 0.1,
    dist: F64 | None = None,
) -> RpeLength:
    """RPE over sub-trajectories of `length_m` metres of ground-truth travel."""
    d = cumulative_distance(p_ref) if dist is None else dist
    i, j = distance_pairs(d, length_m, tol)
    if i.size:
        e_t, e_r = relative_errors(p_ref, R_ref, p_est, R_est, i, j)
    else:
        e_t, e_r = np.zeros(0), np.zeros(0)
    return RpeLength.of(fraction, length_m, e_t, e_r)


def pool_lengths(parts: list[RpeLength]) -> RpeLength:
    """Pool RPE pairs of several segments evaluated at the same length."""
    e_t = np.concatenate([p.trans_errors for p in parts])
    e_r = np.concatenate([p.rot_errors for p in parts])
    return RpeLength.of(parts[0].fraction, parts[0].length_m, e_t, e_r)
