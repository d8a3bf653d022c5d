"""Trajectory alignment: estimate -> reference frame.

Modes (`AlignMode`):

* `se3`   Umeyama rotation + translation (evo `-a`; the headline ATE of ORB-SLAM3 / Basalt);
* `sim3`  Umeyama with scale (evo `-as`; monocular systems);
* `posyaw` 4-DoF: rotation about the gravity axis z only + translation, closed form (what VIO
  papers and rpg_trajectory_evaluation report; roll and pitch are observable with an IMU);
* `origin` the first estimate pose is mapped onto the first reference pose (evo `--align_origin`);
* `none`  identity.

`first_n` fits on the first N matched pairs only (evo `--n_to_align`). The result is a similarity
`p_ref ~= s * R @ p_est + t`, applied to orientations as `R @ R_est`.

**When positions decide an se3/sim3 fit** (evo's definition, Umeyama on positions only) and when
the rotation comes from the orientations instead. What the ATE needs is the *position error* after
the fit, not a unique rotation:

* a path that spans at least a line: the positions fix the line's direction, and a rotation about
  the line's own axis moves the aligned positions only within their lateral spread, so the
  minimum of the fit is unique even where its rotation is not (a straight road, a highway). On an
  exactly straight path the rotation about the line is free and leaves every position error
  unchanged: the fit takes it from the orientations (evo takes whatever its SVD returns, when its
  rank test lets it return anything), so ATE rotation means something there too;
* a platform at rest: the positions' whole extent is noise, comparable to the residual, and the
  fit turns the estimate's noise onto the reference's: its rotation is arbitrary (ATE rotation 79
  deg on the real V1_01 excerpt) and its ATE is noise fitted to noise.

The rule compares the two with the fit's own numbers (`extent_sigmas`): the reference's RMS extent
along its main direction over the fit's per-axis RMS residual (`residual / sqrt(3)`). The positions
decide from `DETERMINED_EXTENT_SIGMAS` = 3 on: the main direction stands out of the residual by 3
sigma, and the fit then fixes it within atan(1/3) whatever the errors' correlation. Noise alone
stays below: at rest an SE(3) residual holds the reference's noise and the estimate's, so the
ratio is at most sqrt(3) (about 1 for isotropic noise), plus what the fit's chance correlation of
noise with noise gains; a Sim(3) fit may shrink the estimate to a point and leave the reference's
own spread as residual, where the ratio reaches 3 only if estimate and reference correlate by
more than 0.82 (real motion seen by both). Below 3, with the matched orientations given, the
rotation is the chordal mean of reference x estimate^-1 (scale 1 for sim3) and the alignment keeps
the position-only fit (`position_fit`) so a report can give both figures.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from eurocslam.errors import EvalError
from eurocslam.geometry import F64, inv_T

AlignMode = Literal["se3", "sim3", "posyaw", "origin", "none"]
ALIGN_MODES: tuple[str, ...] = ("se3", "sim3", "posyaw", "origin", "none")
MIN_PAIRS = 3
# an se3/sim3 fit of positions decides the alignment when the reference's RMS extent along its
# main direction is at least this many per-axis RMS residuals (see the module docstring)
DETERMINED_EXTENT_SIGMAS = 3.0
# singular values of the cross-covariance below this fraction of the largest are rounding: the
# positions are exactly collinear (the second) or one side does not move (the largest, relative
# to the spreads)
_RANK_RTOL = 1e-12


@dataclass(frozen=True)
class Alignment:
    """`p_ref = s * R @ p_est + t`."""

    mode: str
    R: F64
    t: F64
    s: float
    n_used: int
    note: str = ""  # how the fit departed from a plain position fit (rotation from orientations)
    # "positions" (Umeyama, evo's definition) or "orientations" (the rotation from the matched
    # orientations, because the positions do not decide it)
    basis: str = "positions"
    # se3/sim3: the reference's extent along its main direction in per-axis RMS residuals of the
    # position fit (None where there is no position fit)
    extent_sigmas: float | None = None
    # with basis "orientations": the position-only fit (evo's), for its figure beside the headline
    position_fit: Alignment | None = field(default=None, repr=False)

    @property
    def yaw_deg(self) -> float:
        return float(np.degrees(np.arctan2(self.R[1, 0], self.R[0, 0])))

    @property
    def from_orientations(self) -> bool:
        return self.basis == "orientations"

    def matrix(self) -> F64:
        """4x4 similarity matrix."""
        M = np.eye(4)
        M[:3, :3] = self.s * self.R
        M[:3, 3] = self.t
        return M

    def apply_positions(self, p: F64) -> F64:
        """Aligned positions (N, 3)."""
        return np.asarray(self.s * (p @ self.R.T) + self.t, dtype=np.float64)

    def apply(self, p: F64, R_world_body: F64) -> tuple[F64, F64]:
        """Aligned positions (N, 3) and rotations (N, 3, 3)."""
        R2 = np.einsum("ij,njk->nik", self.R, R_world_body)
        return self.apply_positions(p), R2

    def summary(self) -> dict[str, object]:
        d: dict[str, object] = {
            "mode": self.mode,
            "pairs_used": self.n_used,
            "scale": self.s,
            "yaw_deg": self.yaw_deg,
            "rotation": self.R.tolist(),
            "translation": self.t.tolist(),
        }
        if self.mode in ("se3", "sim3"):
            d["basis"] = self.basis
            d["extent_sigmas"] = self.extent_sigmas
        if self.note:
            d["note"] = self.note
        if self.position_fit is not None:
            d["position_fit"] = self.position_fit.summary()
        return d


@dataclass(frozen=True)
class _CrossCovariance:
    """Umeyama's SVD of the positions' cross-covariance, `cov = u diag(d) vt`."""

    u: F64
    d: F64
    vt: F64
    mx: F64
    my: F64
    var_x: float  # mean squared distance of x from its mean


def _cross_covariance(x: F64, y: F64) -> _CrossCovariance:
    n = x.shape[0]
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    var_x = float(np.sum(xc * xc)) / n
    var_y = float(np.sum(yc * yc)) / n
    u, d, vt = np.linalg.svd(yc.T @ xc / n)
    if not d[0] > _RANK_RTOL * np.sqrt(var_x * var_y):
        raise EvalError(
            "alignment is degenerate: the matched positions of one side do not move; "
            "use --align origin or --align none"
        )
    return _CrossCovariance(u, d, vt, mx, my, var_x)


def _is_collinear(c: _CrossCovariance) -> bool:
    """Exactly collinear positions (either side): the cross-covariance has rank 1."""
    return bool(c.d[1] <= _RANK_RTOL * c.d[0])


def _umeyama_from(c: _CrossCovariance, with_scale: bool) -> tuple[F64, F64, float]:
    S = np.eye(3)
    if np.linalg.det(c.u) * np.linalg.det(c.vt) < 0.0:
        S[2, 2] = -1.0
    R = c.u @ S @ c.vt
    s = float(np.trace(np.diag(c.d) @ S) / c.var_x) if with_scale else 1.0
    t = c.my - s * (R @ c.mx)
    return R, t, s


def umeyama(x: F64, y: F64, with_scale: bool) -> tuple[F64, F64, float]:
    """Least-squares R, t, s with `y ~= s R x + t` (Umeyama 1991, evo's `umeyama_alignment`),
    x, y (N, 3). Exactly collinear positions give a rotation that maps the one line onto the
    other, its turn about the line arbitrary (every residual is the same for any turn; evo
    returns such a fit where its absolute rank test lets it, i.e. on long lines); positions of
    which one side does not move are an error."""
    return _umeyama_from(_cross_covariance(x, y), with_scale)


def extent_sigmas(p_ref: F64, residual_rms: float) -> float:
    """The reference positions' RMS extent along their main direction over a fit's per-axis RMS
    residual (`residual_rms / sqrt(3)`); infinite for a residual of zero. Below
    `DETERMINED_EXTENT_SIGMAS` the positions' extent is comparable to the noise (a platform at
    rest)."""
    n = p_ref.shape[0]
    extent = float(np.linalg.svd(p_ref - p_ref.mean(axis=0), compute_uv=False)[0]) / np.sqrt(n)
    per_axis = residual_rms / np.sqrt(3.0)
    return extent / per_axis if per_axis > 0.0 else float("inf")


# a position fit whose rotation is this uncertain (1-sigma) says little about it: `eurocslam
# eval` warns that ATE rotation is not meaningful (a 1.2 m take-off, nearly straight: ~10 deg)
UNCERTAIN_ROTATION_FIT_DEG = 1.0


def rotation_fit_sigma_deg(p_ref: F64, residual_rms: float) -> float:
    """How well positions pin down a fit's rotation about their main direction: the fit's RMS
    residual over their spread across that direction (1-sigma for independent errors). Large on
    a (nearly) straight path or a platform at rest."""
    d = np.linalg.svd(p_ref - p_ref.mean(axis=0), compute_uv=False)
    return float(np.degrees(np.arctan2(residual_rms, float(np.hypot(d[1], d[2])))))


def rotation_from_orientations(R_ref: F64, R_est: F64) -> F64:
    """The rotation R that best maps estimate orientations onto reference ones (R_ref ~= R
    R_est, chordal least squares)."""
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", R_ref, R_est))
    S = np.eye(3)
    S[2, 2] = np.sign(np.linalg.det(u @ vt))
    return np.asarray(u @ S @ vt, dtype=np.float64)


def turn_about_axis_from_orientations(R0: F64, axis: F64, R_ref: F64, R_est: F64) -> F64:
    """`Rot(axis, phi) @ R0` with the turn phi that best maps estimate orientations onto
    reference ones (chordal least squares, closed form): maximises `tr(R^T M)`, M = sum R_ref
    R_est^T, over the rotations about the unit `axis`."""
    N = np.einsum("nij,nkj->ik", R_ref, R_est) @ R0.T
    a = axis / np.linalg.norm(axis)
    ana = float(a @ N @ a)
    cos_part = float(np.trace(N)) - ana
    sin_part = float(a @ np.array([N[2, 1] - N[1, 2], N[0, 2] - N[2, 0], N[1, 0] - N[0, 1]]))
    phi = np.arctan2(sin_part, cos_part)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    R_turn = np.eye(3) + np.sin(phi) * K + (1.0 - np.cos(phi)) * (K @ K)
    return np.asarray(R_turn @ R0, dtype=np.float64)


def posyaw(x: F64, y: F64) -> tuple[F64, F64]:
    """Closed-form yaw + translation with `y ~= Rz(yaw) x + t` (least squares)."""
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    a = float(np.sum(xc[:, 0] * yc[:, 0] + xc[:, 1] * yc[:, 1]))
    b = float(np.sum(xc[:, 0] * yc[:, 1] - xc[:, 1] * yc[:, 0]))
    if abs(a) + abs(b) < 1e-12:
        raise EvalError(
            "position+yaw alignment is degenerate: the matched positions do not move "
            "horizontally; use --align origin or --align none"
        )
    yaw = np.arctan2(b, a)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return R, my - R @ mx


def _length(m: float) -> str:
    return f"{1000 * m:.2g} mm" if m < 0.1 else f"{m:.3g} m"


def _position_fit(mode: str, x: F64, y: F64, R_ref: F64 | None, R_est: F64 | None) -> Alignment:
    """Umeyama on positions (evo's fit), with `extent_sigmas`; on exactly collinear positions
    the turn about the line comes from the orientations when they are given."""
    c = _cross_covariance(x, y)
    R, t, s = _umeyama_from(c, with_scale=(mode == "sim3"))
    note = ""
    if _is_collinear(c) and R_ref is not None and R_est is not None:
        # every turn about the reference's line (R maps the estimate's line onto it) leaves
        # every position error unchanged: take the turn the orientations agree with
        R = turn_about_axis_from_orientations(R, c.u[:, 0], R_ref, R_est)
        t = c.my - s * (R @ c.mx)
        note = (
            "positions on a line: the rotation about it from the orientations (it does not "
            "change the position errors)"
        )
    residual = float(np.sqrt(np.mean(np.sum((y - (s * x @ R.T + t)) ** 2, axis=1))))
    k = x.shape[0]
    return Alignment(mode, R, t, s, k, note, "positions", extent_sigmas(y, residual))


def align(
    mode: str,
    p_ref: F64,
    p_est: F64,
    T_ref0: F64 | None = None,
    T_est0: F64 | None = None,
    first_n: int | None = None,
    R_ref: F64 | None = None,
    R_est: F64 | None = None,
) -> Alignment:
    """Fit the alignment of matched estimate positions onto reference positions.

    `T_ref0`/`T_est0` (first matched poses, 4x4) are needed for `origin`. An `se3`/`sim3` fit is
    Umeyama on positions (evo's) wherever the positions decide it (`extent_sigmas` from
    `DETERMINED_EXTENT_SIGMAS` on, see the module docstring); where they do not (a platform at
    rest) and the matched orientations (`R_ref`, `R_est`, (N, 3, 3)) are given, the rotation
    comes from the orientations, the scale is 1, `basis` is "orientations", `note` says why and
    `position_fit` keeps the position-only fit.
    """
    n = p_ref.shape[0]
    if mode not in ALIGN_MODES:
        raise EvalError(f"unknown alignment '{mode}' (one of {', '.join(ALIGN_MODES)})")
    if mode == "none":
        return Alignment("none", np.eye(3), np.zeros(3), 1.0, 0)
    if mode == "origin":
        if T_ref0 is None or T_est0 is None or n == 0:
            raise EvalError("origin alignment needs at least one matched pose")
        M = T_ref0 @ inv_T(T_est0)
        return Alignment("origin", M[:3, :3].copy(), M[:3, 3].copy(), 1.0, 1)
    k = n if first_n is None or first_n <= 0 else min(first_n, n)
    if k < MIN_PAIRS:
        raise EvalError(
            f"{mode} alignment needs at least {MIN_PAIRS} matched poses, got {k}"
            + (f" (--align-first {first_n})" if first_n else "")
        )
    x, y = p_est[:k], p_ref[:k]
    if mode == "posyaw":
        R, t = posyaw(x, y)
        return Alignment("posyaw", R, t, 1.0, k)
    have_orientations = R_ref is not None and R_est is not None
    Rr = None if R_ref is None else R_ref[:k]
    Re = None if R_est is None else R_est[:k]
    fit: Alignment | None
    try:
        fit = _position_fit(mode, x, y, Rr, Re)
    except EvalError:  # one side does not move at all: no position fit (evo raises too)
        if not have_orientations:
            raise
        fit = None
    if fit is not None and (
        not have_orientations or (fit.extent_sigmas or 0.0) >= DETERMINED_EXTENT_SIGMAS
    ):
        return fit
    assert Rr is not None and Re is not None
    R = rotation_from_orientations(Rr, Re)
    t = y.mean(axis=0) - R @ x.mean(axis=0)
    if fit is None:
        why = "the matched positions of one side do not move"
    else:
        extent = float(np.linalg.svd(y - y.mean(axis=0), compute_uv=False)[0]) / np.sqrt(k)
        why = (
            f"the reference's extent along its main direction ({_length(extent)} RMS) is "
            f"{fit.extent_sigmas:.1f} sigma of the position fit's per-axis residual, under "
            f"{DETERMINED_EXTENT_SIGMAS:g} (a platform at rest)"
        )
    note = f"rotation from the orientations: {why}" + (", scale 1" if mode == "sim3" else "")
    sigmas = None if fit is None else fit.extent_sigmas
    return Alignment(mode, R, t, 1.0, k, note, "orientations", sigmas, fit)
