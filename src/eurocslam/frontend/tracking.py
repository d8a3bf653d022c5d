"""Temporal tracking: the local map, projection search, pose-only optimisation, PnP recovery.

Poses inside this module are `T_rect0_world` (world -> rectified left camera), the form the
projection needs; `StereoTracker` converts to and from `T_world_body`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from eurocslam.camera import RectifiedStereo
from eurocslam.frontend.features import Features, hamming
from eurocslam.geometry import F64, inv_T, make_T, so3_exp

I64 = NDArray[np.int64]
_I3 = np.eye(3)


_FIELDS = ("ids", "xyz", "desc", "octave", "n_visible", "n_found", "last_seen", "kf_uv")
_ARCHIVED = ("ids", "xyz", "desc", "octave", "n_visible", "n_found")


class LandmarkArchive:
    """Landmarks culled for going unseen, kept so they can be re-found (map reuse).

    Rows are appended to arrays grown by doubling and marked dead when revived or dropped, so
    retiring and reviving cost what they move, not the archive's size. Read `live` with the
    arrays up to `n`. Over `capacity` live rows, the least found are dropped (down to 90 %)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self.n = 0  # rows used, live or dead
        self.n_live = 0
        self.ids: I64 = np.zeros(0, np.int64)
        self.xyz: F64 = np.zeros((0, 3))
        self.desc: NDArray[np.uint8] = np.zeros((0, 32), np.uint8)
        self.octave: NDArray[np.int32] = np.zeros(0, np.int32)
        self.n_visible: I64 = np.zeros(0, np.int64)
        self.n_found: I64 = np.zeros(0, np.int64)
        self.live: NDArray[np.bool_] = np.zeros(0, bool)

    def __len__(self) -> int:
        return self.n_live

    def add(self, rows: dict[str, np.ndarray]) -> None:
        k = int(rows["ids"].size)
        if k == 0:
            return
        if self.n + k > self.live.size:
            if self.n_live < self.n // 2:  # mostly dead rows: compact instead of growing
                self._keep(np.nonzero(self.live[: self.n])[0])
            if self.n + k > self.live.size:
                size = max(1024, 2 * (self.n + k))
                for name in (*_ARCHIVED, "live"):
                    a = getattr(self, name)
                    grown = np.zeros((size, *a.shape[1:]), a.dtype)
                    grown[: self.n] = a[: self.n]
                    setattr(self, name, grown)
        sl = slice(self.n, self.n + k)
        for name in _ARCHIVED:
            getattr(self, name)[sl] = rows[name]
        self.live[sl] = True
        self.n += k
        self.n_live += k
        if self.n_live > self.capacity:
            live = np.nonzero(self.live[: self.n])[0]
            order = np.argsort(-self.n_found[live], kind="stable")
            self.live[live[order[int(0.9 * self.capacity) :]]] = False
            self.n_live = int(self.live[: self.n].sum())

    def take(self, rows: NDArray[np.intp]) -> dict[str, np.ndarray]:
        """Rows (live, distinct) out of the archive."""
        out = {name: getattr(self, name)[rows] for name in _ARCHIVED}
        self.live[rows] = False
        self.n_live -= int(rows.size)
        return out

    def clear(self) -> None:
        self.live[: self.n] = False
        self.n = self.n_live = 0

    def _keep(self, rows: NDArray[np.intp]) -> None:
        for name in (*_ARCHIVED, "live"):
            a = getattr(self, name)
            a[: rows.size] = a[rows]
        self.n = self.n_live = int(rows.size)


