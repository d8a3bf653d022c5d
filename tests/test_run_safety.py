"""A run never loses the previous run's outputs: bad input is refused before OUT is touched, and
a run that fails later leaves the previous outputs as they were (new ones are swapped in only
once complete)."""

from __future__ import annotations

import hashlib
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from eurocslam.cli import main
from eurocslam.dataset import open_sequence
from eurocslam.dataset.types import StereoFrame
from eurocslam.errors import DatasetError
from eurocslam.runner import run_slam
from eurocslam.synth import SynthSpec, synthesize


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return synthesize(SynthSpec.tiny(seed=2), tmp_path_factory.mktemp("synth") / "tiny")


@pytest.fixture(scope="module")
def finished(seq: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "out"
    assert main(["run", str(seq), "-o", str(out), "--no-progress"]) == 0
    return out


def _snapshot(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_a_bad_config_leaves_the_previous_outputs(
    seq: Path, finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _copy(finished, tmp_path / "out")
    before = _snapshot(out)
    assert "run.mcap" in before and "trajectory_final.tum" in before
    bad = tmp_path / "bad.yaml"
    bad.write_text("frontend:\n  n_featurs: 800\n")  # a typo under frontend:
    capsys.readouterr()
    rc = main(["run", str(seq), "-o", str(out), "--config", str(bad), "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "frontend.n_featurs" in err and "Traceback" not in err
    assert _snapshot(out) == before  # byte for byte, nothing added (no .partial)
    assert {p.name for p in out.iterdir()} == {Path(k).parts[0] for k in before}


@pytest.mark.parametrize(
    "content",
    [None, b"not a vocabulary", b"PK\x03\x04 truncated zip"],
    ids=["missing", "text", "truncated"],
)
def test_a_bad_vocabulary_is_one_line_and_keeps_the_previous_outputs(
    seq: Path,
    finished: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    content: bytes | None,
) -> None:
    out = _copy(finished, tmp_path / "out")
    before = _snapshot(out)
    voc = tmp_path / "voc.npz"
    if content is not None:
        voc.write_bytes(content)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(f"places:\n  vocabulary: {voc}\n")
    capsys.readouterr()
    rc = main(["run", str(seq), "-o", str(out), "--config", str(cfg), "--no-progress"])
    err = capsys.readouterr().err
    assert rc != 0
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(voc) in lines[0] and "Traceback" not in err, err
    assert _snapshot(out) == before


def test_bad_input_before_the_first_frame_creates_nothing(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "new"
    assert main(["run", str(seq), "-o", str(out), "--start", "500", "--no-progress"]) == 2
    assert "no stereo frames" in capsys.readouterr().err
    assert not out.exists()


class _Failing:
    """The sequence, with a read error after `n` frames (a disk going away, say)."""

    def __init__(self, path: Path, n: int) -> None:
        self._seq = open_sequence(path)
        self._n = n

    def __getattr__(self, name: str) -> object:
        return getattr(self._seq, name)

    def frames(self, **kw: object) -> Iterator[StereoFrame]:
        for i, fr in enumerate(self._seq.frames(**kw)):
            if i == self._n:
                raise DatasetError("cam0/data/x.png: read error")
            yield fr


def test_a_run_that_fails_midway_keeps_the_previous_outputs(
    seq: Path, finished: Path, tmp_path: Path
) -> None:
    out = _copy(finished, tmp_path / "out")
    before = _snapshot(out)
    with pytest.raises(DatasetError, match="read error"):
        run_slam(_Failing(seq, 15), out)  # type: ignore[arg-type]
    after = _snapshot(out)
    partial = after.pop("run.mcap.partial")  # what the failed run wrote, readable
    assert partial and after == before
    from mcap.reader import make_reader

    with open(out / "run.mcap.partial", "rb") as f:
        n = sum(1 for m in make_reader(f).iter_messages(topics=["/slam/pose"]))
    assert 10 <= n <= 15
    assert not (out / ".staging").exists()


def test_a_finished_run_replaces_the_previous_outputs(
    seq: Path, finished: Path, tmp_path: Path
) -> None:
    out = _copy(finished, tmp_path / "out")
    (out / "run.mcap.partial").write_bytes(b"stale")
    (out / "notes.txt").write_text("mine")  # not an output: left alone
    run_slam(open_sequence(seq), out, options=None)
    names = sorted(p.name for p in out.iterdir())
    assert "run.mcap.partial" not in names and "notes.txt" in names and ".staging" not in names
    from eurocslam.run_options import RunOptions

    run_slam(open_sequence(seq), out, options=RunOptions(mcap=False))
    assert not (out / "run.mcap").exists()  # a stale MCAP is not mistaken for this run's
    assert (out / "trajectory_final.tum").exists()
