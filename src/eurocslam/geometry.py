"""SE(3) and quaternion helpers. The only place that converts wxyz <-> xyzw.

Conventions: `T_a_b` is a 4x4 homogeneous matrix mapping points from frame b into frame a.
Quaternions are Hamilton, unit norm; arrays are `(..., 4)`. EuRoC CSVs are w-first (`wxyz`),
ROS and TUM are x-first (`xyzw`).
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
_I3 = np.eye(3)


def wxyz_to_xyzw(q: F64) -> F64:
    q = np.asarray(q, dtype=np.float64)
    return np.concatenate([q[..., 1:4], q[..., 0:1]], axis=-1)


def xyzw_to_wxyz(q: F64) -> F64:
    q = np.asarray(q, dtype=np.float64)
    return np.concatenate([q[..., 3:4], q[..., 0:3]], axis=-1)


def normalize_quat(q: F64) -> F64:
    """Normalise quaternions (any layout); raises ValueError on a zero-norm quaternion."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("zero-norm quaternion")
    return cast(F64, q / n)


def quat_wxyz_to_rot(q: F64) -> F64:
    """Rotation matrices (..., 3, 3) from unit quaternions (..., 4) in wxyz order."""
    q = normalize_quat(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty((*q.shape[:-1], 3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def _rot_to_quat_one(m: list[list[float]]) -> F64:
    """`rot_to_quat_wxyz` of one matrix (nested lists), same Shepperd branch choice."""
    (a, b, c), (d, e, f), (g, h, i) = m
    key = (1 + a + e + i, 1 + a - e - i, 1 - a + e - i, 1 - a - e + i)
    k = key.index(max(key))
    if k == 0:
        q = (key[0], h - f, c - g, d - b)
    elif k == 1:
        q = (h - f, key[1], b + d, c + g)
    elif k == 2:
        q = (c - g, b + d, key[2], f + h)
    else:
        q = (d - b, c + g, f + h, key[3])
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0:
        n = -n
    return np.array([q[0] / n, q[1] / n, q[2] / n, q[3] / n])


def rot_to_quat_wxyz(r: F64) -> F64:
    """Unit quaternions (..., 4) wxyz with w >= 0 from rotation matrices (..., 3, 3). Vectorised."""
    r = np.asarray(r, dtype=np.float64)
    if r.shape == (3, 3):  # one matrix (a message per frame): plain floats are 20x faster
        return _rot_to_quat_one(r.tolist())
    shape = r.shape[:-2]
    m = r.reshape(-1, 3, 3)
    d0, d1, d2 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    # four candidate solutions; pick the numerically largest denominator per matrix (Shepperd)
    # fmt: off
    cand = np.stack(
        [
            np.stack([1 + d0 + d1 + d2, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0],
                      m[:, 1, 0] - m[:, 0, 1]], axis=1),
            np.stack([m[:, 2, 1] - m[:, 1, 2], 1 + d0 - d1 - d2, m[:, 0, 1] + m[:, 1, 0],
                      m[:, 0, 2] + m[:, 2, 0]], axis=1),
            np.stack([m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1 - d0 + d1 - d2,
                      m[:, 1, 2] + m[:, 2, 1]], axis=1),
            np.stack([m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1],
                      1 - d0 - d1 + d2], axis=1),
        ],
        axis=1,
    )
    # fmt: on
    key = np.stack([1 + d0 + d1 + d2, 1 + d0 - d1 - d2, 1 - d0 + d1 - d2, 1 - d0 - d1 + d2], axis=1)
    q = cand[np.arange(m.shape[0]), np.argmax(key, axis=1)]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    return cast(F64, q.reshape(*shape, 4))


def make_T(r: F64, t: F64) -> F64:
    """4x4 (or (..., 4, 4)) homogeneous transforms from rotations and translations."""
    r = np.asarray(r, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros((*r.shape[:-2], 4, 4))
    T[..., :3, :3] = r
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv_T(T: F64) -> F64:
    """Inverse of rigid transforms (..., 4, 4)."""
    T = np.asarray(T, dtype=np.float64)
    r = T[..., :3, :3]
    rt = np.swapaxes(r, -1, -2)
    t = T[..., :3, 3]
    return make_T(rt, -np.einsum("...ij,...j->...i", rt, t))


def rigid(T: F64) -> F64:
    """The nearest rigid transform: rotation projected onto SO(3) (SVD), bottom row exact.

    Every pose entering or leaving tracking passes through here: a rotation that is slightly
    off SO(3) makes `inv_T` (a transpose) an inexact inverse, and compositions amplify it.
    """
    T = np.asarray(T, dtype=np.float64)
    R = T[:3, :3]
    if (
        np.abs(R.T @ R - _I3).max() < 1e-12
        and T[3, 3] == 1.0
        and not T[3, :3].any()
        and _det3_sign_positive(R)
    ):
        return cast(F64, T.copy())  # already rigid to round-off: skip the SVD (hot path)
    u, _, vt = np.linalg.svd(R)
    R = u @ vt
    if np.linalg.det(R) < 0:
        R = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    return make_T(R, T[:3, 3])


def _det3_sign_positive(R: F64) -> bool:
    """det(R) > 0 for a 3x3 `R` already orthogonal to 1e-12 (det +-1 to round-off: any
    formula gives its sign), by the triple product on Python floats instead of an LU
    factorisation (`np.linalg.det`: its wrapper is most of `rigid`'s hot path)."""
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    return bool(a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) > 0)


def extrapolate(Ta: F64, Tb: F64, s: float) -> F64:
    """`Tb` moved on by `s` times the motion from `Ta` to `Tb` (constant body-frame twist)."""
    d = inv_T(Ta) @ Tb
    return Tb @ make_T(so3_exp(so3_log(d[:3, :3]) * s), d[:3, 3] * s)


def extrapolate_last(poses: list[tuple[int, F64]], t: int) -> F64 | None:
    """Pose at `t` extrapolated from the last two `(t_ns, T)` of `poses` (constant body-frame
    twist); the last alone when it is the only one; None when there is none."""
    if not poses:
        return None
    if len(poses) == 1 or poses[-1][0] <= poses[-2][0]:
        return poses[-1][1]
    (ta, Ta), (tb, Tb) = poses[-2:]
    return extrapolate(Ta, Tb, (t - tb) / (tb - ta))


def transform_points(T: F64, p: F64) -> F64:
    """Apply T (4x4) to points (N, 3)."""
    p = np.asarray(p, dtype=np.float64)
    return cast(F64, p @ T[:3, :3].T + T[:3, 3])


def skew(v: F64) -> F64:
    x, y, z = np.asarray(v, dtype=np.float64).reshape(3).tolist()  # Python floats: no per-
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])  # element numpy scalars


