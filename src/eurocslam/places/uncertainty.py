"""How uncertain a place match's pose is.

A verified match is a motion-only fit of the query's stereo measurements (uL, uR, v) to the
candidate keyframe's points, weighted by the pixels' noise. Its covariance propagates each
measurement's noise, widened by the uncertainty of the point it matched, through that fit (a
sandwich: the fit does not weigh the points' uncertainty itself). A point triangulated
from one stereo pair is uncertain mostly along its ray, sigma_Z ~ Z^2 / (f b) * sigma_d, so far
points say little about translation, and a candidate seen from a rig with a short baseline
less than from a long one. Both keyframes' depth uncertainty enters: the query's through its
uR row, the candidate's through its points.

Tangent spaces are [rotation, translation] (GTSAM's Pose3 order); the result is the covariance
of a left (world-frame) perturbation of the query's body pose, the frame a loop's drift `D`
(`T_world_query_measured @ inv(T_world_query_estimated)`) lives in.
"""

from __future__ import annotations

import numpy as np

from eurocslam.camera import RectifiedStereo
from eurocslam.geometry import F64, inv_T, se3_adjoint


def stereo_point_cov(uvr: F64, sigma: F64, geom: RectifiedStereo) -> F64:
    """Covariances (N, 3, 3) in the rectified camera frame of points triangulated from stereo
    measurements `uvr` (N, 3: uL, uR, v) with pixel sigmas `sigma` (N,) on each coordinate."""
    uL, uR, v = uvr[:, 0], uvr[:, 1], uvr[:, 2]
    d = np.maximum(uL - uR, 1e-3)
    fx, fy, b = geom.fx, geom.fy, geom.baseline
    # X = (uL - cx) b / d, Y = (v - cy) fx b / (fy d), Z = fx b / d
    X, Y = (uL - geom.cx) * b / d, (v - geom.cy) * fx * b / (fy * d)
    J = np.zeros((len(d), 3, 3))  # d(X, Y, Z) / d(uL, uR, v)
    J[:, 0, 0] = b / d - X / d
    J[:, 0, 1] = X / d
    J[:, 1, 0] = -Y / d
    J[:, 1, 1] = Y / d
    J[:, 1, 2] = fx * b / (fy * d)
    J[:, 2, 0] = -fx * b / (d * d)
    J[:, 2, 1] = fx * b / (d * d)
    return np.asarray(np.einsum("nij,n,nkj->nik", J, sigma * sigma, J), dtype=np.float64)


def match_covariance(
    T_rect0_world: F64,
    pts_world: F64,
    point_cov_world: F64,
    meas: F64,
    sigma: F64,
    geom: RectifiedStereo,
) -> F64:
    """Covariance (6, 6) of the query body pose that the fit of `meas` (N, 3: uL, uR, v of the
    query, pixel sigmas `sigma`) to `pts_world` (N, 3, with covariances `point_cov_world`) at
    `T_rect0_world` gives, as a left perturbation in the world frame. Infinite where fewer than
    two measurements leave the pose undetermined."""
    R, t = T_rect0_world[:3, :3], T_rect0_world[:3, 3]
    pc = pts_world @ R.T + t
    X, Y, Z = pc[:, 0], pc[:, 1], np.maximum(pc[:, 2], 1e-6)
    fx, fy, fxb = geom.fx, geom.fy, geom.fx * geom.baseline
    n = len(Z)
    Jp = np.zeros((n, 3, 3))  # d(uL, uR, v) / d(point in the camera frame)
    Jp[:, 0, 0] = fx / Z
    Jp[:, 0, 2] = -fx * X / Z**2
    Jp[:, 1, 0] = fx / Z
    Jp[:, 1, 2] = -(fx * X - fxb) / Z**2
    Jp[:, 2, 1] = fy / Z
    Jp[:, 2, 2] = -fy * Y / Z**2
    # the camera pose perturbed on the left: pc' = exp(dw) pc + dt, d pc / d(dw, dt)
    dpc = np.zeros((n, 3, 6))
    dpc[:, 0, 1], dpc[:, 0, 2] = pc[:, 2], -pc[:, 1]  # -[pc]x
    dpc[:, 1, 0], dpc[:, 1, 2] = -pc[:, 2], pc[:, 0]
    dpc[:, 2, 0], dpc[:, 2, 1] = pc[:, 1], -pc[:, 0]
    dpc[:, :, 3:] = np.eye(3)
    J = Jp @ dpc
    # each measurement's noise: the query's pixels and the candidate point's position
    Jw = Jp @ R
    C = np.einsum("nij,njk,nlk->nil", Jw, point_cov_world, Jw)
    C += (sigma * sigma)[:, None, None] * np.eye(3)
    # the fit weighs the pixels alone (1 / sigma^2), not the points' uncertainty: its
    # covariance is the sandwich H^-1 M H^-1, not the inverse of the optimal information
    w = 1.0 / (sigma * sigma)
    H = np.einsum("nji,n,njk->ik", J, w, J)
    if n < 2 or np.linalg.cond(H) > 1e12:
        return np.full((6, 6), np.inf)
    M = np.einsum("nji,n,njk,n,nkl->il", J, w, C, w, J)
    H_inv = np.linalg.inv(H)
    cov_cam = H_inv @ M @ H_inv
    # T_world_body' = exp(-Ad(T_world_rect0) d) T_world_body: the same covariance, moved
    A = se3_adjoint(inv_T(T_rect0_world))
    cov = A @ cov_cam @ A.T
    return np.asarray(0.5 * (cov + cov.T), dtype=np.float64)
