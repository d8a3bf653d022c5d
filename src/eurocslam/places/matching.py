"""Guided descriptor matching through the vocabulary (DBoW2's direct index, ORB-SLAM's
SearchByBoW): only descriptors under the same vocabulary node are compared.

    voc = default_vocabulary()
    na = voc.node_ids(voc.lookup(desc_a), level=2)
    nb = voc.node_ids(voc.lookup(desc_b), level=2)
    m = match_guided(desc_a, na, desc_b, nb)      # m.ia[i] <-> m.ib[i], Hamming m.dist[i]

A node at level 2 of the shipped tree (64 nodes) splits 1,000 x 1,000 comparisons into about
16,000 candidate pairs; the few true matches the node split separates are lost, as in DBoW2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

I32 = NDArray[np.int32]
I64 = NDArray[np.int64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class Matches:
    """Index pairs into the two descriptor sets and their Hamming distances."""

    ia: I64
    ib: I64
    dist: I32

    def __len__(self) -> int:
        return int(self.ia.size)


def _ranges(starts: I64, lens: I64) -> I64:
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offs = np.repeat(starts - np.cumsum(lens) + lens, lens)
    return np.asarray(offs + np.arange(total), dtype=np.int64)


def _hamming(a: U8, b: U8) -> I32:
    c = np.bitwise_count(np.ascontiguousarray(a).view(np.uint64) ^ b.view(np.uint64))
    return np.asarray(c.sum(axis=1, dtype=np.int32), dtype=np.int32)


def match_guided(
    desc_a: U8,
    nodes_a: I32,
    desc_b: U8,
    nodes_b: I32,
    *,
    max_hamming: int = 50,
    ratio: float = 0.75,
) -> Matches:
    """For each descriptor of `a`, the nearest descriptor of `b` under the same node, kept when
    its distance is <= `max_hamming` and < `ratio` x the second nearest's there (when there is
    one); each `b` descriptor goes to one `a` descriptor at most (the nearest). ORB-SLAM's
    thresholds: 50 and 0.75 for relocalization and loops."""
    da = np.ascontiguousarray(desc_a, np.uint8)
    db = np.ascontiguousarray(desc_b, np.uint8)
    empty = Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int32))
    if da.shape[0] == 0 or db.shape[0] == 0:
        return empty
    ob = np.argsort(nodes_b, kind="stable")
    sorted_b = np.asarray(nodes_b)[ob]
    lo = np.searchsorted(sorted_b, nodes_a, side="left")
    hi = np.searchsorted(sorted_b, nodes_a, side="right")
    cnt = (hi - lo).astype(np.int64)
    ia = np.repeat(np.arange(da.shape[0], dtype=np.int64), cnt)
    if ia.size == 0:
        return empty
    ib = ob[_ranges(lo.astype(np.int64), cnt)].astype(np.int64)
    d = _hamming(da[ia], db[ib])
    # best and second best per a-descriptor: sort by (a, distance, b)
    order = np.lexsort((ib, d, ia))
    ia, ib, d = ia[order], ib[order], d[order]
    first = np.ones(ia.size, bool)
    first[1:] = ia[1:] != ia[:-1]
    pos = np.flatnonzero(first)
    has_second = np.zeros(pos.size, bool)
    nxt = pos + 1
    in_range = nxt < ia.size
    has_second[in_range] = ia[nxt[in_range]] == ia[pos[in_range]]
    second = np.full(pos.size, np.iinfo(np.int32).max, np.int64)
    second[has_second] = d[nxt[has_second]]
    best_d = d[pos].astype(np.int64)
    keep = (best_d <= max_hamming) & (best_d < ratio * second)
    ma, mb, md = ia[pos[keep]], ib[pos[keep]], d[pos[keep]]
    # one a per b: the nearest (ties: the lower a index)
    o = np.lexsort((ma, md, mb))
    ma, mb, md = ma[o], mb[o], md[o]
    uniq = np.ones(mb.size, bool)
    uniq[1:] = mb[1:] != mb[:-1]
    ma, mb, md = ma[uniq], mb[uniq], md[uniq]
    o = np.argsort(ma, kind="stable")
    return Matches(ma[o], mb[o], md[o].astype(np.int32))