class LocalMap:
    """Landmarks with persistent int64 ids, kept sorted by id.

    `archive` holds the reliable landmarks culled because they went unseen (`retire`);
    `revive` moves re-found ones back under their old ids."""

    def __init__(self, first_id: int = 0, archive_capacity: int = 0) -> None:
        self.next_id = int(first_id)
        self.ids: I64 = np.zeros(0, np.int64)
        self.xyz: F64 = np.zeros((0, 3))  # world frame
        self.desc: NDArray[np.uint8] = np.zeros((0, 32), np.uint8)
        self.octave: NDArray[np.int32] = np.zeros(0, np.int32)
        self.n_visible: I64 = np.zeros(0, np.int64)  # predicted inside the image
        self.n_found: I64 = np.zeros(0, np.int64)  # matched as a pose inlier
        self.last_seen: I64 = np.zeros(0, np.int64)  # t_ns of the last inlier match
        self.kf_uv: F64 = np.zeros((0, 2))  # pixel position at the last keyframe (NaN: unseen)
        self.archive = LandmarkArchive(archive_capacity)

    def __len__(self) -> int:
        return int(self.ids.size)

    def add(
        self, xyz: F64, desc: NDArray[np.uint8], octave: NDArray[np.int32], uv: F64, t_ns: int
    ) -> I64:
        n = xyz.shape[0]
        ids = np.arange(self.next_id, self.next_id + n, dtype=np.int64)
        self.next_id += n
        self._append(
            {
                "ids": ids,
                "xyz": xyz,
                "desc": desc,
                "octave": octave.astype(np.int32),
                "n_visible": np.ones(n, np.int64),
                "n_found": np.ones(n, np.int64),
                "last_seen": np.full(n, t_ns, np.int64),
                "kf_uv": uv,
            }
        )
        return ids

    def keep(self, mask: NDArray[np.bool_] | NDArray[np.intp]) -> None:
        """Keep the rows `mask` selects (a boolean mask or row indices, in their order)."""
        for name in _FIELDS:
            setattr(self, name, getattr(self, name)[mask])

    def clear(self) -> None:
        self.keep(np.zeros(len(self), dtype=bool))
        self.archive.clear()

    def retire(self, mask: NDArray[np.bool_]) -> None:
        """Move rows `mask` out of the map into the archive."""
        if not mask.any():
            return
        self.archive.add({name: getattr(self, name)[mask] for name in _ARCHIVED})
        self.keep(~mask)

    def revive(
        self,
        rows: NDArray[np.intp],
        xyz: F64,
        desc: NDArray[np.uint8],
        octave: NDArray[np.int32],
        uv: F64,
        t_ns: int,
    ) -> I64:
        """Move archive rows back into the map under their ids, as seen now: position,
        descriptor, octave and pixel of the sighting that re-found them."""
        back = self.archive.take(rows)
        n = int(rows.size)
        back.update(
            xyz=xyz,
            desc=desc,
            octave=octave.astype(np.int32),
            kf_uv=uv,
            last_seen=np.full(n, t_ns, np.int64),
            n_visible=back["n_visible"] + 1,
            n_found=back["n_found"] + 1,
        )
        self._append(back)
        return back["ids"]

    def _append(self, rows: dict[str, np.ndarray]) -> None:
        if rows["ids"].size == 0:
            return
        tail_sorted = not len(self) or rows["ids"].min() > self.ids[-1]
        for name in _FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), rows[name]]))
        if not (tail_sorted and np.all(np.diff(rows["ids"]) > 0)):
            self.keep(np.argsort(self.ids, kind="stable"))

    def index_of(self, ids: I64) -> NDArray[np.intp]:
        """Row of each id, -1 when the id is not (or no longer) in the map."""
        ids = np.asarray(ids, dtype=np.int64)
        pos = np.searchsorted(self.ids, ids)
        pos = np.clip(pos, 0, max(len(self) - 1, 0))
        found = (len(self) > 0) & (self.ids[pos] == ids) if len(self) else np.zeros(ids.shape, bool)
        return np.where(found, pos, -1)


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
        and np.linalg.det(R) > 0
    ):
        return T.copy()  # already rigid to round-off: skip the SVD (hot path)
    u, _, vt = np.linalg.svd(R)
    R = u @ vt
    if np.linalg.det(R) < 0:
        R = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    return make_T(R, T[:3, 3])


def rect_T_from_body(T_world_body: F64, T_body_rect0: F64) -> F64:
    """T_rect0_world from T_world_body."""
    return rigid(inv_T(rigid(T_world_body) @ T_body_rect0))


def body_T_from_rect(T_rect0_world: F64, T_body_rect0: F64) -> F64:
    """T_world_body from T_rect0_world."""
    return rigid(inv_T(rigid(T_rect0_world)) @ inv_T(T_body_rect0))


@dataclass(frozen=True)
class Projection:
    uv: F64  # (N, 2) predicted left pixels
    uR: F64  # (N,) predicted right column
    in_view: NDArray[np.bool_]  # in front of the camera and inside the image


def project_map(
    T_rect0_world: F64, xyz: F64, geom: RectifiedStereo, margin: float = 2.0
) -> Projection:
    pc = xyz @ T_rect0_world[:3, :3].T + T_rect0_world[:3, 3]
    z = pc[:, 2]
    front = z > 0.1
    zs = np.where(front, z, 1.0)
    u = geom.fx * pc[:, 0] / zs + geom.cx
    v = geom.fy * pc[:, 1] / zs + geom.cy
    uR = u - geom.fx * geom.baseline / zs
    in_view = (
        front
        & (u >= margin)
        & (u < geom.width - margin)
        & (v >= margin)
        & (v < geom.height - margin)
    )
    return Projection(np.column_stack([u, v]), uR, in_view)


