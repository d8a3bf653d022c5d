"""A bag-of-words vocabulary tree over 32-byte ORB descriptors (the DBoW2 design).

The tree has branching factor `k` and at most `levels` levels below the root; every node holds a
binary centre (the bitwise majority of the training descriptors under it) and the leaves are the
words. A descriptor descends from the root to the child at the smallest Hamming distance, level
by level, and lands on one word. An image's words, weighted by term frequency x inverse document
frequency (IDF from the training images) and L1-normalised, are its `BowVector`; two vectors are
compared with DBoW2's L1 score (`BowVector.score`, 1 = identical, 0 = no word in common).

Storage: nodes in breadth-first order, so one array of child counts describes the tree (a node's
children are contiguous and follow those of the nodes before it). The `.npz` file holds numpy
arrays only (no pickles), a kind tag, a format version and an id (a hash of the content, checked
on load). `default_vocabulary()` loads the one shipped with the package, once.
"""

from __future__ import annotations

import hashlib
import json
import threading
import zipfile
import zlib
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from eurocslam.errors import VocabularyError

KIND = "eurocslam.orb_vocabulary"
FORMAT_VERSION = 1
DESCRIPTOR_BYTES = 32
DEFAULT_FILE = "orb_k8_l5.npz"  # in the package's data/vocabulary/

I32 = NDArray[np.int32]
U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]
_FAR = DESCRIPTOR_BYTES * 8 + 1  # farther than any Hamming distance


@dataclass(frozen=True)
class BowVector:
    """A sparse, L1-normalised bag-of-words vector: sorted unique word ids and their weights
    (positive, summing to 1; empty for an image without descriptors)."""

    words: I32
    weights: F64

    def __len__(self) -> int:
        return int(self.words.size)

    @staticmethod
    def empty() -> BowVector:
        return BowVector(np.zeros(0, np.int32), np.zeros(0, np.float64))

    def score(self, other: BowVector) -> float:
        """DBoW2's L1 score, 1 - |a - b|_1 / 2 (in [0, 1]): for L1-normalised non-negative
        vectors it is the sum over the shared words of the smaller weight."""
        _, ia, ib = np.intersect1d(self.words, other.words, assume_unique=True, return_indices=True)
        return float(np.minimum(self.weights[ia], other.weights[ib]).sum())


def _content_id(k: int, levels: int, node_desc: U8, n_children: I32, idf: F64) -> str:
    h = hashlib.sha256()
    h.update(f"{KIND}/{FORMAT_VERSION}/k={k}/levels={levels}/".encode())
    for a in (node_desc, n_children, idf):
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


