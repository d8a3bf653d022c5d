"""The saved map format (OUT/map): round trip, every kind of corrupt folder as one line naming
the file, and the rig check."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from eurocslam.dataset.calib import StereoRig
from eurocslam.errors import MapError
from eurocslam.maps import MapKeyframe, SavedMap, load_map, save_map
from eurocslam.maps.store import rig_mismatch, rig_record


def _rig() -> StereoRig:
    from eurocslam.synth import SynthSpec
    from eurocslam.synth.sequence import Scene

    return Scene.build(SynthSpec.tiny()).rig


def _map(rig: StereoRig, n_kf: int = 3, seed: int = 0) -> SavedMap:
    rng = np.random.default_rng(seed)
    kfs = []
    for i in range(n_kf):
        n, w = 20 + i, 7 + i
        T = np.eye(4)
        T[:3, 3] = rng.normal(size=3)
        kfs.append(
            MapKeyframe(
                key=10 + i,
                t_ns=1_400_000_000_000_000_000 + i * 50_000_000,
                session=0,
                T_world_body=T,
                uv=rng.uniform(0, 700, (n, 3)),
                desc=rng.integers(0, 256, (n, 32), dtype=np.uint8),
                landmark_id=np.where(rng.random(n) < 0.8, rng.integers(0, 50, n), -1),
                octave=rng.integers(0, 8, n).astype(np.int32),
                p_body=rng.normal(size=(n, 3)),
                bow_word=np.sort(rng.choice(1000, w, replace=False)).astype(np.int32),
                bow_weight=np.full(w, 1.0 / w),
            )
        )
    m = 50
    return SavedMap(
        kfs,
        np.arange(m, dtype=np.int64),
        rng.normal(size=(m, 3)),
        rng.integers(0, 256, (m, 32), dtype=np.uint8),
        rng.integers(0, 8, m).astype(np.int32),
        "vocab-id",
        rig_record(rig),
        "stereo-inertial",
        [{"name": "s1", "keyframes": n_kf, "landmarks": m}],
    )


@pytest.fixture(scope="module")
def rig() -> StereoRig:
    return _rig()


def test_round_trip_is_exact(rig: StereoRig, tmp_path: Path) -> None:
    m = _map(rig)
    back = load_map(save_map(tmp_path / "map", m))
    assert len(back.keyframes) == len(m.keyframes)
    for a, b in zip(m.keyframes, back.keyframes, strict=True):
        for f in a.__dataclass_fields__:
            va, vb = getattr(a, f), getattr(b, f)
            assert np.array_equal(np.asarray(va), np.asarray(vb)), f
            assert np.asarray(va).dtype == np.asarray(vb).dtype or np.isscalar(va), f
    for f in ("landmark_id", "landmark_xyz", "landmark_desc", "landmark_octave"):
        assert np.array_equal(getattr(m, f), getattr(back, f)), f
    assert (back.vocabulary_id, back.mode, back.sessions) == (m.vocabulary_id, m.mode, m.sessions)
    assert back.next_landmark_id == 50 and back.next_key == 13
    assert rig_mismatch(back.rig, rig) is None


def test_an_empty_map_round_trips(rig: StereoRig, tmp_path: Path) -> None:
    m = replace(
        _map(rig, n_kf=0),
        landmark_id=np.zeros(0, np.int64),
        landmark_xyz=np.zeros((0, 3)),
        landmark_desc=np.zeros((0, 32), np.uint8),
        landmark_octave=np.zeros(0, np.int32),
    )
    back = load_map(save_map(tmp_path / "map", m))
    assert back.keyframes == [] and back.next_landmark_id == 0


def _corrupt(folder: Path, how: str) -> Path:
    if how == "no folder":
        return folder / "nothing"
    if how == "no map.json":
        (folder / "map.json").unlink()
    elif how == "map.json not json":
        (folder / "map.json").write_text("{not json")
    elif how == "other format":
        meta = json.loads((folder / "map.json").read_text())
        (folder / "map.json").write_text(json.dumps({**meta, "format": "something"}))
    elif how == "newer version":
        meta = json.loads((folder / "map.json").read_text())
        (folder / "map.json").write_text(json.dumps({**meta, "version": 99}))
    elif how == "truncated keyframes":
        p = folder / "keyframes.npz"
        p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    elif how == "no landmarks":
        (folder / "landmarks.npz").unlink()
    elif how == "offsets wrong":
        with np.load(folder / "keyframes.npz") as z:
            arrays = {k: z[k] for k in z.files}
        arrays["obs_offset"] = arrays["obs_offset"][:-1]
        np.savez(folder / "keyframes.npz", **arrays)
    elif how == "wrong dtype":
        with np.load(folder / "landmarks.npz") as z:
            arrays = {k: z[k] for k in z.files}
        arrays["xyz"] = arrays["xyz"].astype(np.float32)
        np.savez(folder / "landmarks.npz", **arrays)
    elif how == "counts differ":
        meta = json.loads((folder / "map.json").read_text())
        (folder / "map.json").write_text(json.dumps({**meta, "landmarks": 7}))
    return folder


@pytest.mark.parametrize(
    "how",
    [
        "no folder",
        "no map.json",
        "map.json not json",
        "other format",
        "newer version",
        "truncated keyframes",
        "no landmarks",
        "offsets wrong",
        "wrong dtype",
        "counts differ",
    ],
)
def test_a_corrupt_map_is_one_line_naming_the_file(
    rig: StereoRig, tmp_path: Path, how: str
) -> None:
    folder = _corrupt(save_map(tmp_path / "map", _map(rig)), how)
    with pytest.raises(MapError) as e:
        load_map(folder)
    msg = str(e.value)
    assert "\n" not in msg and str(tmp_path) in msg, msg


def test_a_map_from_another_rig_is_named(rig: StereoRig) -> None:
    rec = rig_record(rig)
    other = replace(rig, cam0=replace(rig.cam0, fx=rig.cam0.fx + 1.0))
    why = rig_mismatch(rec, other)
    assert why is not None and "cam0 intrinsics" in why
    moved = np.array(rig.cam1.T_body_cam, dtype=float)
    moved[0, 3] += 0.01
    why = rig_mismatch(rec, replace(rig, cam1=replace(rig.cam1, T_body_cam=moved)))
    assert why is not None and "cam1 T_body_cam" in why
    # the IMU may be missing on either side (a stereo-only session in a stereo-inertial map)
    assert rig_mismatch(rec, replace(rig, imu=None)) is None
    # the same numbers through another camera model: a fisheye is another camera
    fisheye = replace(rig, cam0=replace(rig.cam0, distortion_model="equidistant"))
    why = rig_mismatch(rec, fisheye)
    assert why is not None and "cam0 distortion model 'radial-tangential'" in why
    # a map saved before the model was recorded: compared by the numbers alone
    del rec["cam0"]["distortion_model"]
    assert rig_mismatch(rec, rig) is None
