"""Place recognition: the vocabulary tree, its files, the keyframe database, and the appearance
of real frames and of a repetitive-texture world."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import SHARED_EUROC
from eurocslam.errors import EurocSlamError, VocabularyError
from eurocslam.places import (
    BowVector,
    Candidate,
    KeyframeDatabase,
    Vocabulary,
    default_vocabulary,
)
from eurocslam.places.clustering import build_tree, majority
from eurocslam.places.vocabulary import FORMAT_VERSION, KIND, default_vocabulary_path

KITTI = SHARED_EUROC.parent / "kitti_excerpt" / "sequences" / "k2" / "image_0"


# ---- helpers ---------------------------------------------------------------------------------
def clustered_descriptors(rng: np.random.Generator, n_images: int, per_image: int) -> list:
    """Descriptors drawn around 40 random prototypes (a few bits flipped), per image."""
    protos = rng.integers(0, 256, (40, 32), dtype=np.uint8)
    images = []
    for _ in range(n_images):
        which = rng.integers(0, protos.shape[0], per_image)
        flips = rng.random((per_image, 256)) < 0.04
        bits = np.unpackbits(protos[which], axis=1) ^ flips.astype(np.uint8)
        images.append(np.packbits(bits, axis=1))
    return images


@pytest.fixture(scope="module")
def small_voc() -> tuple[Vocabulary, list[np.ndarray]]:
    rng = np.random.default_rng(7)
    images = clustered_descriptors(rng, 30, 200)
    tree = build_tree(np.concatenate(images), k=5, levels=3, seed=1)
    plain = Vocabulary(5, 3, tree.node_desc, tree.n_children, np.ones((tree.n_children == 0).sum()))
    voc = Vocabulary.from_tree(
        5, 3, tree.node_desc, tree.n_children, [plain.lookup(d) for d in images], {"test": 1}
    )
    return voc, images


def reference_lookup(voc: Vocabulary, d: np.ndarray) -> int:
    """Descend one descriptor child by child (the definition `lookup` vectorises)."""
    node = 0
    while voc.n_children[node] > 0:
        first = int(voc.first_child[node])
        kids = range(first, first + int(voc.n_children[node]))
        dist = [int(np.unpackbits(voc.node_desc[c] ^ d).sum()) for c in kids]
        node = first + int(np.argmin(dist))
    return int(voc.node_word[node])


def one_line_error(path: Path) -> str:
    with pytest.raises(VocabularyError) as e:
        Vocabulary.load(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg
    assert isinstance(e.value, EurocSlamError)
    return msg


def rewrite(src: Path, dst: Path, **changes: object) -> Path:
    """Copy a vocabulary file's arrays into another .npz with some entries changed/removed."""
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = np.asarray(v)
    np.savez(dst, **arrays)
    return dst


# ---- clustering ------------------------------------------------------------------------------
def test_majority_is_the_bitwise_vote() -> None:
    rng = np.random.default_rng(0)
    desc = rng.integers(0, 256, (301, 32), dtype=np.uint8)
    labels = rng.integers(0, 3, 301).astype(np.int64)
    centres, sizes = majority(desc, labels, 3)
    for c in range(3):
        bits = np.unpackbits(desc[labels == c], axis=1)
        expect = np.packbits(bits.sum(axis=0) * 2 > bits.shape[0])
        assert np.array_equal(centres[c], expect)
        assert sizes[c] == np.count_nonzero(labels == c)


def test_tree_is_deterministic_and_breadth_first(small_voc) -> None:  # type: ignore[no-untyped-def]
    voc, images = small_voc
    tree = build_tree(np.concatenate(images), k=5, levels=3, seed=1)
    assert np.array_equal(tree.node_desc, voc.node_desc)
    assert np.array_equal(tree.n_children, voc.n_children)
    assert voc.depth.max() <= 3 and voc.n_children.max() <= 5
    assert np.all(voc.parent[1:] < np.arange(1, voc.n_nodes))


def test_train_is_reproducible(small_voc) -> None:  # type: ignore[no-untyped-def]
    from eurocslam.places.train import train

    voc, images = small_voc
    again = train(images, 5, 3, seed=1)
    assert again.id == voc.id and again.info["training_images"] == len(images)


