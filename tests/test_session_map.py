"""Maps across sessions (pipeline/session_map.py, `run --map`): a run saves OUT/map; a later run
localizes in it by appearance and comes out in its frame; a map it cannot use is a one-line
error before OUT is touched."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from eurocslam.cli import main
from eurocslam.dataset import open_sequence
from eurocslam.maps.store import load_map
from eurocslam.places import default_vocabulary
from eurocslam.synth import SynthSpec, synthesize
from eurocslam.trajectory import Trajectory


def _final(out: Path) -> Trajectory:
    from eurocslam.trajectory_io import read_trajectory

    return read_trajectory(out / "trajectory_final.csv")


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return synthesize(SynthSpec(duration_s=8.0, seed=1), tmp_path_factory.mktemp("s") / "seq")


@pytest.fixture(scope="module")
def first(seq: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "first"
    assert main(["run", str(seq), "-o", str(out), "--no-progress", "--no-mcap"]) == 0
    return out


@pytest.fixture(scope="module")
def second(seq: Path, first: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same flight again, started in the first run's map."""
    out = tmp_path_factory.mktemp("runs") / "second"
    args = ["run", str(seq), "-o", str(out), "--no-progress", "--no-mcap"]
    assert main([*args, "--map", str(first / "map")]) == 0
    return out


def test_a_run_saves_its_map(first: Path) -> None:
    s = json.loads((first / "summary.json").read_text())
    m = load_map(first / "map")
    assert len(m.keyframes) == s["keyframes"] > 0
    assert m.vocabulary_id == default_vocabulary().id
    assert m.mode == "stereo-inertial" and [x["name"] for x in m.sessions] == ["seq"]
    assert np.isfinite(m.landmark_xyz).all() and len(m.landmark_id) > 1000
    # every landmark a keyframe observes is in the map, and the keyframe poses are the final
    # trajectory's at the keyframes' times
    seen = np.concatenate([kf.landmark_id for kf in m.keyframes])
    assert set(seen[seen >= 0].tolist()) <= set(m.landmark_id.tolist())
    final = _final(first)
    for kf in m.keyframes[:: max(len(m.keyframes) // 5, 1)]:
        i = int(np.searchsorted(final.t_ns, kf.t_ns))
        assert final.t_ns[i] == kf.t_ns
        assert np.linalg.norm(final.p[i] - kf.T_world_body[:3, 3]) < 1e-5


def test_a_second_session_localizes_and_comes_out_in_the_maps_frame(
    first: Path, second: Path
) -> None:
    s = json.loads((second / "summary.json").read_text())
    assert s["prior_map"]["keyframes"] == len(load_map(first / "map").keyframes)
    assert 0.0 < s["prior_map"]["localized_after_s"] < 2.0
    assert [m["segment"] for m in s["places"]["merges"]] == [1]
    a, b = _final(first), _final(second)
    assert np.array_equal(a.t_ns, b.t_ns) and b.segment is None  # one frame
    # the same flight, so the same poses: in the first run's frame to millimetres
    assert np.sqrt(np.mean(np.sum((a.p - b.p) ** 2, axis=1))) < 0.003
    # the saved map is the union: both sessions' keyframes
    m = load_map(second / "map")
    assert [x["name"] for x in m.sessions] == ["seq", "seq"]
    n1 = len(load_map(first / "map").keyframes)
    assert {kf.session for kf in m.keyframes} == {0, 1} and len(m.keyframes) > n1


def test_localize_only_keeps_the_map_as_it_is(seq: Path, first: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["run", str(seq), "-o", str(out), "--no-progress", "--no-mcap", "--end", "3"]
    assert main([*args, "--map", str(first / "map"), "--localize-only"]) == 0
    assert not (out / "map").exists()
    s = json.loads((out / "summary.json").read_text())
    assert s["prior_map"]["localized_after_s"] is not None


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_a_map_from_another_rig_is_refused(
    first: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    other = synthesize(SynthSpec.tiny(seed=3), tmp_path / "other")
    cam = other / "mav0" / "cam0" / "sensor.yaml"
    cam.write_text(cam.read_text().replace("intrinsics: [458.654", "intrinsics: [460.0"))
    assert open_sequence(other).rig.cam0.fx == 460.0
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("previous")
    capsys.readouterr()
    rc = main(["run", str(other), "-o", str(out), "--no-progress", "--map", str(first / "map")])
    assert rc != 0
    line = _one_line_error(capsys)
    assert str(first / "map" / "map.json") in line and "cam0 intrinsics" in line
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]


@pytest.mark.parametrize("damage", ["missing", "truncated"])
def test_a_corrupt_map_is_refused(
    seq: Path, first: Path, tmp_path: Path, damage: str, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = shutil.copytree(first / "map", tmp_path / "map")
    kf = bad / "keyframes.npz"
    if damage == "missing":
        kf.unlink()
    else:
        kf.write_bytes(kf.read_bytes()[:1000])
    capsys.readouterr()
    rc = main(["run", str(seq), "-o", str(tmp_path / "out"), "--no-progress", "--map", str(bad)])
    assert rc != 0
    assert str(kf) in _one_line_error(capsys)
    assert not (tmp_path / "out").exists()


def test_a_map_needs_place_recognition(
    seq: Path, first: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "off.yaml"
    cfg.write_text("places:\n  enabled: false\n")
    args = ["run", str(seq), "-o", str(tmp_path / "o"), "--config", str(cfg), "--no-progress"]
    capsys.readouterr()
    assert main([*args, "--map", str(first / "map")]) != 0
    assert "places.enabled" in _one_line_error(capsys)