def search_by_projection(
    proj: Projection,
    lm_rows: NDArray[np.intp],
    lm_desc: NDArray[np.uint8],
    lm_octave: NDArray[np.int32],
    feats: Features,
    feat_uR: F64,
    tree: cKDTree,
    scale: F64,
    radius_px: float,
    max_hamming: int,
    ratio: float,
    taken: NDArray[np.bool_] | None = None,
    k: int = 6,
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.int32]]:
    """Match projected landmarks (rows `lm_rows` of the projection) to keypoints nearby.

    Returns (landmark rows, keypoint indices, distances); each keypoint used at most once.
    """
    empty = (np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.int32))
    if lm_rows.size == 0 or len(feats) == 0:
        return empty
    k = min(k, len(feats))
    radius = radius_px * scale[np.clip(lm_octave[lm_rows], 0, scale.size - 1)]
    d_px, nn = tree.query(proj.uv[lm_rows], k=k, distance_upper_bound=float(radius.max()))
    d_px = np.asarray(d_px).reshape(lm_rows.size, k)
    nn = np.asarray(nn).reshape(lm_rows.size, k)
    valid = np.isfinite(d_px) & (nn < len(feats))
    nn = np.where(valid, nn, 0)
    valid &= d_px <= radius[:, None]
    valid &= np.abs(feats.octave[nn] - lm_octave[lm_rows][:, None]) <= 2
    # stereo consistency when both sides know a right column
    kp_uR = feat_uR[nn]
    pred_uR = proj.uR[lm_rows][:, None]
    with np.errstate(invalid="ignore"):
        valid &= ~(np.abs(kp_uR - pred_uR) > radius[:, None])
    if taken is not None:
        valid &= ~taken[nn]
    dist = np.full(valid.shape, 1 << 20, dtype=np.int32)
    vi, vj = np.nonzero(valid)
    dist[vi, vj] = hamming(lm_desc[lm_rows[vi]], feats.desc[nn[vi, vj]])
    order = np.argsort(dist, axis=1)
    r = np.arange(lm_rows.size)
    b = order[:, 0]
    best = dist[r, b]
    best_kp = nn[r, b]
    if k > 1:
        second = dist[r, order[:, 1]]
        # a second candidate at the same keypoint position (another octave) is not a rival
        second_kp = nn[r, order[:, 1]]
        same_spot = np.linalg.norm(feats.uv[second_kp] - feats.uv[best_kp], axis=1) < 2.0
        second = np.where(same_spot, 1 << 20, second)
    else:
        second = np.full(lm_rows.size, 1 << 20)
    ok = (best <= max_hamming) & (best < ratio * second)
    rows, kps, dists = lm_rows[ok], best_kp[ok], best[ok]
    if rows.size == 0:
        return empty
    # one landmark per keypoint: keep the smallest distance
    order2 = np.lexsort((dists, kps))
    kp_s = kps[order2]
    first = np.ones(kp_s.size, dtype=bool)
    first[1:] = kp_s[1:] != kp_s[:-1]
    sel = order2[first]
    return rows[sel], kps[sel], dists[sel]


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
        front = Z > 0.05
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
    for rnd in range(rounds):
        robust = rnd < rounds - 1
        if robust and previous is not None and np.array_equal(previous, inlier):
            continue  # the last round's inliers again: its converged pose stands
        previous = inlier
        for _ in range(iterations):
            X, Y, Z, iz, front, ru, rr, rv, e2 = residuals(T)
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
                dx = -np.linalg.solve(H + 1e-9 * np.eye(6), g)
            except np.linalg.LinAlgError:
                break
            dR = so3_exp(dx[3:])
            T = make_T(dR @ T[:3, :3], dR @ T[:3, 3] + dx[:3])
            if np.linalg.norm(dx) < 1e-5:  # 10 um / 10 urad
                break
        *_, front, _, _, _, chi2 = residuals(T)
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
    if n < 6:
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
    if not ok or idx is None or len(idx) < 6:
        return None, inl
    inl[idx.reshape(-1)] = True
    R, _ = cv2.Rodrigues(rvec)
    return make_T(np.asarray(R, np.float64), np.asarray(tvec, np.float64).reshape(3)), inl
