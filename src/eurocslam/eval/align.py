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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from eurocslam.errors import EvalError
from eurocslam.geometry import F64, inv_T

AlignMode = Literal["se3", "sim3", "posyaw", "origin", "none"]
ALIGN_MODES: tuple[str, ...] = ("se3", "sim3", "posyaw", "origin", "none")
MIN_PAIRS = 3


@dataclass(frozen=True)
class Alignment:
    """`p_ref = s * R @ p_est + t`."""

    mode: str
    R: F64
    t: F64
    s: float
    n_used: int
    note: str = ""  # how the fit departed from its mode (a rotation from orientations)

    @property
    def yaw_deg(self) -> float:
        return float(np.degrees(np.arctan2(self.R[1, 0], self.R[0, 0])))

    def matrix(self) -> F64:
        """4x4 similarity matrix."""
        M = np.eye(4)
        M[:3, :3] = self.s * self.R
        M[:3, 3] = self.t
        return M

    def apply(self, p: F64, R_world_body: F64) -> tuple[F64, F64]:
        """Aligned positions (N, 3) and rotations (N, 3, 3)."""
        p2 = self.s * (p @ self.R.T) + self.t
        R2 = np.einsum("ij,njk->nik", self.R, R_world_body)
        return p2, R2

    def summary(self) -> dict[str, object]:
        return {
            "mode": self.mode,
            "pairs_used": self.n_used,
            "scale": self.s,
            "yaw_deg": self.yaw_deg,
            "rotation": self.R.tolist(),
            "translation": self.t.tolist(),
            **({"note": self.note} if self.note else {}),
        }


def umeyama(x: F64, y: F64, with_scale: bool) -> tuple[F64, F64, float]:
    """Least-squares R, t, s with `y ~= s R x + t` (Umeyama 1991), x, y (N, 3)."""
    n = x.shape[0]
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    sigma_x = float(np.sum(xc * xc)) / n
    cov = yc.T @ xc / n
    u, d, vt = np.linalg.svd(cov)
    # evo's rank test, plus a relative one: exactly collinear points give d[1] ~ 1e-16 * d[0]
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < 2 or d[1] <= 1e-12 * d[0]:
        raise EvalError(
            "alignment is degenerate: the matched positions are (nearly) collinear or static; "
            "use --align origin or --align none"
        )
    S = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        S[2, 2] = -1.0
    R = u @ S @ vt
    s = float(np.trace(np.diag(d) @ S) / sigma_x) if with_scale else 1.0
    t = my - s * (R @ mx)
    return R, t, s


# a position fit whose rotation is this uncertain (1-sigma) says little about it: `eurocslam
# eval` warns (a 1.2 m take-off, nearly straight: ~10 deg); from UNDETERMINED on (the real
# V1_01 excerpt, a drone at rest: 16-18 deg) the fit takes its rotation from the orientations
# when it has them
UNCERTAIN_ROTATION_FIT_DEG = 1.0
UNDETERMINED_ROTATION_FIT_DEG = 10.0


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

    `T_ref0`/`T_est0` (first matched poses, 4x4) are needed for `origin`. With the matched
    orientations (`R_ref`, `R_est`, (N, 3, 3)), an `se3`/`sim3` fit whose positions cannot fix
    the rotation (`rotation_fit_sigma_deg` above `UNDETERMINED_ROTATION_FIT_DEG`: a platform at
    rest, a straight line) takes the rotation from the orientations instead, and the scale 1;
    the alignment's `note` says so.
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
    try:
        R, t, s = umeyama(x, y, with_scale=(mode == "sim3"))
        residual = float(np.sqrt(np.mean(np.sum((y - (s * x @ R.T + t)) ** 2, axis=1))))
        sigma = rotation_fit_sigma_deg(y, residual)
        if R_ref is None or R_est is None or sigma < UNDETERMINED_ROTATION_FIT_DEG:
            return Alignment(mode, R, t, s, k)
        why = f"the positions pin it down to ~{sigma:.0f} deg"
    except EvalError:  # exactly collinear or static positions
        if R_ref is None or R_est is None:
            raise
        why = "the positions do not fix it"
    R = rotation_from_orientations(R_ref[:k], R_est[:k])
    t = y.mean(axis=0) - R @ x.mean(axis=0)
    note = f"rotation from the orientations: {why}" + (", scale 1" if mode == "sim3" else "")
    return Alignment(mode, R, t, 1.0, k, note)
