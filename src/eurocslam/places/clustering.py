"""Hierarchical k-majority clustering of binary descriptors: the vocabulary tree's training.

DBoW2's recipe in Hamming space: at each node, k-means++ seeding (the next centre drawn with
probability proportional to the squared distance to the nearest chosen one), then k-majority
iterations (assign every descriptor to its nearest centre; a centre becomes the bitwise majority
of its descriptors) until the assignment no longer changes; the same again inside every cluster
down to `levels` levels. A node with at most k distinct descriptors gets one leaf per
descriptor. Deterministic for a given seed; nodes come out in breadth-first order, the layout
`Vocabulary` stores.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

logger = logging.getLogger(__name__)

U8 = NDArray[np.uint8]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]
_CHUNK = 1 << 14  # descriptors per block when computing distances / majorities


def hamming_to(desc64: NDArray[np.uint64], centres64: NDArray[np.uint64]) -> NDArray[np.int32]:
    """Hamming distances (n, m) between descriptors (n, 4) and centres (m, 4) as uint64 words."""
    out = np.empty((desc64.shape[0], centres64.shape[0]), np.int32)
    for s in range(0, desc64.shape[0], _CHUNK):
        c = np.bitwise_count(desc64[s : s + _CHUNK, None, :] ^ centres64[None, :, :])
        o = out[s : s + _CHUNK]
        np.add(c[:, :, 0], c[:, :, 1], out=o, dtype=np.int32)
        o += c[:, :, 2]
        o += c[:, :, 3]
    return out


def majority(desc: U8, labels: I64, k: int) -> tuple[U8, I64]:
    """Bitwise majority of the descriptors of each label 0..k-1 (a bit is set when more than
    half of the cluster has it, as DBoW2) and the cluster sizes. Bits are summed per cluster
    with integer numpy (a float matrix product was as fast on an idle machine but several times
    slower when BLAS threads competed with other work)."""
    sizes = np.bincount(labels, minlength=k).astype(np.int64)
    sums = np.zeros((k, desc.shape[1] * 8), np.int64)
    order = np.argsort(labels, kind="stable")
    s = desc[order]
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    for c in np.flatnonzero(sizes).tolist():
        for a in range(int(bounds[c]), int(bounds[c + 1]), _CHUNK):
            b = min(a + _CHUNK, int(bounds[c + 1]))
            sums[c] += np.unpackbits(s[a:b], axis=1).sum(axis=0, dtype=np.int64)
    centres = np.packbits(2 * sums > sizes[:, None], axis=1)
    return centres.astype(np.uint8), sizes


def kmeanspp(desc64: NDArray[np.uint64], k: int, rng: np.random.Generator) -> I64:
    """Indices of k seeds (fewer when there are fewer distinct descriptors) by k-means++."""
    n = desc64.shape[0]
    chosen = [int(rng.integers(n))]
    dmin = hamming_to(desc64, desc64[chosen[-1]][None, :])[:, 0].astype(np.float64)
    while len(chosen) < k:
        w = dmin * dmin
        total = float(w.sum())
        if total <= 0.0:
            break  # every descriptor equals a chosen seed
        nxt = int(np.searchsorted(np.cumsum(w), rng.random() * total, side="right"))
        nxt = min(nxt, n - 1)
        chosen.append(nxt)
        np.minimum(dmin, hamming_to(desc64, desc64[nxt][None, :])[:, 0], out=dmin)
    return np.asarray(chosen, np.int64)


def kmajority(desc: U8, k: int, rng: np.random.Generator, max_iter: int) -> tuple[U8, I64]:
    """Cluster descriptors (n > k) into at most k groups: centres (m, 32) and labels (n,)."""
    d64 = desc.view(np.uint64)
    centres = desc[kmeanspp(d64, k, rng)]
    labels = np.full(desc.shape[0], -1, np.int64)
    for _ in range(max_iter):
        new = hamming_to(d64, centres.view(np.uint64)).argmin(axis=1).astype(np.int64)
        if np.array_equal(new, labels):
            break
        labels = new
        centres, sizes = majority(desc, labels, centres.shape[0])
        if not sizes.all():  # an empty cluster: drop it and relabel
            keep = np.flatnonzero(sizes)
            centres = centres[keep]
            remap = np.full(sizes.size, -1, np.int64)
            remap[keep] = np.arange(keep.size)
            labels = remap[labels]
    return centres, labels


@dataclass(frozen=True)
class Tree:
    """A vocabulary tree in breadth-first order: node centres (row 0, the root, is zeros) and
    each node's number of children (0: a leaf, i.e. a word)."""

    node_desc: U8
    n_children: I32


def build_tree(desc: U8, k: int, levels: int, seed: int = 0, max_iter: int = 30) -> Tree:
    """Hierarchical k-majority clustering of training descriptors (n, 32) uint8."""
    rng = np.random.default_rng([seed, 0xB0])
    desc = np.ascontiguousarray(desc, dtype=np.uint8)
    node_desc: list[U8] = [np.zeros((1, desc.shape[1]), np.uint8)]
    n_children: list[int] = []
    # breadth-first: children are numbered in the order their parents are processed
    queue: deque[tuple[I64, int]] = deque([(np.arange(desc.shape[0], dtype=np.int64), 0)])
    done = 0
    while queue:
        idx, depth = queue.popleft()
        done += 1
        if depth >= levels or idx.size <= 1:
            n_children.append(0)
            continue
        sub = desc[idx]
        uniq = np.unique(sub, axis=0)
        if uniq.shape[0] <= k:
            # one leaf per distinct descriptor
            n_children.append(uniq.shape[0])
            node_desc.append(uniq)
            for _ in range(uniq.shape[0]):
                queue.append((np.zeros(0, np.int64), levels))
            continue
        centres, labels = kmajority(sub, k, rng, max_iter)
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(centres.shape[0] + 1))
        n_children.append(centres.shape[0])
        node_desc.append(centres)
        for c in range(centres.shape[0]):
            queue.append((idx[order[bounds[c] : bounds[c + 1]]], depth + 1))
        if depth == 0:
            logger.info("vocabulary: root split into %d clusters", centres.shape[0])
    return Tree(np.vstack(node_desc), np.asarray(n_children, np.int32))