class Vocabulary:
    """A vocabulary tree. Build one with `eurocslam.places.train` (or `clustering.build_tree`
    and `Vocabulary.from_tree`), load one with `Vocabulary.load` or `default_vocabulary()`.

    `lookup(desc)` gives each descriptor's word id, `bow(word_ids)` the image's `BowVector`,
    `transform(desc)` both steps. Read-only after construction, so one instance can serve
    several threads."""

    def __init__(
        self,
        k: int,
        levels: int,
        node_desc: U8,
        n_children: I32,
        idf: F64,
        info: dict[str, Any] | None = None,
        source: str = "<memory>",
    ) -> None:
        self.k = int(k)
        self.levels = int(levels)
        self.node_desc: U8 = np.ascontiguousarray(node_desc, dtype=np.uint8)
        self.n_children: I32 = np.ascontiguousarray(n_children, dtype=np.int32)
        self.idf: F64 = np.ascontiguousarray(idf, dtype=np.float64)
        self.info: dict[str, Any] = dict(info or {})
        self.source = source
        problem = self._check()
        if problem is not None:
            raise VocabularyError(f"{source}: not a valid vocabulary: {problem}")
        n = self.n_nodes
        self.first_child: I32 = np.zeros(n, np.int32)
        self.first_child[1:] = 1 + np.cumsum(self.n_children[:-1], dtype=np.int64)
        self.first_child[0] = 1
        self.parent: I32 = np.zeros(n, np.int32)
        self.parent[1:] = np.repeat(np.arange(n, dtype=np.int32), self.n_children)
        leaves = np.flatnonzero(self.n_children == 0).astype(np.int32)
        self.word_node: I32 = leaves  # word id -> node
        self.node_word: I32 = np.full(n, -1, np.int32)
        self.node_word[leaves] = np.arange(leaves.size, dtype=np.int32)
        depth = np.zeros(n, np.int32)
        for _ in range(self.levels):
            depth[1:] = depth[self.parent[1:]] + 1
        self.depth: I32 = depth
        # lookup tables: every internal node's children as one contiguous block (n_internal + 1,
        # k, 4) of uint64 words, missing children (and the dummy row leaves point to) carrying a
        # distance penalty, so one level of the descent is one gather, xor and popcount
        internal = np.flatnonzero(self.n_children > 0)
        self._row: I32 = np.full(n, internal.size, np.int32)
        self._row[internal] = np.arange(internal.size, dtype=np.int32)
        offs = np.arange(self.k)
        valid = np.zeros((internal.size + 1, self.k), bool)
        valid[:-1] = offs[None, :] < self.n_children[internal][:, None]
        child = np.zeros((internal.size + 1, self.k), np.int64)
        child[:-1] = self.first_child[internal][:, None] + offs[None, :]
        child[~valid] = 0
        self._blocks = np.ascontiguousarray(self.node_desc.view(np.uint64)[child])
        self._penalty = np.where(valid, 0, _FAR).astype(np.int16)
        self._internal = self.n_children > 0
        self.id = _content_id(self.k, self.levels, self.node_desc, self.n_children, self.idf)

    # ---- structure ------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return int(self.n_children.size)

    @property
    def n_words(self) -> int:
        return int(self.idf.size)

    @cached_property
    def nbytes(self) -> int:
        """Memory of the tree's arrays in bytes."""
        arrays = (
            self.node_desc,
            self.n_children,
            self.idf,
            self.first_child,
            self.parent,
            self.node_word,
            self.word_node,
            self.depth,
            self._row,
            self._blocks,
            self._penalty,
            self._internal,
        )
        return int(sum(a.nbytes for a in arrays))

    def _check(self) -> str | None:
        """What is wrong with the arrays, or None."""
        if not 2 <= self.k <= 255:
            return f"k = {self.k} (2..255)"
        if not 1 <= self.levels <= 16:
            return f"levels = {self.levels} (1..16)"
        nd, nc, idf = self.node_desc, self.n_children, self.idf
        if nd.ndim != 2 or nd.shape[1] != DESCRIPTOR_BYTES:
            return f"node descriptors have shape {nd.shape}, expected (n, {DESCRIPTOR_BYTES})"
        if nc.ndim != 1 or nc.size != nd.shape[0] or nc.size < 2:
            return f"{nc.size} child counts for {nd.shape[0]} nodes"
        if int(nc.min()) < 0 or int(nc.max()) > self.k:
            return f"a node has {int(nc.min())}..{int(nc.max())} children (0..k={self.k})"
        if int(nc.sum()) != nc.size - 1 or nc[0] == 0:
            return "the child counts do not describe one tree"
        n_leaves = int(np.count_nonzero(nc == 0))
        if idf.ndim != 1 or idf.size != n_leaves:
            return f"{idf.size} word weights for {n_leaves} words"
        if not bool(np.all(np.isfinite(idf))) or float(idf.min()) < 0.0:
            return "word weights must be finite and >= 0"
        # breadth-first order: the children of node i follow those of nodes < i, so every
        # child's index is larger than its parent's (and depth is bounded by `levels`)
        parent = np.repeat(np.arange(nc.size), nc)
        if not bool(np.all(parent < np.arange(1, nc.size))):
            return "nodes are not in breadth-first order"
        depth = np.zeros(nc.size, np.int64)
        for _ in range(self.levels + 1):
            depth[1:] = depth[parent] + 1
        if int(depth.max()) > self.levels:
            return f"the tree is {int(depth.max())} levels deep, more than levels={self.levels}"
        return None

    # ---- lookup ---------------------------------------------------------------------------
    def lookup(self, desc: U8) -> I32:
        """The word id of every descriptor (n, 32) uint8: descend from the root to the child at
        the smallest Hamming distance, all descriptors at once, one level per step (ties: the
        first child, as DBoW2)."""
        d = np.ascontiguousarray(desc, dtype=np.uint8)
        if d.ndim != 2 or d.shape[1] != DESCRIPTOR_BYTES:
            raise ValueError(f"descriptors must be (n, {DESCRIPTOR_BYTES}) uint8, got {d.shape}")
        n = d.shape[0]
        cur = np.zeros(n, np.int32)
        if n == 0:
            return cur
        d64 = d.view(np.uint64)[:, None, :]  # (n, 1, 4)
        for _ in range(self.levels):
            row = self._row[cur]
            c = np.bitwise_count(self._blocks[row] ^ d64)  # (n, k, 4) uint8
            dist = np.add(c[:, :, 0], c[:, :, 1], dtype=np.int16)
            dist += c[:, :, 2]
            dist += c[:, :, 3]
            dist += self._penalty[row]
            best = self.first_child[cur] + dist.argmin(axis=1).astype(np.int32)
            cur = np.where(self._internal[cur], best, cur)
        return self.node_word[cur]

    def bow(self, word_ids: I32) -> BowVector:
        """The TF-IDF, L1-normalised bag-of-words vector of one image's word ids."""
        w = np.asarray(word_ids)
        if w.size == 0:
            return BowVector.empty()
        words, counts = np.unique(w, return_counts=True)
        weights = counts * self.idf[words]  # tf x idf (tf's 1/n cancels in the normalisation)
        keep = weights > 0
        words, weights = words[keep], weights[keep]
        total = float(weights.sum())
        if total <= 0.0:
            return BowVector.empty()
        return BowVector(words.astype(np.int32, copy=False), weights / total)

    def transform(self, desc: U8) -> BowVector:
        """The `BowVector` of one image's descriptors (n, 32) uint8."""
        return self.bow(self.lookup(desc))

    # ---- files ----------------------------------------------------------------------------
    def save(self, path: Path | str) -> Path:
        """Write the vocabulary as a compressed `.npz` (numpy arrays only)."""
        p = Path(path)
        tmp = p.with_name(p.name + ".partial")
        with open(tmp, "wb") as f:
            np.savez_compressed(
                f,
                kind=np.array(KIND),
                format_version=np.array(FORMAT_VERSION, np.int64),
                id=np.array(self.id),
                k=np.array(self.k, np.int64),
                levels=np.array(self.levels, np.int64),
                node_desc=self.node_desc,
                n_children=self.n_children,
                idf=self.idf,
                info=np.array(json.dumps(self.info, sort_keys=True)),
            )
        tmp.replace(p)
        return p

    @classmethod
    def load(cls, path: Path | str) -> Vocabulary:
        """Read a vocabulary file; anything but an intact file of this kind and version raises
        a one-line `VocabularyError` naming the file."""
        p = Path(path)
        try:
            z = np.load(p, allow_pickle=False)
            if not isinstance(z, np.lib.npyio.NpzFile):
                raise VocabularyError(f"{p}: not a vocabulary file (a single array, not an .npz)")
            with z:
                arrays = {name: z[name] for name in z.files}
        except FileNotFoundError:
            raise VocabularyError(f"{p}: vocabulary file not found") from None
        except IsADirectoryError:
            raise VocabularyError(f"{p}: is a folder, not a vocabulary file") from None
        except VocabularyError:
            raise
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as e:
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise VocabularyError(f"{p}: not a readable vocabulary file ({msg})") from None
        kind = _scalar(arrays, "kind", str, p)
        if kind != KIND:
            raise VocabularyError(f"{p}: not an eurocslam ORB vocabulary (kind {kind!r})")
        version = _scalar(arrays, "format_version", int, p)
        if version != FORMAT_VERSION:
            raise VocabularyError(
                f"{p}: vocabulary format version {version}, this eurocslam reads version "
                f"{FORMAT_VERSION} (rebuild it with python -m eurocslam.places.train)"
            )
        try:
            info = json.loads(_scalar(arrays, "info", str, p))
        except json.JSONDecodeError:
            raise VocabularyError(f"{p}: corrupt vocabulary (info is not JSON)") from None
        node_desc = _array(arrays, "node_desc", np.uint8, p)
        n_children = _array(arrays, "n_children", np.int32, p)
        idf = _array(arrays, "idf", np.float64, p)
        voc = cls(
            _scalar(arrays, "k", int, p),
            _scalar(arrays, "levels", int, p),
            node_desc,
            n_children,
            idf,
            info if isinstance(info, dict) else {},
            source=str(p),
        )
        stored = _scalar(arrays, "id", str, p)
        if stored != voc.id:
            raise VocabularyError(
                f"{p}: corrupt vocabulary (content hash {voc.id}, the file says {stored})"
            )
        return voc

    @classmethod
    def from_tree(
        cls,
        k: int,
        levels: int,
        node_desc: U8,
        n_children: I32,
        train_words: list[I32],
        info: dict[str, Any] | None = None,
    ) -> Vocabulary:
        """A vocabulary from a tree and the training images' descriptors (as word ids of the
        tree without weights): IDF = log(N images / images containing the word); a word no
        training image reaches gets log(N), the weight of the rarest seen word."""
        n_leaves = int(np.count_nonzero(np.asarray(n_children) == 0))
        tmp = cls(k, levels, node_desc, n_children, np.ones(n_leaves), info)
        df = np.zeros(n_leaves, np.int64)
        for w in train_words:
            df[np.unique(w)] += 1
        n_img = max(len(train_words), 1)
        idf = np.log(n_img / np.maximum(df, 1)).astype(np.float64)
        return cls(k, levels, tmp.node_desc, tmp.n_children, idf, info)

    def __repr__(self) -> str:
        return (
            f"Vocabulary(id={self.id}, k={self.k}, levels={self.levels}, words={self.n_words}, "
            f"source={self.source})"
        )


