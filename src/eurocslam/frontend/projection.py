"""Projection: the local map seen from a pose, and the search for its landmarks among a
frame's keypoints near where they project; the ORB pyramid's scales and a keypoint's pixel
sigma by its octave (one rule for tracking and place recognition).

Poses here are `T_rect0_world` (world -> rectified left camera), the form the projection
needs; `rect_T_from_body` / `body_T_from_rect` convert from and to `T_world_body`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.typing import NDArray

from eurocslam.camera import RectifiedStereo
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.features import Features, hamming_pairs
from eurocslam.geometry import F64, inv_T, rigid

if TYPE_CHECKING:  # the caller builds the tree: the extraction workers need no scipy
    from scipy.spatial import cKDTree

IN_FRONT_M = 0.1  # a point this close to the camera plane or behind it does not project
MAX_OCTAVE_GAP = 2  # pyramid levels between a landmark's octave and a keypoint matched to it
SAME_SPOT_PX = 2.0  # a second candidate this close to the best is the same corner (another level)
CANDIDATES = 6  # the nearest keypoints a landmark's projection considers
_NO_MATCH = 1 << 20  # a descriptor distance no candidate has


def pyramid_scales(config: FrontendConfig) -> F64:
    """The scale of each ORB pyramid level (1 at full resolution)."""
    return np.asarray(config.orb_scale_factor ** np.arange(config.orb_levels), dtype=np.float64)


def octave_sigma(scales: F64, octave: NDArray[np.integer]) -> F64:
    """The pixel sigma of keypoints by their pyramid `octave` (its scale; octaves beyond the
    pyramid take its ends)."""
    return cast(F64, scales[np.clip(octave, 0, scales.size - 1)])


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
    """The map's points `xyz` (world) seen from `T_rect0_world`: rectified stereo pixels, and
    which are in front (`IN_FRONT_M`) and inside the image, `margin` pixels from its edges."""
    pc = xyz @ T_rect0_world[:3, :3].T + T_rect0_world[:3, 3]
    z = pc[:, 2]
    front = z > IN_FRONT_M
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


@dataclass(frozen=True)
class MatchRule:
    """Which keypoint a projected landmark takes: one within `radius_px` (times the landmark's
    octave scale) of its projection, at most `max_hamming` descriptor bits away and closer than
    `ratio` times the second best."""

    radius_px: float
    max_hamming: int
    ratio: float


def search_by_projection(
    proj: Projection,
    lm_rows: NDArray[np.intp],
    lm_desc: NDArray[np.uint8],
    lm_octave: NDArray[np.int32],
    feats: Features,
    feat_uR: F64,
    tree: cKDTree,
    scale: F64,
    rule: MatchRule,
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.int32]]:
    """Match projected landmarks (rows `lm_rows` of the projection) to keypoints nearby (`tree`
    over `feats.uv`; `feat_uR` their right columns, NaN: none) by `rule`.

    Returns (landmark rows, keypoint indices, distances); each keypoint used at most once.
    """
    empty = (np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.int32))
    if lm_rows.size == 0 or len(feats) == 0:
        return empty
    k = min(CANDIDATES, len(feats))
    radius = rule.radius_px * octave_sigma(scale, lm_octave[lm_rows])
    d_px, nn = tree.query(proj.uv[lm_rows], k=k, distance_upper_bound=float(radius.max()))
    d_px = np.asarray(d_px).reshape(lm_rows.size, k)
    nn = np.asarray(nn).reshape(lm_rows.size, k)
    valid = np.isfinite(d_px) & (nn < len(feats))
    nn = np.where(valid, nn, 0)
    valid &= d_px <= radius[:, None]
    valid &= np.abs(feats.octave[nn] - lm_octave[lm_rows][:, None]) <= MAX_OCTAVE_GAP
    # stereo consistency when both sides know a right column
    kp_uR = feat_uR[nn]
    pred_uR = proj.uR[lm_rows][:, None]
    with np.errstate(invalid="ignore"):
        valid &= ~(np.abs(kp_uR - pred_uR) > radius[:, None])
    dist = np.full(valid.shape, _NO_MATCH, dtype=np.int32)
    vi, vj = np.nonzero(valid)
    dist[vi, vj] = hamming_pairs(lm_desc, lm_rows[vi], feats.desc, nn[vi, vj])
    order = np.argsort(dist, axis=1)
    r = np.arange(lm_rows.size)
    b = order[:, 0]
    best = dist[r, b]
    best_kp = nn[r, b]
    if k > 1:
        second = dist[r, order[:, 1]]
        # a second candidate at the same keypoint position (another octave) is not a rival
        second_kp = nn[r, order[:, 1]]
        same_spot = np.linalg.norm(feats.uv[second_kp] - feats.uv[best_kp], axis=1) < SAME_SPOT_PX
        second = np.where(same_spot, _NO_MATCH, second)
    else:
        second = np.full(lm_rows.size, _NO_MATCH)
    ok = (best <= rule.max_hamming) & (best < rule.ratio * second)
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
