"""A keyframe database searched by appearance: an inverted index from words to keyframes.

`add(key, bow)` files a keyframe's `BowVector` under each of its words; `query(bow, n)` scores
every keyframe that shares a word with the query by DBoW2's L1 score (the sum over the shared
words of the smaller weight, which is 1 - |a - b|_1 / 2 for L1-normalised vectors) and returns
the best `n` as `Candidate(key, score)`, best first. Only the posting lists of the query's words
are read, so a query costs what they hold, not the database size.

The database only *proposes* places: a candidate is not a loop or a relocalization until it is
verified geometrically (descriptor matches, PnP-RANSAC with the stereo depths) and, for a loop,
consistent over several keyframes. Two different places with the same repetitive texture score
high in any appearance index; only the geometry can tell them apart.

Layout: the posting lists are one array sorted by word (CSR: `indptr` per word) plus a short
tail of recent additions, merged in when it grows past a fraction of the sorted part (a linear
merge of two sorted runs), so adding is O(words of the keyframe) and a query is a handful of
vectorised numpy calls. Keys are opaque ints chosen by the caller (e.g. a segment and a keyframe
index packed into one int). Not thread-safe: one thread adds and queries.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Iterator
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from eurocslam.places.vocabulary import BowVector

I32 = NDArray[np.int32]
I64 = NDArray[np.int64]
F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
_KEY_OVERHEAD_BYTES = 3 * 28 + 2 * 8  # a key's int objects and its dict/list slots (estimate)
_BOW_OVERHEAD_BYTES = 3 * 112  # a stored BowVector and its two array headers (estimate)


class Candidate(NamedTuple):
    """A keyframe proposed by `KeyframeDatabase.query`: its key and L1 score in [0, 1]."""

    key: int
    score: float


def _ranges(starts: I64, lens: I64) -> I64:
    """Concatenated aranges [starts[i], starts[i] + lens[i])."""
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offs = np.repeat(starts - np.cumsum(lens) + lens, lens)
    return np.asarray(offs + np.arange(total), dtype=np.int64)


class KeyframeDatabase:
    """Inverted index over keyframes' bag-of-words vectors (see the module docstring)."""

    TAIL_MIN_ENTRIES = 16384  # merge the tail once it holds more than this ...
    TAIL_FRACTION = 0.125  # ... and more than this share of the sorted part

    def __init__(self) -> None:
        self._slot_of: dict[int, int] = {}  # key -> slot (insertion order)
        self._keys: list[int] = []  # slot -> key
        self._bows: list[BowVector | None] = []  # slot -> vector (None: removed)
        self._alive = np.zeros(0, bool)
        # sorted part: entries ordered by (word, slot); indptr[w]..indptr[w + 1] are word w's
        self._indptr: I64 = np.zeros(1, np.int64)
        self._slot: I32 = np.zeros(0, np.int32)
        self._weight: F32 = np.zeros(0, np.float32)
        # tail: recent additions, unsorted (word, slot, weight) per keyframe
        self._tail: list[tuple[I32, I32, F32]] = []
        self._tail_entries = 0
        self._tail_cat: tuple[I32, I32, F32] | None = None
        self.last_query_ms = 0.0
        self.total_query_ms = 0.0
        self.n_queries = 0

    # ---- contents -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._slot_of)

    def __contains__(self, key: object) -> bool:
        return key in self._slot_of

    def __iter__(self) -> Iterator[int]:
        return iter(self.keys())

    def keys(self) -> list[int]:
        """The keys in the database, in the order they were added."""
        return [k for k, b in zip(self._keys, self._bows, strict=True) if b is not None]

    def bow(self, key: int) -> BowVector:
        """The vector a key was added with (KeyError if absent)."""
        b = self._bows[self._slot_of[key]]
        if b is None:  # pragma: no cover - removed keys leave _slot_of
            raise KeyError(key)
        return b

    def add(self, key: int, bow: BowVector) -> None:
        """File a keyframe under each of its words. A key can be added once (ValueError)."""
        key = int(key)
        if key in self._slot_of:
            raise ValueError(f"keyframe key {key} is already in the database")
        slot = len(self._keys)
        self._slot_of[key] = slot
        self._keys.append(key)
        self._bows.append(bow)
        if slot >= self._alive.size:
            grown = np.zeros(max(256, 2 * self._alive.size), bool)
            grown[: self._alive.size] = self._alive
            self._alive = grown
        self._alive[slot] = True
        if len(bow):
            words = np.asarray(bow.words, np.int32)
            self._tail.append(
                (words, np.full(words.size, slot, np.int32), bow.weights.astype(np.float32))
            )
            self._tail_entries += words.size
            self._tail_cat = None
            if self._tail_entries > max(
                self.TAIL_MIN_ENTRIES, self.TAIL_FRACTION * self._slot.size
            ):
                self._merge()

    def remove(self, key: int) -> None:
        """Take a keyframe out (KeyError if absent); its postings go at the next merge."""
        slot = self._slot_of.pop(int(key))
        self._bows[slot] = None
        self._alive[slot] = False

    def _tail_arrays(self) -> tuple[I32, I32, F32]:
        if self._tail_cat is None:
            if self._tail:
                w, s, x = zip(*self._tail, strict=True)
                self._tail_cat = (np.concatenate(w), np.concatenate(s), np.concatenate(x))
            else:
                self._tail_cat = (
                    np.zeros(0, np.int32),
                    np.zeros(0, np.int32),
                    np.zeros(0, np.float32),
                )
        return self._tail_cat

    def _merge(self) -> None:
        """Sort the tail into the sorted part (both are sorted runs by (word, slot): a stable
        sort merges them in linear time) and drop removed keyframes' entries."""
        tw, ts, tx = self._tail_arrays()
        n_words_old = self._indptr.size - 1
        old_w = np.repeat(np.arange(n_words_old, dtype=np.int32), np.diff(self._indptr))
        order_t = np.argsort(tw, kind="stable")  # slots ascend within a word already
        words = np.concatenate([old_w, tw[order_t]])
        slots = np.concatenate([self._slot, ts[order_t]])
        weights = np.concatenate([self._weight, tx[order_t]])
        order = np.argsort(words, kind="stable")
        words, slots, weights = words[order], slots[order], weights[order]
        live = self._alive[slots]
        words, slots, weights = words[live], slots[live], weights[live]
        n_words = max(n_words_old, int(words.max()) + 1 if words.size else 0)
        self._indptr = np.zeros(n_words + 1, np.int64)
        np.cumsum(np.bincount(words, minlength=n_words), out=self._indptr[1:])
        self._slot = np.ascontiguousarray(slots, np.int32)
        self._weight = np.ascontiguousarray(weights, np.float32)
        self._tail = []
        self._tail_entries = 0
        self._tail_cat = None

    # ---- queries --------------------------------------------------------------------------
    def scores(self, bow: BowVector) -> tuple[I64, F64]:
        """Slots and L1 scores of every live keyframe sharing a word with `bow`."""
        n = len(self._keys)
        total = np.zeros(n, np.float64)
        qw = np.asarray(bow.words, np.int64)
        qx = bow.weights
        if qw.size and n:
            # sorted part: the posting ranges of the query's words
            n_words = self._indptr.size - 1
            known = qw < n_words
            kw, kx = qw[known], qx[known]
            starts = self._indptr[kw]
            lens = self._indptr[kw + 1] - starts
            idx = _ranges(starts, lens)
            contrib = np.minimum(np.repeat(kx, lens), self._weight[idx])
            total += np.bincount(self._slot[idx], weights=contrib, minlength=n)
            # tail: match its words against the (sorted) query words
            tw, ts, tx = self._tail_arrays()
            if tw.size:
                pos = np.minimum(np.searchsorted(qw, tw), qw.size - 1)
                hit = qw[pos] == tw
                contrib = np.minimum(qx[pos[hit]], tx[hit])
                total += np.bincount(ts[hit], weights=contrib, minlength=n)
        hit_slots = np.flatnonzero((total > 0.0) & self._alive[:n])
        return hit_slots.astype(np.int64), total[hit_slots]

    def query(
        self,
        bow: BowVector,
        n: int = 5,
        *,
        exclude: Collection[int] = (),
        exclude_last: int = 0,
        accept: Callable[[int], bool] | None = None,
        min_score: float = 0.0,
    ) -> list[Candidate]:
        """The best `n` keyframes by L1 score, best first (ties: the earlier added first).

        `exclude`: keys never to return (e.g. the query's covisible keyframes);
        `exclude_last`: leave out the keyframes added last (the recent past, which always
        looks like the present); `accept(key)`: a filter applied to the best-scored keys first
        (e.g. only keys of another segment); `min_score`: a floor on the score."""
        t0 = time.perf_counter()
        slots, score = self.scores(bow)
        keep = score >= min_score
        if exclude_last > 0:
            keep &= slots < len(self._keys) - exclude_last
        slots, score = slots[keep], score[keep]
        order = np.lexsort((slots, -score))
        out: list[Candidate] = []
        for i in order.tolist():
            key = self._keys[int(slots[i])]
            if key in exclude or (accept is not None and not accept(key)):
                continue
            out.append(Candidate(key, float(score[i])))
            if len(out) >= n:
                break
        ms = (time.perf_counter() - t0) * 1e3
        self.last_query_ms = ms
        self.total_query_ms += ms
        self.n_queries += 1
        return out

    def score(self, key: int, bow: BowVector) -> float:
        """The L1 score between a stored keyframe and a vector (e.g. the query against its best
        covisible neighbour, the reference DBoW2 normalises loop scores by)."""
        return self.bow(key).score(bow)

    # ---- cost -----------------------------------------------------------------------------
    def memory_bytes(self) -> int:
        """Bytes held: the posting lists, the stored vectors and the key tables (the Python
        objects' overheads estimated)."""
        total = self._indptr.nbytes + self._slot.nbytes + self._weight.nbytes
        total += self._alive.nbytes + 12 * self._tail_entries
        for b in self._bows:
            if b is not None:
                total += b.words.nbytes + b.weights.nbytes + _BOW_OVERHEAD_BYTES
        total += _KEY_OVERHEAD_BYTES * len(self._keys)
        return int(total)

    def stats(self) -> dict[str, float]:
        """Size and cost figures: keyframes, posting entries, bytes (in all and per keyframe),
        queries and their mean time in ms."""
        mem = self.memory_bytes()
        return {
            "keyframes": float(len(self)),
            "entries": float(self._slot.size + self._tail_entries),
            "memory_bytes": float(mem),
            "memory_bytes_per_keyframe": mem / max(len(self), 1),
            "queries": float(self.n_queries),
            "mean_query_ms": self.total_query_ms / max(self.n_queries, 1),
        }