def _scalar(arrays: dict[str, Any], name: str, typ: type, path: Path) -> Any:
    if name not in arrays:
        raise VocabularyError(f"{path}: not a vocabulary file (no {name!r} entry)")
    a = arrays[name]
    if a.shape != ():
        raise VocabularyError(f"{path}: corrupt vocabulary ({name!r} is not a single value)")
    if typ is str and a.dtype.kind == "U":
        return str(a)
    if typ is int and a.dtype.kind in "iu":
        return int(a)
    raise VocabularyError(f"{path}: corrupt vocabulary ({name!r} has type {a.dtype})")


def _array(arrays: dict[str, Any], name: str, dtype: type, path: Path) -> Any:
    if name not in arrays:
        raise VocabularyError(f"{path}: not a vocabulary file (no {name!r} entry)")
    a = arrays[name]
    if a.dtype != np.dtype(dtype):
        raise VocabularyError(
            f"{path}: corrupt vocabulary ({name!r} is {a.dtype}, expected {np.dtype(dtype)})"
        )
    return a


_DEFAULT: Vocabulary | None = None
_DEFAULT_LOCK = threading.Lock()


def default_vocabulary_path() -> Path:
    """The vocabulary shipped with the package."""
    return Path(str(resources.files("eurocslam") / "data" / "vocabulary" / DEFAULT_FILE))


def default_vocabulary() -> Vocabulary:
    """The shipped vocabulary, loaded on first use and shared afterwards."""
    global _DEFAULT
    with _DEFAULT_LOCK:
        if _DEFAULT is None:
            _DEFAULT = Vocabulary.load(default_vocabulary_path())
        return _DEFAULT
