"""Build a vocabulary from rendered images: the shipped one, or any other.

    python -m eurocslam.places.train OUT.npz                 # the shipped vocabulary's recipe
    python -m eurocslam.places.train OUT.npz --seeds 1 2 3 --k 8 --levels 5

The training images are rendered by the project's own generator (`eurocslam.synth`: the
built-in drone flight in the worlds of `--seeds`, `--duration` seconds each, one left image
every `--step` seconds; `--groundtruth FILE` adds a replica of a recorded motion per file, in a
world seed of its own) and go through the frontend's rectification and ORB extractor with the
default configuration, as in a SLAM run. The tree is built by hierarchical k-majority clustering
(`clustering.py`) and weighted by IDF over the training images. Deterministic: the same options
give a file with the same id on any machine with the same numpy.

The benchmark's worlds (seed 0, the replicas `benchmarks/bench_places.py` evaluates on) are not
in the default seeds, so its recall is measured on unseen rooms.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.errors import EurocSlamError
from eurocslam.places.clustering import build_tree
from eurocslam.places.renders import replica_spec, views
from eurocslam.places.vocabulary import Vocabulary
from eurocslam.synth import SynthSpec

logger = logging.getLogger(__name__)

DEFAULT_SEEDS = tuple(range(1, 21))
DEFAULT_DURATION_S = 60.0
DEFAULT_STEP_S = 0.5
DEFAULT_K = 8
DEFAULT_LEVELS = 5
REPLICA_SEED_BASE = 100  # world seed of the i-th --groundtruth replica: 100 + i


def training_descriptors(
    seeds: Sequence[int],
    duration_s: float,
    step_s: float,
    groundtruths: Sequence[Path] = (),
    replica_step_s: float = 1.0,
) -> list[np.ndarray]:
    """ORB descriptors (n, 32) of every training image, in a fixed order."""
    images: list[np.ndarray] = []
    specs: list[tuple[str, SynthSpec, float]] = [
        (f"built-in flight, world {s}", SynthSpec(duration_s=duration_s, seed=s), step_s)
        for s in seeds
    ]
    specs += [
        (
            f"replica of {g.name}, world {REPLICA_SEED_BASE + i}",
            replica_spec(g, REPLICA_SEED_BASE + i),
            replica_step_s,
        )
        for i, g in enumerate(groundtruths)
    ]
    for what, spec, step in specs:
        t0 = time.perf_counter()
        n0 = len(images)
        images += [v.desc for v in views(spec, step)]
        logger.info("%s: %d images in %.0f s", what, len(images) - n0, time.perf_counter() - t0)
    return images


def train(
    images: Sequence[np.ndarray],
    k: int,
    levels: int,
    seed: int = 0,
    info: dict[str, Any] | None = None,
) -> Vocabulary:
    """A vocabulary from per-image descriptors: the tree over all of them, IDF per image."""
    desc = np.concatenate([np.asarray(d, np.uint8).reshape(-1, 32) for d in images])
    if desc.shape[0] <= k:
        raise EurocSlamError(f"{desc.shape[0]} training descriptors: too few for k={k}")
    t0 = time.perf_counter()
    tree = build_tree(desc, k, levels, seed=seed)
    n_leaves = int(np.count_nonzero(tree.n_children == 0))
    plain = Vocabulary(k, levels, tree.node_desc, tree.n_children, np.ones(n_leaves))
    words = [plain.lookup(d) for d in images]
    meta = dict(info or {})
    meta.update(
        k=k,
        levels=levels,
        tree_seed=seed,
        training_images=len(images),
        training_descriptors=int(desc.shape[0]),
    )
    voc = Vocabulary.from_tree(k, levels, tree.node_desc, tree.n_children, words, meta)
    logger.info(
        "vocabulary %s: %d words, %d nodes, built in %.0f s",
        voc.id,
        voc.n_words,
        voc.n_nodes,
        time.perf_counter() - t0,
    )
    return voc


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m eurocslam.places.train",
        description="Build an ORB vocabulary tree from images rendered by eurocslam.synth.",
    )
    ap.add_argument("out", type=Path, help="output .npz")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(DEFAULT_SEEDS))
    ap.add_argument("--duration", type=float, default=DEFAULT_DURATION_S)
    ap.add_argument("--step", type=float, default=DEFAULT_STEP_S)
    ap.add_argument(
        "--groundtruth", type=Path, nargs="*", default=[], help="also replicas of these motions"
    )
    ap.add_argument("--k", type=int, default=DEFAULT_K, help="branching factor")
    ap.add_argument("--levels", type=int, default=DEFAULT_LEVELS, help="depth of the tree")
    ap.add_argument("--tree-seed", type=int, default=0, help="seed of the k-means++ seeding")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    try:
        from eurocslam import __version__
        from eurocslam.synth.sequence import GENERATOR_REVISION

        images = training_descriptors(args.seeds, args.duration, args.step, args.groundtruth)
        info = {
            "built_by": f"eurocslam {__version__} python -m eurocslam.places.train",
            "generator_revision": GENERATOR_REVISION,
            "seeds": list(args.seeds),
            "duration_s": args.duration,
            "step_s": args.step,
            "groundtruth": [g.name for g in args.groundtruth],
        }
        voc = train(images, args.k, args.levels, args.tree_seed, info)
        voc.save(args.out)
    except EurocSlamError as e:
        print(f"error: {e}", file=sys.stderr)
        return e.exit_code
    print(f"{args.out}: vocabulary {voc.id}, {voc.n_words} words")
    return 0


if __name__ == "__main__":
    sys.exit(main())