def test_train_command_builds_a_loadable_vocabulary(tmp_path: Path) -> None:
    """The training command end to end, on a 2 s rendered flight (3 images)."""
    from eurocslam.places.train import main

    out = tmp_path / "voc.npz"
    args = [str(out), "--seeds", "3", "--duration", "2", "--step", "0.9", "--k", "4"]
    assert main([*args, "--levels", "2"]) == 0
    voc = Vocabulary.load(out)
    assert (voc.k, voc.levels, voc.info["seeds"]) == (4, 2, [3])
    assert voc.info["training_images"] == 3 and voc.n_words > 4


# ---- vocabulary ------------------------------------------------------------------------------
def test_lookup_matches_the_reference_descent(small_voc) -> None:  # type: ignore[no-untyped-def]
    voc, images = small_voc
    rng = np.random.default_rng(3)
    queries = np.concatenate([images[0][:50], rng.integers(0, 256, (50, 32), dtype=np.uint8)])
    words = voc.lookup(queries)
    assert words.dtype == np.int32 and words.shape == (100,)
    assert [reference_lookup(voc, d) for d in queries] == words.tolist()
    assert np.array_equal(voc.lookup(queries), words)  # deterministic
    assert voc.lookup(np.zeros((0, 32), np.uint8)).shape == (0,)
    with pytest.raises(ValueError):
        voc.lookup(np.zeros((3, 16), np.uint8))


def test_bow_vector_is_tf_idf_and_l1_normalised(small_voc) -> None:  # type: ignore[no-untyped-def]
    voc, images = small_voc
    words = voc.lookup(images[1])
    bow = voc.bow(words)
    assert np.all(np.diff(bow.words) > 0) and np.all(bow.weights > 0)
    assert bow.weights.sum() == pytest.approx(1.0)
    w0 = int(bow.words[0])
    expect = np.count_nonzero(words == w0) * voc.idf[w0]
    total = sum(np.count_nonzero(words == w) * voc.idf[w] for w in np.unique(words))
    assert bow.weights[0] == pytest.approx(expect / total)
    assert bow.score(bow) == pytest.approx(1.0)
    other = voc.transform(images[2])
    l1 = 1 - 0.5 * np.abs(dense(bow, voc.n_words) - dense(other, voc.n_words)).sum()
    assert bow.score(other) == pytest.approx(l1)
    assert len(voc.transform(np.zeros((0, 32), np.uint8))) == 0


def dense(b: BowVector, n: int) -> np.ndarray:
    v = np.zeros(n)
    v[b.words] = b.weights
    return v