def so3_exp(w: F64) -> F64:
    """Rodrigues: rotation matrix from a rotation vector (3,)."""
    w = np.asarray(w, dtype=np.float64)
    flat = w.ravel()
    th = math.sqrt(float(flat.dot(flat)))  # np.linalg.norm's own arithmetic, without its wrapper
    if th < 1e-12:
        return np.eye(3) + skew(w)
    k = skew(w / th)
    return cast(F64, _I3 + np.sin(th) * k + (1 - np.cos(th)) * (k @ k))


def so3_log(r: F64) -> F64:
    """Rotation vector (3,) from a rotation matrix."""
    r = np.asarray(r, dtype=np.float64)
    c = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    th = float(np.arccos(c))
    if th < 1e-9:
        return np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2.0
    if np.pi - th < 1e-6:
        # near pi: axis from the largest diagonal element of (R + I) / 2
        b = (r + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(b)))
        axis = b[:, i] / np.sqrt(max(b[i, i], 1e-12))
        return cast(F64, axis / np.linalg.norm(axis) * th)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return cast(F64, v * th / (2.0 * np.sin(th)))


def rotation_angle(r: F64) -> float:
    """Rotation angle in radians of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))


def yaw_of(r: F64) -> float:
    """Yaw (rotation about world z) of a rotation matrix, ZYX convention."""
    return float(np.arctan2(r[1, 0], r[0, 0]))


def rot_z(yaw: float) -> F64:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_between(a: F64, b: F64) -> F64:
    """Smallest rotation R with R @ a/|a| = b/|b|."""
    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-12:
        # opposite: rotate pi about any axis orthogonal to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return so3_exp(axis / np.linalg.norm(axis) * np.pi)
    k = skew(v)
    return np.eye(3) + k + k @ k / (1.0 + c)


# ---- SE(3) tangent space: [rotation, translation] (GTSAM's Pose3 order) ----------------------
def se3_adjoint(T: F64) -> F64:
    """Adjoint (6, 6) of a rigid transform in [rotation, translation] order:
    `T @ exp(xi) = exp(Ad(T) @ xi) @ T`, so a covariance of a right (body-frame) perturbation
    becomes one of a left (world-frame) perturbation as `Ad @ cov @ Ad.T`."""
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, :3] = skew(t) @ R
    A[3:, 3:] = R
    return A


def se3_exp(xi: F64) -> F64:
    """The pose (4, 4) `exp(twist)` of a twist (6,) [rotation vector, translation part]: the
    inverse of `se3_log`."""
    w = np.asarray(xi[:3], dtype=np.float64)
    th = float(np.linalg.norm(w))
    W = skew(w)
    if th < 1e-9:
        V = np.eye(3) + 0.5 * W
    else:
        V = np.eye(3) + (1.0 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)
    return make_T(so3_exp(w), V @ np.asarray(xi[3:], dtype=np.float64))


def se3_log(T: F64) -> F64:
    """The twist (6,) [rotation vector, translation part] with `exp(twist) = T`."""
    w = so3_log(T[:3, :3])
    th = float(np.linalg.norm(w))
    W = skew(w)
    if th < 1e-9:
        V_inv = np.eye(3) - 0.5 * W
    else:
        half = th / 2.0
        V_inv = (
            np.eye(3) - 0.5 * W + (1.0 - half * np.cos(half) / np.sin(half)) / (th * th) * (W @ W)
        )
    return np.concatenate([w, V_inv @ T[:3, 3]])
