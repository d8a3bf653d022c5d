"""Pose solvers: a pose from 3D-2D matches, used by tracking and by place recognition.

`optimize_pose` refines a pose on stereo reprojection errors with ORB-SLAM's outlier schedule;
`pnp_ransac` finds one without a prior (`cv2.solvePnPRansac`); `pose_from_descriptors`
matches a frame's descriptors to a set of points first. Poses are `T_rect0_world`.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.linalg import LinAlgError
from numpy.typing import NDArray

from eurocslam.camera import RectifiedStereo
from eurocslam.geometry import F64, make_T, rigid, so3_exp

# what np.linalg.solve runs for a vector b (a private numpy module: where a numpy version lacks
# it, `_solve6` is `np.linalg.solve` itself, the same numbers)
_SOLVE1 = getattr(getattr(np.linalg, "_umath_linalg", None), "solve1", None)

CHI2_STEREO_95 = 7.815  # chi-square 95 %, 3 dof: a stereo measurement (u, uR, v) in sigmas
CHI2_MONO_95 = 5.991  # 2 dof: a mono one (u, v)
POSE_IN_FRONT_M = 0.05  # a point nearer the camera plane (or behind) weighs nothing in a solve
MIN_PNP_POINTS = 6  # fewer correspondences (or RANSAC inliers): no PnP pose
_CONVERGED = 1e-5  # a Gauss-Newton step below this (10 um / 10 urad) ends the iterations
_DAMPING = 1e-9 * np.eye(6)  # added to the normal equations' matrix


def _raise_singular(err: str, flag: int) -> None:
    raise LinAlgError("Singular matrix")


def _solve6(H: F64, g: F64) -> F64:
    """`np.linalg.solve(H, g)` for a float64 (6, 6) and (6,): the same LAPACK gufunc under the
    same error state, without the wrapper's checks and conversions (a call per Gauss-Newton
    iteration of every pose solve)."""
    if _SOLVE1 is None:
        return np.asarray(np.linalg.solve(H, g), dtype=np.float64)
    with np.errstate(
        call=_raise_singular, invalid="call", over="ignore", divide="ignore", under="ignore"
    ):
        return _SOLVE1(H, g, signature="dd->d")  # type: ignore[no-any-return]


def optimize_pose(
    T_rect0_world: F64,
    xyz: F64,
    meas: F64,
    sigma: F64,
    geom: RectifiedStereo,
    chi2_stereo: float,
    chi2_mono: float,
    rounds: int = 4,
    iterations: int = 6,
) -> tuple[F64, NDArray[np.bool_], F64]:
    """Motion-only Gauss-Newton on stereo (uL, uR, v) reprojection errors (uR NaN: mono).

    ORB-SLAM's schedule: `rounds` rounds of Huber-weighted iterations; after each round every
    measurement is re-classified by its chi-square (outliers get zero weight, may come back),
    the robust kernel is dropped in the last round, and a robust round whose inliers are the
    last round's is skipped (it would stop where that one did). `sigma` is the pixel sigma per
    measurement (octave scale). Returns (T_rect0_world, inlier mask, chi2 per measurement).
    """
    T = rigid(T_rect0_world)
    n = xyz.shape[0]
    inlier = np.ones(n, dtype=bool)
    chi2 = np.zeros(n)
    if n == 0:
        return T, inlier, chi2
    stereo = np.isfinite(meas[:, 1])
    m_u, m_v = meas[:, 0], meas[:, 2]
    m_r = np.where(stereo, meas[:, 1], 0.0)
    inv_s2 = 1.0 / (sigma * sigma)
    thr = np.where(stereo, chi2_stereo, chi2_mono)
    fx, fy, cx, cy = geom.fx, geom.fy, geom.cx, geom.cy
    fxb = fx * geom.baseline
    st = stereo.astype(np.float64)
    xyz_t = np.ascontiguousarray(xyz.T)

    def residuals(T: F64) -> tuple[Any, ...]:
        X, Y, Z = T[:3, :3] @ xyz_t + T[:3, 3:4]
        front = Z > POSE_IN_FRONT_M
        iz = 1.0 / np.where(front, Z, 1.0)
        u = fx * X * iz + cx
        ru = u - m_u
        rr = (u - fxb * iz - m_r) * st
        rv = fy * Y * iz + cy - m_v
        e2 = (ru * ru + rr * rr + rv * rv) * inv_s2
        return X, Y, Z, iz, front, ru, rr, rv, e2

    # J[k, m] (6, 3, n): d(measurement m = u, uR, v)/d(parameter k = dt, dw); rows contiguous
    J = np.empty((6, 3, n))
    r = np.empty((3, n))
    previous: NDArray[np.bool_] | None = None
    # the residuals at the current pose: a round starts where the last one ended (or stopped
    # without a step), at the pose whose residuals classified the measurements
    res = residuals(T)
    for rnd in range(rounds):
        robust = rnd < rounds - 1
        if robust and previous is not None and np.array_equal(previous, inlier):
            continue  # the last round's inliers again: its converged pose stands
        previous = inlier
        for _ in range(iterations):
            X, Y, Z, iz, front, ru, rr, rv, e2 = res
            good = inlier & front
            if np.count_nonzero(good) < 4:
                break
            w = inv_s2 * good
            if robust:  # Huber: weight sqrt(delta^2 / e^2) beyond the chi-square threshold
                w = np.where(e2 > thr, w * np.sqrt(thr / np.maximum(e2, 1e-12)), w)
            # for pc' = exp(dw) pc + dt; rotation part j . (-[pc]x)
            a = fx * iz
            c = fy * iz
            du_dz = -X * a * iz
            duR_dz = du_dz + fxb * iz * iz
            dv_dz = -Y * c * iz
            J[0, 0] = a
            J[1, 0] = 0.0
            J[2, 0] = du_dz
            J[3, 0] = Y * du_dz
            J[4, 0] = Z * a - X * du_dz
            J[5, 0] = -Y * a
            J[:, 1] = J[:, 0]
            J[2, 1] = duR_dz
            J[3, 1] = Y * duR_dz
            J[4, 1] = Z * a - X * duR_dz
            J[:, 1] *= st
            J[0, 2] = 0.0
            J[1, 2] = c
            J[2, 2] = dv_dz
            J[3, 2] = Y * dv_dz - Z * c
            J[4, 2] = -X * dv_dz
            J[5, 2] = X * c
            r[0], r[1], r[2] = ru, rr, rv
            Jw = (J * w).reshape(6, 3 * n)
            H = Jw @ J.reshape(6, 3 * n).T
            g = Jw @ r.reshape(-1)
            try:
                dx = -_solve6(H + _DAMPING, g)
            except LinAlgError:
                break
            dR = so3_exp(dx[3:])
            T = make_T(dR @ T[:3, :3], dR @ T[:3, 3] + dx[:3])
            res = residuals(T)
            if math.sqrt(dx.dot(dx)) < _CONVERGED:  # np.linalg.norm's own arithmetic
                break
        *_, front, _, _, _, chi2 = res
        inlier = (chi2 < thr) & front
    return rigid(T), inlier, chi2


def pnp_ransac(
    xyz: F64,
    uv: F64,
    geom: RectifiedStereo,
    T_guess: F64 | None,
    reproj_px: float,
    iterations: int,
) -> tuple[F64 | None, NDArray[np.bool_]]:
    """`cv2.solvePnPRansac` on world points vs rectified left pixels. (T_rect0_world, inliers)."""
    n = xyz.shape[0]
    inl = np.zeros(n, dtype=bool)
    if n < MIN_PNP_POINTS:
        return None, inl
    K = np.array([[geom.fx, 0, geom.cx], [0, geom.fy, geom.cy], [0, 0, 1.0]])
    kwargs: dict[str, Any] = {}
    if T_guess is not None:
        rvec0, _ = cv2.Rodrigues(T_guess[:3, :3])
        kwargs = {"useExtrinsicGuess": True, "rvec": rvec0, "tvec": T_guess[:3, 3].reshape(3, 1)}
    try:
        ok, rvec, tvec, idx = cv2.solvePnPRansac(
            xyz.astype(np.float64),
            uv.astype(np.float64),
            K,
            None,
            iterationsCount=iterations,
            reprojectionError=reproj_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_EPNP if T_guess is None else cv2.SOLVEPNP_ITERATIVE,
            **kwargs,
        )
    except cv2.error:
        return None, inl
    if not ok or idx is None or len(idx) < MIN_PNP_POINTS:
        return None, inl
    inl[idx.reshape(-1)] = True
    R, _ = cv2.Rodrigues(rvec)
    return make_T(np.asarray(R, np.float64), np.asarray(tvec, np.float64).reshape(3)), inl


def pose_from_descriptors(
    desc: NDArray[np.uint8],
    uv: F64,
    points_xyz: F64,
    points_desc: NDArray[np.uint8],
    geom: RectifiedStereo,
    ratio: float,
    max_hamming: int,
    min_inliers: int,
    reproj_px: float,
    iterations: int,
) -> F64 | None:
    """The pose (T_rect0_world) of a frame whose keypoints (`desc`, pixels `uv`) see the points
    (`points_xyz`, `points_desc`), without a prior: each keypoint's nearest point by descriptor
    (best under `ratio` times the second, at most `max_hamming`), then `pnp_ransac`; None with
    fewer than `min_inliers` matches or inliers."""
    if points_xyz.shape[0] < MIN_PNP_POINTS or desc.shape[0] < MIN_PNP_POINTS:
        return None
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc, points_desc, k=2)
    q, t = [], []
    for pair in knn:
        if (
            len(pair) == 2
            and pair[0].distance < ratio * pair[1].distance
            and (pair[0].distance <= max_hamming)
        ):
            q.append(pair[0].queryIdx)
            t.append(pair[0].trainIdx)
    if len(q) < min_inliers:
        return None
    qi, ti = np.array(q), np.array(t)
    T, inl = pnp_ransac(points_xyz[ti], uv[qi], geom, None, reproj_px, iterations)
    if T is None or inl.sum() < min_inliers:
        return None
    return T