def test_save_load_round_trip(small_voc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    voc, images = small_voc
    path = voc.save(tmp_path / "v.npz")
    back = Vocabulary.load(path)
    assert back.id == voc.id and back.info == {"test": 1}
    for d in images[:5]:
        a, b = voc.transform(d), back.transform(d)
        assert np.array_equal(a.words, b.words) and np.array_equal(a.weights, b.weights)
    assert not (tmp_path / "v.npz.partial").exists()


def test_bad_files_give_one_line_errors(small_voc, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    voc, _ = small_voc
    good = voc.save(tmp_path / "good.npz")
    data = good.read_bytes()
    assert "not found" in one_line_error(tmp_path / "missing.npz")
    assert "folder" in one_line_error(tmp_path)
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    assert "not a readable vocabulary" in one_line_error(tmp_path / "trunc.npz")
    (tmp_path / "junk.npz").write_bytes(b"\x00garbage" * 100)
    one_line_error(tmp_path / "junk.npz")
    (tmp_path / "empty.npz").write_bytes(b"")
    one_line_error(tmp_path / "empty.npz")
    np.save(tmp_path / "array.npy", np.zeros(3))
    one_line_error(tmp_path / "array.npy")
    msg = one_line_error(rewrite(good, tmp_path / "kind.npz", kind="something.else"))
    assert "not an eurocslam ORB vocabulary" in msg
    assert "no 'kind'" in one_line_error(rewrite(good, tmp_path / "nokind.npz", kind=None))
    msg = one_line_error(rewrite(good, tmp_path / "v2.npz", format_version=FORMAT_VERSION + 1))
    assert f"version {FORMAT_VERSION + 1}" in msg
    # one flipped bit in a centre: the content hash no longer matches the stored id
    nd = voc.node_desc.copy()
    nd[5, 3] ^= 1
    assert "content hash" in one_line_error(rewrite(good, tmp_path / "flip.npz", node_desc=nd))
    msg = one_line_error(
        rewrite(good, tmp_path / "tree.npz", n_children=voc.n_children[::-1].copy())
    )
    assert "not a valid vocabulary" in msg
    msg = one_line_error(rewrite(good, tmp_path / "dtype.npz", idf=voc.idf.astype(np.float32)))
    assert "float32" in msg
    one_line_error(rewrite(good, tmp_path / "info.npz", info="{not json"))
    # a zip member damaged in place (the archive's CRC catches it)
    bad = bytearray(data)
    with zipfile.ZipFile(good) as z:
        info = z.getinfo("node_desc.npy")
    start = info.header_offset + 30 + len(info.filename) + 40
    bad[start : start + 8] = b"\xff" * 8
    (tmp_path / "crc.npz").write_bytes(bytes(bad))
    one_line_error(tmp_path / "crc.npz")


def test_default_vocabulary_is_shipped_and_loaded_once() -> None:
    path = default_vocabulary_path()
    assert path.exists() and path.stat().st_size < 2_000_000
    voc = default_vocabulary()
    assert default_vocabulary() is voc
    assert voc.info["built_by"].endswith("python -m eurocslam.places.train")
    assert voc.info["training_images"] > 0 and 0 not in voc.info["seeds"]
    # the shipped file is what `python -m eurocslam.places.train OUT` builds by default
    from eurocslam.places import train

    assert voc.info["seeds"] == list(train.DEFAULT_SEEDS) and voc.info["groundtruth"] == []
    assert (voc.k, voc.levels) == (train.DEFAULT_K, train.DEFAULT_LEVELS)
    assert voc.info["duration_s"] == train.DEFAULT_DURATION_S
    assert voc.info["step_s"] == train.DEFAULT_STEP_S
    with np.load(path) as z:
        assert str(z["kind"]) == KIND and str(z["id"]) == voc.id
        assert json.loads(str(z["info"])) == voc.info


def test_default_vocabulary_transform_is_vectorised() -> None:
    """A 1000-descriptor image in one call (the speed is measured in bench_places.py)."""
    voc = default_vocabulary()
    rng = np.random.default_rng(0)
    desc = rng.integers(0, 256, (1000, 32), dtype=np.uint8)
    bow = voc.transform(desc)
    assert 0 < len(bow) <= 1000
    assert np.array_equal(voc.transform(desc).weights, bow.weights)


# ---- database --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def bows(small_voc) -> list[BowVector]:  # type: ignore[no-untyped-def]
    voc, images = small_voc
    return [voc.transform(d) for d in images]


def brute_force(db: KeyframeDatabase, bow: BowVector) -> list[tuple[int, float]]:
    scored = [(k, db.bow(k).score(bow)) for k in db]
    return sorted([t for t in scored if t[1] > 0], key=lambda t: -t[1])


def test_identical_image_scores_highest(bows: list[BowVector]) -> None:
    db = KeyframeDatabase()
    for i, b in enumerate(bows):
        db.add(1000 + i, b)
    for i in (0, 7, 29):
        best = db.query(bows[i], 3)
        assert best[0] == Candidate(1000 + i, pytest.approx(1.0))
        assert best[1].score < 1.0
    assert len(db) == len(bows) and 1005 in db and 5 not in db


def test_query_agrees_with_brute_force_across_merges(bows: list[BowVector]) -> None:
    db = KeyframeDatabase()
    db.TAIL_MIN_ENTRIES = 200  # merge the tail often
    for i, b in enumerate(bows * 3):
        db.add(i, b)
        if i % 11 == 5:
            db.remove(i - 2)
        q = bows[(i * 7) % len(bows)]
        got = db.query(q, 8)
        ref = brute_force(db, q)[:8]
        assert [c.score for c in got] == pytest.approx([s for _, s in ref], abs=1e-6)
    stats = db.stats()
    assert stats["keyframes"] == len(db) and stats["memory_bytes"] == db.memory_bytes() > 0
    assert stats["queries"] == 3 * len(bows) and db.last_query_ms >= 0.0


def test_exclusions_and_filters(bows: list[BowVector]) -> None:
    db = KeyframeDatabase()
    for i, b in enumerate(bows):
        db.add(i, b)
    q = bows[29]
    assert db.query(q, 1)[0].key == 29
    assert 29 not in [c.key for c in db.query(q, 30, exclude={29})]
    recent = [c.key for c in db.query(q, 30, exclude_last=5)]
    assert recent and max(recent) < 25
    even = db.query(q, 30, accept=lambda k: k % 2 == 0)
    assert even and all(c.key % 2 == 0 for c in even)
    assert all(c.score >= 0.5 for c in db.query(q, 30, min_score=0.5))
    db.remove(29)
    assert 29 not in db and 29 not in [c.key for c in db.query(q, 30)]
    with pytest.raises(KeyError):
        db.remove(29)
    with pytest.raises(ValueError, match="already"):
        db.add(3, bows[3])
    assert db.query(BowVector.empty(), 5) == []
    assert KeyframeDatabase().query(q, 5) == []
    assert db.score(3, bows[3]) == pytest.approx(1.0)


# ---- appearance on rendered and real images --------------------------------------------------
def test_repetitive_texture_proposes_a_different_place() -> None:
    """Two places 2 m apart, looking 60+ deg apart, in a room tiled with one texture: the
    database proposes the other place with a score as high as a true revisit's in an ordinary
    room. It only proposes: rejecting such a candidate is the geometric verification's job."""
    from places_helpers import far_apart_frames, left_descriptors, repetitive_scene

    voc = default_vocabulary()
    scene = repetitive_scene(seed=0)
    a, b = far_apart_frames(scene)
    da, db_, da2 = left_descriptors(scene, [a, b, a + 4])
    database = KeyframeDatabase()
    database.add(b, voc.transform(db_))
    best = database.query(voc.transform(da), 1)
    assert best and best[0].key == b
    assert best[0].score > 0.15  # an ordinary room scores different places < 0.1
    assert voc.transform(da).score(voc.transform(da2)) > best[0].score  # same place: higher


def orb_real(files: list[Path]) -> list[np.ndarray]:
    from eurocslam.frontend.config import FrontendConfig
    from eurocslam.frontend.features import OrbExtractor

    img0 = cv2.imread(str(files[0]), cv2.IMREAD_GRAYSCALE)
    orb = OrbExtractor(FrontendConfig(), img0.shape[1], img0.shape[0])
    return [orb.extract(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)).desc for f in files]


def test_real_kitti_scores_fall_with_distance() -> None:
    """Out of domain (trained on renders): KITTI frames ~1 m apart score higher than frames
    10 m apart, and every frame's best match is a temporal neighbour."""
    if not KITTI.exists():
        pytest.skip(f"KITTI excerpt not available ({KITTI})")
    voc = default_vocabulary()
    bows = [voc.transform(d) for d in orb_real(sorted(KITTI.glob("*.png"))[:31])]
    near = np.mean([bows[i].score(bows[i + 1]) for i in range(20)])
    far = np.mean([bows[i].score(bows[i + 10]) for i in range(20)])
    assert near > 1.3 * far
    db = KeyframeDatabase()
    for i, b in enumerate(bows):
        db.add(i, b)
    for i, b in enumerate(bows):
        best = db.query(b, 1, exclude={i})[0]
        assert abs(best.key - i) <= 2


def test_real_euroc_frames_recognise_their_own_place(v101_micro: Path, mh01_first5: Path) -> None:
    """Real EuRoC frames: frames of one place score far above frames of the other sequence."""
    voc = default_vocabulary()
    v1 = orb_real(sorted((v101_micro / "mav0" / "cam0" / "data").glob("*.png"))[:10])
    mh = orb_real(sorted((mh01_first5 / "mav0" / "cam0" / "data").glob("*.png")))
    bv, bm = [voc.transform(d) for d in v1], [voc.transform(d) for d in mh]
    same_v1 = np.mean([bv[i].score(bv[i + 1]) for i in range(9)])
    same_mh = np.mean([bm[i].score(bm[i + 1]) for i in range(4)])
    cross = np.mean([a.score(b) for a in bv for b in bm])
    assert same_v1 > 3 * cross and same_mh > 2 * cross
