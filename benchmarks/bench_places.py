"""Place recognition benchmark: the bag-of-words keyframe database against faiss binary indexes.

    .venv/bin/python benchmarks/bench_places.py            # shipped vocabulary (BoW only)
    .venv/bin/python benchmarks/bench_places.py --faiss    # also faiss (pip install faiss-cpu)
    .venv/bin/python benchmarks/bench_places.py --vocab A.npz B.npz --sequences V1_01_easy

Table 1, retrieval on rendered replicas of EuRoC flights (seed 0, the benchmark's world; the
shipped vocabulary is trained on other worlds): every `--step` seconds the left image is a
keyframe; it queries the database of the keyframes older than `--window` seconds, then joins
it. A query *has a revisit* when some older keyframe's camera is within `--radius` metres and
`--angle` degrees of viewing direction of its own (ground truth); recall@N: the share of those
queries with such a keyframe among the first N candidates. Per method: the index's size after
the flight, the build time (adding every keyframe, BoW transform included), query ms per
keyframe (transform + query), memory per keyframe, recall@1/@5, and the mean top-1 score of
queries with and without a revisit (the gap is what a threshold can use).

Methods: `bow:FILE` (vocabulary file; `bow` alone: the shipped one), `faiss-flat` (exact nearest
descriptor in an `IndexBinaryFlat`, a keyframe's score = its share of the query's descriptors
whose nearest neighbour is in it at Hamming <= 50 and passes a 0.8 ratio test) and `faiss-hnsw`
(the same over `IndexBinaryHNSW`, M=16).

Table 2, real frames (out of domain: the vocabulary never saw a real image), from
../shared/data: V1_01 micro (95 frames, the drone standing still), the first 5 MH_01 frames and
the KITTI excerpt (51 frames, about 1 m apart): mean L1 score of frame pairs k frames apart, and
the share of frames whose best match among the others is a temporal neighbour (+-2 frames; not
for the static V1_01 frames, all of one place), and the mean score against the other sets'
frames (different places).
Rendered views are cached in `--cache` (default under the system's temporary directory).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from eurocslam.dataset.calib import load_rig
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.features import OrbExtractor
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.places.database import KeyframeDatabase
from eurocslam.places.renders import replica_spec, views
from eurocslam.places.vocabulary import Vocabulary, default_vocabulary, default_vocabulary_path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("EUROCSLAM_SHARED", REPO.parent / "shared/data"))
DEFAULT_SEQUENCES = ["V1_01_easy", "V2_01_easy", "MH_01_easy", "MH_05_difficult"]


# ---- rendered sequences ----------------------------------------------------------------------
@dataclass
class Seq:
    name: str
    t_s: np.ndarray  # (n,)
    T: np.ndarray  # (n, 4, 4) T_world_rect0
    desc: list[np.ndarray]


def groundtruth_file(name: str) -> Path:
    for ext in (".csv", ".txt"):
        f = SHARED / "euroc" / "groundtruth" / f"{name}{ext}"
        if f.exists():
            return f
    sys.exit(f"no ground truth for {name} in {SHARED / 'euroc' / 'groundtruth'}")


def load_seq(name: str, seed: int, step: float, cache: Path) -> Seq:
    f = cache / f"{name}_s{seed}_step{step:g}.npz"
    if not f.exists():
        t0 = time.perf_counter()
        vs = list(views(replica_spec(groundtruth_file(name), seed), step))
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(
            f,
            t_ns=np.array([v.t_ns for v in vs]),
            T=np.stack([v.T_world_rect0 for v in vs]),
            n=np.array([v.desc.shape[0] for v in vs]),
            desc=np.concatenate([v.desc for v in vs]),
        )
        print(f"rendered {name}: {len(vs)} views in {time.perf_counter() - t0:.0f} s", flush=True)
    z = np.load(f)
    desc = np.split(z["desc"], np.cumsum(z["n"])[:-1])
    t = (z["t_ns"] - z["t_ns"][0]) * 1e-9
    return Seq(name, t, z["T"], desc)


def true_matches(seq: Seq, radius: float, angle_deg: float) -> np.ndarray:
    """(n, n) bool: camera j within `radius` m and `angle_deg` of viewing direction of i."""
    p = seq.T[:, :3, 3]
    z = seq.T[:, :3, 2]
    dist = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
    cosang = np.clip(z @ z.T, -1.0, 1.0)
    return (dist < radius) & (cosang > np.cos(np.radians(angle_deg)))


# ---- indexes ---------------------------------------------------------------------------------
class BowIndex:
    def __init__(self, voc: Vocabulary) -> None:
        self.voc = voc
        self.db = KeyframeDatabase()
        self.bows: dict[int, object] = {}

    def prepare(self, key: int, desc: np.ndarray) -> object:
        return self.voc.transform(desc)

    def add(self, key: int, prepared: object) -> None:
        self.db.add(key, prepared)  # type: ignore[arg-type]

    def query(self, prepared: object, n: int) -> list[tuple[int, float]]:
        return [(c.key, c.score) for c in self.db.query(prepared, n)]  # type: ignore[arg-type]

    def memory_bytes(self) -> int:
        return self.db.memory_bytes()


class FaissIndex:
    MAX_HAMMING = 50
    RATIO = 0.8

    def __init__(self, kind: str) -> None:
        import faiss

        self.index = (
            faiss.IndexBinaryFlat(256) if kind == "flat" else faiss.IndexBinaryHNSW(256, 16)
        )
        self.owner = np.zeros(0, np.int64)
        self.n_desc = 0

    def prepare(self, key: int, desc: np.ndarray) -> object:
        return np.ascontiguousarray(desc)

    def add(self, key: int, prepared: object) -> None:
        d = prepared  # type: ignore[assignment]
        self.index.add(d)
        self.owner = np.concatenate([self.owner, np.full(d.shape[0], key)])  # type: ignore[union-attr]
        self.n_desc += d.shape[0]  # type: ignore[union-attr]

    def query(self, prepared: object, n: int) -> list[tuple[int, float]]:
        d = prepared
        if self.n_desc < 2 or d.shape[0] == 0:  # type: ignore[union-attr]
            return []
        D, I = self.index.search(d, 2)
        ok = (I[:, 0] >= 0) & (D[:, 0] <= self.MAX_HAMMING) & (D[:, 0] < self.RATIO * D[:, 1])
        votes = np.bincount(self.owner[I[ok, 0]])
        top = np.argsort(-votes, kind="stable")[:n]
        m = d.shape[0]  # type: ignore[union-attr]
        return [(int(k), votes[k] / m) for k in top if votes[k] > 0]

    def memory_bytes(self) -> int:
        import faiss

        # the serialised index is the in-memory one (vectors, and HNSW's links)
        return int(faiss.serialize_index_binary(self.index).size + self.owner.nbytes)


def make_index(method: str) -> Callable[[], BowIndex | FaissIndex]:
    if method == "bow":
        return lambda: BowIndex(default_vocabulary())
    if method.startswith("bow:"):
        voc = Vocabulary.load(method[4:])
        return lambda: BowIndex(voc)
    if method in ("faiss-flat", "faiss-hnsw"):
        return lambda: FaissIndex(method.split("-")[1])
    sys.exit(f"unknown method {method!r}")


def evaluate(make: Callable[[], BowIndex | FaissIndex], seq: Seq, args: argparse.Namespace) -> dict:
    idx = make()
    truth = true_matches(seq, args.radius, args.angle)
    n = len(seq.desc)
    add_s = query_s = 0.0
    pending: list[tuple[int, object]] = []
    hits1 = hits5 = n_rev = 0
    top_rev: list[float] = []
    top_norev: list[float] = []
    tops: list[tuple[float, bool]] = []  # (top-1 score, top-1 is a true revisit)
    for i in range(n):
        t0 = time.perf_counter()
        prep = idx.prepare(i, seq.desc[i])
        t1 = time.perf_counter()
        # keyframes join the database once they are older than the window
        while pending and seq.t_s[pending[0][0]] < seq.t_s[i] - args.window:
            j, pj = pending.pop(0)
            ta = time.perf_counter()
            idx.add(j, pj)
            add_s += time.perf_counter() - ta
        t2 = time.perf_counter()
        cands = idx.query(prep, 5)
        t3 = time.perf_counter()
        query_s += (t1 - t0) + (t3 - t2)
        add_s += t1 - t0
        pending.append((i, prep))
        older = seq.t_s < seq.t_s[i] - args.window
        revisit = bool((truth[i] & older).any())
        best = cands[0][1] if cands else 0.0
        (top_rev if revisit else top_norev).append(best)
        ok = [bool(truth[i, k]) for k, _ in cands]
        if cands:
            tops.append((best, ok[0]))
        if revisit:
            n_rev += 1
            hits1 += bool(ok[:1] and ok[0])
            hits5 += any(ok)
    size = n - len(pending)
    mem = idx.memory_bytes()
    return {
        "keyframes": size,
        "queries": n,
        "revisits": n_rev,
        "build_s": add_s,
        "query_ms": 1e3 * query_s / n,
        "kb_per_kf": mem / max(size, 1) / 1024,
        "r1": hits1 / max(n_rev, 1),
        "r5": hits5 / max(n_rev, 1),
        "ap": average_precision(tops, n_rev),
        "top_rev": float(np.mean(top_rev)) if top_rev else float("nan"),
        "top_norev": float(np.mean(top_norev)) if top_norev else float("nan"),
        "tops": tops,
        "hits1": hits1,
        "hits5": hits5,
        "query_s": query_s,
        "mem": mem,
    }


def average_precision(tops: list[tuple[float, bool]], n_revisits: int) -> float:
    """Average precision of the top-1 proposals ranked by score (a loop detector with a score
    threshold: precision and recall over every threshold), recall over the revisit queries."""
    if n_revisits == 0 or not tops:
        return float("nan")
    order = sorted(range(len(tops)), key=lambda i: -tops[i][0])
    correct = np.array([tops[i][1] for i in order], dtype=float)
    precision = np.cumsum(correct) / np.arange(1, correct.size + 1)
    return float(np.sum(precision * correct) / n_revisits)


# ---- real frames -----------------------------------------------------------------------------
def real_sets() -> list[tuple[str, list[np.ndarray]]]:
    """ORB descriptors of the real frames at hand: (name, per-frame descriptors)."""
    cfg = FrontendConfig()
    out = []
    for name, folder in (
        ("V1_01 micro (static)", SHARED / "euroc" / "V1_01_easy_micro"),
        ("MH_01 first 5", SHARED / "euroc" / "MH_01_easy_first5"),
    ):
        if not folder.exists():
            continue
        rig = load_rig(folder)
        rect = StereoRectifier(rig, cfg.rectify_alpha)
        g = rect.geometry
        orb = OrbExtractor(cfg, g.width, g.height)
        files = sorted((folder / "mav0" / "cam0" / "data").glob("*.png"))
        out.append(
            (
                name,
                [orb.extract(rect.rectify_left(cv2.imread(str(f), 0))).desc for f in files],
            )
        )
    kitti = SHARED / "kitti_excerpt" / "sequences" / "k2" / "image_0"
    if kitti.exists():
        files = sorted(kitti.glob("*.png"))
        img0 = cv2.imread(str(files[0]), 0)
        orb = OrbExtractor(cfg, img0.shape[1], img0.shape[0])
        out.append(("KITTI excerpt", [orb.extract(cv2.imread(str(f), 0)).desc for f in files]))
    return out


def real_table(voc: Vocabulary, sets: list[tuple[str, list[np.ndarray]]]) -> None:
    print(f"\nReal frames, vocabulary {voc.id} ({voc.n_words} words)")
    gaps = (1, 2, 5, 10, 20, 40)
    hdr = "set                     frames  " + "".join(f"gap {g:<4}" for g in gaps)
    print(hdr + "  best is +-2  vs other set")
    bows_all = {name: [voc.transform(d) for d in ds] for name, ds in sets}
    for name, bows in bows_all.items():
        n = len(bows)
        S = np.array([[a.score(b) for b in bows] for a in bows])
        cells = []
        for g in gaps:
            cells.append(f"{np.mean(np.diag(S, g)):.3f}   " if g < n else "   -     ")
        np.fill_diagonal(S, -1.0)
        best = S.argmax(axis=1)
        near = float(np.mean(np.abs(best - np.arange(n)) <= 2)) if n > 1 else float("nan")
        near_s = "(static)" if "static" in name else f"{near:.0%}"
        others = [b for o, bs in bows_all.items() if o != name for b in bs]
        cross = np.mean([a.score(b) for a in bows[:10] for b in others]) if others else np.nan
        print(f"{name:<24}{n:>6}  " + "".join(cells) + f"  {near_s:>9}  {cross:>11.3f}")


def print_row(label: str, name: str, r: dict) -> None:
    print(
        f"{label:<28}{name:<17}{r['keyframes']:>5}{r['revisits']:>8}"
        f"{r['build_s']:>9.2f}{r['query_ms']:>9.2f}{r['kb_per_kf']:>8.1f}"
        f"{r['r1']:>7.1%}{r['r5']:>7.1%}{r['ap']:>7.3f}{r['top_rev']:>9.3f}{r['top_norev']:>9.3f}",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--sequences", nargs="+", default=DEFAULT_SEQUENCES)
    ap.add_argument("--seed", type=int, default=0, help="world of the replicas (default 0)")
    ap.add_argument("--step", type=float, default=0.25, help="seconds between keyframes")
    ap.add_argument("--window", type=float, default=10.0, help="recent seconds not searched")
    ap.add_argument("--radius", type=float, default=1.0, help="revisit: camera within metres")
    ap.add_argument("--angle", type=float, default=30.0, help="and viewing direction, degrees")
    ap.add_argument("--vocab", nargs="*", default=[], help="vocabulary files to compare")
    ap.add_argument("--faiss", action="store_true", help="also faiss-flat and faiss-hnsw")
    ap.add_argument("--no-real", action="store_true", help="skip the real frames")
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "eurocslam-places-cache"
    )
    args = ap.parse_args()
    methods = ["bow"] + [f"bow:{v}" for v in args.vocab]
    if args.faiss:
        methods += ["faiss-flat", "faiss-hnsw"]
    cv2.setNumThreads(1)
    seqs = [load_seq(s, args.seed, args.step, args.cache) for s in args.sequences]
    print(
        f"Retrieval: keyframe every {args.step:g} s, last {args.window:g} s not searched, "
        f"revisit = within {args.radius:g} m and {args.angle:g} deg; shipped vocabulary "
        f"{default_vocabulary_path().name}"
    )
    print(
        f"{'method':<28}{'sequence':<17}{'kf':>5}{'revisit':>8}{'build s':>9}{'query ms':>9}"
        f"{'KB/kf':>8}{'R@1':>7}{'R@5':>7}{'AP':>7}{'top rev':>9}{'top new':>9}"
    )
    for m in methods:
        make = make_index(m)
        label = m if len(m) <= 27 else "bow:..." + m[-20:]
        rows = []
        for seq in seqs:
            r = evaluate(make, seq, args)
            rows.append(r)
            print_row(label, seq.name, r)
        if len(rows) > 1:
            n_rev = sum(r["revisits"] for r in rows)
            pooled = {
                "keyframes": sum(r["keyframes"] for r in rows),
                "revisits": n_rev,
                "build_s": sum(r["build_s"] for r in rows),
                "query_ms": 1e3 * sum(r["query_s"] for r in rows) / sum(r["queries"] for r in rows),
                "kb_per_kf": sum(r["mem"] for r in rows)
                / max(sum(r["keyframes"] for r in rows), 1)
                / 1024,
                "r1": sum(r["hits1"] for r in rows) / max(n_rev, 1),
                "r5": sum(r["hits5"] for r in rows) / max(n_rev, 1),
                # AP over the pooled proposals: one threshold for every sequence
                "ap": average_precision([t for r in rows for t in r["tops"]], n_rev),
                "top_rev": float(np.mean([r["top_rev"] for r in rows])),
                "top_norev": float(np.mean([r["top_norev"] for r in rows])),
            }
            print_row(label, "all (pooled)", pooled)
    if not args.no_real:
        sets = real_sets()
        if not sets:
            print(f"\nno real frames under {SHARED}: table 2 skipped")
        for m in methods:
            if m.startswith("bow"):
                voc = default_vocabulary() if m == "bow" else Vocabulary.load(m[4:])
                real_table(voc, sets)


if __name__ == "__main__":
    main()
