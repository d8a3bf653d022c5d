"""Stereo matching along rows of rectified images.

For every left keypoint, candidates are the right keypoints on (nearly) the same row
(|vL - vR| <= tolerance x octave scale), at a disparity the rig allows (`disparity_window`), on a
neighbouring pyramid octave. A match needs a small descriptor distance, a ratio test against
the best *distinct* other candidate, left-right consistency (the right keypoint's best left
candidate is this one), and a successful sub-pixel refinement: zero-mean SSD block matching of a
mean-normalised patch along the row with a parabola fit, as in ORB-SLAM.
All of it is vectorised over candidate pairs (no Python loop per keypoint).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from eurocslam.camera import RectifiedStereo
from eurocslam.dataset.types import U8
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.features import Features, hamming_pairs
from eurocslam.frontend.projection import octave_sigma
from eurocslam.geometry import F64


@dataclass(frozen=True)
class StereoMatches:
    """Per left keypoint: right-image column uR (NaN when unmatched) and depth (NaN idem)."""

    uR: F64  # (N,)
    depth: F64  # (N,) metres along rect0 z
    right_index: NDArray[np.intp]  # (N,) matched right keypoint, -1 if none

    @property
    def valid(self) -> NDArray[np.bool_]:
        return np.isfinite(self.uR)


def disparity_window(config: FrontendConfig, geom: RectifiedStereo) -> tuple[float, float]:
    """The disparities (px) a stereo match may have on this rig: from `stereo_min_disparity_px`
    to that of a point `stereo_min_depth_baselines` baselines away (fx / that)."""
    return config.stereo_min_disparity_px, geom.fx / config.stereo_min_depth_baselines


def _first_per_group(group: NDArray[np.intp], key: NDArray[np.int32]) -> NDArray[np.intp]:
    """Indices (into the pair arrays) of the smallest `key` for each distinct `group`
    (non-negative). The order is `np.lexsort((key, group))`'s: one stable sort of group and key
    packed into one int64 (a Hamming distance takes 9 bits), at a fraction of lexsort's cost
    (1/4-1/6 where `group` is sorted already, as the left keypoints are)."""
    if group.size == 0:
        return np.zeros(0, np.intp)
    k0 = int(key.min())
    span = int(key.max()) - k0 + 1
    if (int(group.max()) + 1) * span < 1 << 62:
        packed = group.astype(np.int64) * span + (key.astype(np.int64) - k0)
        order = np.argsort(packed, kind="stable")
    else:
        order = np.lexsort((key, group))
    g = group[order]
    first = np.ones(g.size, dtype=bool)
    first[1:] = g[1:] != g[:-1]
    return order[first]


def _group_min(n: int, group: NDArray[np.intp], value: NDArray[np.int32]) -> NDArray[np.int64]:
    """Per index 0..n-1 the smallest `value` of its `group` entries (1 << 20 where none):
    `np.minimum.at` on a `1 << 20` array, by one `reduceat` where `group` is sorted (the left
    keypoints of the candidate pairs are)."""
    out = np.full(n, 1 << 20, dtype=np.int64)
    if group.size == 0 or np.any(group[1:] < group[:-1]):
        np.minimum.at(out, group, value)
        return out
    starts = np.flatnonzero(np.concatenate([[True], group[1:] != group[:-1]]))
    mins = np.minimum.reduceat(value, starts)
    out[group[starts]] = np.minimum(out[group[starts]], mins)
    return out


def candidate_pairs(
    left: Features, right: Features, scale: F64, config: FrontendConfig, geom: RectifiedStereo
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(left index, right index) of every geometrically admissible stereo pair."""
    nl, nr = len(left), len(right)
    if nl == 0 or nr == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    vR = right.uv[:, 1]
    order = np.argsort(vR, kind="stable")
    vRs = vR[order]
    tol = config.stereo_row_tolerance_px * octave_sigma(scale, left.octave)
    vL = left.uv[:, 1]
    lo = np.searchsorted(vRs, vL - tol, side="left")
    hi = np.searchsorted(vRs, vL + tol, side="right")
    counts = hi - lo
    total = int(counts.sum())
    li = np.repeat(np.arange(nl), counts)
    starts = np.repeat(lo - (np.cumsum(counts) - counts), counts)
    rj = order[starts + np.arange(total)]
    d = left.uv[li, 0] - right.uv[rj, 0]
    d_min, d_max = disparity_window(config, geom)
    keep = (d >= d_min) & (d <= d_max) & (np.abs(left.octave[li] - right.octave[rj]) <= 1)
    return li[keep], rj[keep]


def _refine_subpixel(
    img_l: U8, img_r: U8, uL: F64, vL: F64, uR: F64, half: int, search: int
) -> tuple[F64, F64]:
    """Sub-pixel right columns by zero-mean SSD along the row: (uR refined or NaN, best cost)."""
    h, w = img_l.shape
    m = uL.size
    out = np.full(m, np.nan)
    cost_best = np.full(m, np.inf)
    if m == 0:
        return out, cost_best
    ul0 = np.rint(uL).astype(np.int64)
    ur0 = np.rint(uR).astype(np.int64)
    v0 = np.rint(vL).astype(np.int64)
    ok = (
        (v0 - half >= 0)
        & (v0 + half < h)
        & (ul0 - half >= 0)
        & (ul0 + half < w)
        & (ur0 - half - search - 1 >= 0)
        & (ur0 + half + search + 1 < w)
    )
    idx = np.nonzero(ok)[0]
    if idx.size == 0:
        return out, cost_best
    s = search + 1
    n_off = 2 * s + 1
    p = 2 * half + 1
    top = v0[idx] - half
    # left patches (M, P, P), mean-normalised; gathered from a window view of the image
    pl = sliding_window_view(img_l, (p, p))[top, ul0[idx] - half].astype(np.float32)
    pl -= pl.mean(axis=(1, 2), keepdims=True)
    # right strip (M, P, P + 2 * (search + 1)) covering every shifted window
    strip = sliding_window_view(img_r, (p, p + 2 * s))[top, ur0[idx] - half - s]
    strip = strip.astype(np.float32)
    # zero-mean SSD of the left patch against every window of the strip, without building the
    # windows: |pl|^2 - 2 <pl, w> + (sum w^2 - (sum w)^2 / P^2); <pl, w> one patch column at a time
    cross = np.zeros((idx.size, n_off), np.float32)  # <pl, window at offset o>
    for q in range(p):
        cross += np.einsum("mp,mpo->mo", pl[:, :, q], strip[:, :, q : q + n_off])
    col = strip.sum(axis=1)  # (M, P + 2s)
    col2 = (strip * strip).sum(axis=1)
    csum = np.concatenate([np.zeros((col.shape[0], 1), np.float32), np.cumsum(col, axis=1)], 1)
    csum2 = np.concatenate([np.zeros((col.shape[0], 1), np.float32), np.cumsum(col2, axis=1)], 1)
    sw = csum[:, p:] - csum[:, :-p]  # (M, n_off)
    sw2 = csum2[:, p:] - csum2[:, :-p]
    cost = (pl * pl).sum(axis=(1, 2))[:, None] - 2.0 * cross + (sw2 - sw * sw / (p * p))
    cost = np.maximum(cost, 0.0)
    # only offsets -search..search are candidates (the outer ones feed the parabola)
    inner = cost[:, 1:-1]
    best = np.argmin(inner, axis=1) + 1
    at_edge = (best == 1) | (best == n_off - 2)
    r = np.arange(idx.size)
    s0 = cost[r, best]
    sm = cost[r, best - 1]
    sp = cost[r, best + 1]
    denom = 2.0 * (sm + sp - 2.0 * s0)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(denom > 0, (sm - sp) / denom, 0.0)
    good = ~at_edge & (np.abs(delta) <= 1.0)
    shift = best - s + delta  # offset of the right window centre from ur0
    # disparity measured between patch centres: ul0 - (ur0 + shift); keep it for the unrounded uL
    disp = ul0[idx] - (ur0[idx] + shift)
    refined = uL[idx] - disp
    out[idx[good]] = refined[good]
    cost_best[idx[good]] = s0[good]
    return out, cost_best


def match_stereo(
    left: Features,
    right: Features,
    img_l: U8,
    img_r: U8,
    scale: F64,
    config: FrontendConfig,
    geom: RectifiedStereo,
) -> StereoMatches:
    """Stereo-match left keypoints against right keypoints of a rectified pair."""
    nl = len(left)
    uR_out = np.full(nl, np.nan)
    depth = np.full(nl, np.nan)
    rindex = np.full(nl, -1, dtype=np.intp)
    li, rj = candidate_pairs(left, right, scale, config, geom)
    if li.size == 0:
        return StereoMatches(uR_out, depth, rindex)
    dist = hamming_pairs(left.desc, li, right.desc, rj)
    # best candidate per left keypoint
    best_pair = _first_per_group(li, dist)
    best_l = li[best_pair]
    best_r_of_l = np.full(nl, -1, dtype=np.intp)
    best_d_of_l = np.full(nl, 1 << 20, dtype=np.int64)
    best_r_of_l[best_l] = rj[best_pair]
    best_d_of_l[best_l] = dist[best_pair]
    # second best among *distinct* candidates (> 2 px away from the best on the row)
    distinct = np.abs(right.uv[rj, 0] - right.uv[best_r_of_l[li], 0]) > 2.0
    second = _group_min(nl, li[distinct], dist[distinct])
    # best left candidate per right keypoint (left-right consistency)
    best_pair_r = _first_per_group(rj, dist)
    best_l_of_r = np.full(len(right), -1, dtype=np.intp)
    best_l_of_r[rj[best_pair_r]] = li[best_pair_r]

    cand = best_l
    r_c = best_r_of_l[cand]
    d_c = best_d_of_l[cand]
    ok = d_c <= config.stereo_max_hamming
    ok &= d_c < config.stereo_ratio * second[cand]
    ok &= best_l_of_r[r_c] == cand
    cand, r_c = cand[ok], r_c[ok]
    if cand.size == 0:
        return StereoMatches(uR_out, depth, rindex)
    uR_ref, cost = _refine_subpixel(
        img_l,
        img_r,
        left.uv[cand, 0],
        left.uv[cand, 1],
        right.uv[r_c, 0],
        config.subpixel_half_window,
        config.subpixel_search_px,
    )
    good = np.isfinite(uR_ref)
    if good.any():
        # photometric outliers: cost far above the typical one (ORB-SLAM: SAD > 1.5 x 1.4 x
        # median; squared here because the cost is a sum of squares)
        thr = (1.5 * 1.4) ** 2 * float(np.median(cost[good]))
        # floor: a 2-grey-level RMS difference per pixel is never an outlier (clean images
        # otherwise give a median near 0 and reject everything)
        floor = 4.0 * (2 * config.subpixel_half_window + 1) ** 2
        good &= cost <= max(thr, floor)
    d = left.uv[cand, 0] - uR_ref
    d_min, d_max = disparity_window(config, geom)
    with np.errstate(invalid="ignore"):
        good &= (d >= d_min) & (d <= d_max)
    cand, r_c, uR_ref, d = cand[good], r_c[good], uR_ref[good], d[good]
    uR_out[cand] = uR_ref
    depth[cand] = geom.fx * geom.baseline / d
    rindex[cand] = r_c
    return StereoMatches(uR_out, depth, rindex)
