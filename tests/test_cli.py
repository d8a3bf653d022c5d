"""CLI behaviour a user sees: doctor exit codes and output, and reader errors mapped to one
stderr line with a non-zero exit (never a traceback), in-process and through a real process."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from asl_helpers import clean_v101_copy, read_lines, write_lines
from eurocslam.cli import main
from import_helpers import modules_loaded_by


@pytest.fixture(scope="module")
def pristine(v101_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cli") / "V1_01_clean"
    clean_v101_copy(v101_micro, root, max_frames=20)
    return root


@pytest.fixture
def seq(pristine: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "seq"
    shutil.copytree(pristine, dst, symlinks=True)
    return dst


def test_doctor_exit_codes(
    mh01_first5: Path, pristine: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["doctor", str(pristine)]) == 0
    out = capsys.readouterr()
    assert out.out.splitlines()[-1].endswith("-> exit 0 (ok)") and out.err == ""
    assert main(["doctor", str(mh01_first5)]) == 1
    out = capsys.readouterr()
    assert "WARNING mav0/imu0/data.csv: IMU ends 0.185 s before the last stereo frame" in out.out
    assert main(["doctor", str(tmp_path / "absent")]) == 2
    out = capsys.readouterr()
    assert out.out.splitlines()[1].startswith("ERROR")
    assert "Traceback" not in out.out + out.err


def test_doctor_json(mh01_first5: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["doctor", "--json", "--full", str(mh01_first5)]) == 1
    d = json.loads(capsys.readouterr().out)
    assert d["exit_code"] == 1 and d["summary"]["images_decoded"] == 10


def test_doctor_bad_options(mh01_first5: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["doctor", "--sample", "-1", str(mh01_first5)]) == 2
    assert main(["doctor", "--topic", "cam0=/left", str(mh01_first5)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and all(ln.startswith("eurocslam doctor: error:") for ln in err)


def _drop_yaml(m: Path) -> str:
    (m / "cam1" / "sensor.yaml").unlink()
    return "cam1/sensor.yaml: file not found"


def _broken_row(m: Path) -> str:
    p = m / "imu0" / "data.csv"
    lines = read_lines(p)
    lines[40] = "1403715273,1.0"
    write_lines(p, lines)
    return "imu0/data.csv:41: expected 7 columns, found 2"


def _seconds(m: Path) -> str:
    p = m / "cam0" / "data.csv"
    lines = read_lines(p)
    lines[3] = "1403715273.4121,x.png"
    write_lines(p, lines)
    return "cam0/data.csv:4: timestamp '1403715273.4121' is not an integer (looks like seconds"


def _no_mav0(m: Path) -> str:
    shutil.rmtree(m)
    return "not an EuRoC ASL sequence"


def _bad_focal(m: Path) -> str:
    p = m / "cam0" / "sensor.yaml"
    p.write_text(p.read_text().replace("intrinsics: [458.654,", "intrinsics: [0.0,"))
    return "cam0/sensor.yaml: key 'intrinsics': focal lengths must be positive"


@pytest.mark.parametrize("damage", [_drop_yaml, _broken_row, _seconds, _no_mav0, _bad_focal])
def test_reader_errors_are_one_stderr_line(
    seq: Path,
    tmp_path: Path,
    damage: Callable[[Path], str],
    capsys: pytest.CaptureFixture[str],
) -> None:
    expected = damage(seq / "mav0")
    out = tmp_path / "out.mcap"
    assert main(["convert", str(seq), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("eurocslam convert: error: ")
    assert expected in lines[0]
    assert not out.exists()
    # and the doctor reports the same sequence as broken, without raising
    assert main(["doctor", str(seq)]) == 2
    capsys.readouterr()


def test_real_process(seq: Path, tmp_path: Path) -> None:
    """The installed entry point, as a user runs it: one line on stderr, exit 2, no traceback."""
    _broken_row(seq / "mav0")
    cmd = [sys.executable, "-m", "eurocslam.cli"]
    p = subprocess.run(
        [*cmd, "convert", str(seq), "-o", str(tmp_path / "o.mcap")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 2
    assert p.stderr.count("\n") == 1 and "imu0/data.csv:41" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr


def test_no_command_prints_help(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2
    assert "doctor" in capsys.readouterr().out
    with pytest.raises(SystemExit) as ei:
        main(["--version"])
    assert ei.value.code == 0


def test_ctrl_c_while_the_commands_load_is_an_interrupt_not_a_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import eurocslam.cli as cli

    def interrupted() -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert main(["run", "x"]) == 130
    assert capsys.readouterr().err == "eurocslam: interrupted\n"


def test_error_messages_are_folded_to_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Even an error whose text spans lines (e.g. a YAML parser's) prints as one stderr line."""
    import types

    import eurocslam.cli as cli
    from eurocslam.errors import DatasetError

    def run(args: object) -> int:
        raise DatasetError("x/sensor.yaml: not valid YAML:\n  in line 3\n    bad: [")

    fake = types.SimpleNamespace(NAME="fake", HELP="h", add_arguments=lambda p: None, run=run)
    monkeypatch.setattr(cli, "_commands", lambda: ([fake], {}))
    assert cli.main(["fake"]) == 2
    err = capsys.readouterr().err
    assert err == "eurocslam fake: error: x/sensor.yaml: not valid YAML: in line 3 bad: [\n"


def test_a_command_that_fails_to_import_is_reported_not_a_traceback(monkeypatch, capsys):
    """A broken install (a missing dependency) leaves the rest of the CLI working and says so."""
    from eurocslam import cli

    real = cli._commands

    def with_broken():
        mods, broken = real()
        mods = [m for m in mods if m.NAME != "synth"]
        return mods, {**broken, "synth": "ModuleNotFoundError: No module named 'scipy'"}

    monkeypatch.setattr(cli, "_commands", with_broken)
    assert cli.main(["synth", "out"]) == 3
    err = capsys.readouterr().err
    assert "eurocslam synth: unavailable" in err and "scipy" in err and "Traceback" not in err


def test_command_line_starts_without_the_heavy_modules() -> None:
    """Every command builds every command's arguments: that must not load the renderer (SciPy),
    GTSAM or OpenCV (0.3 s of each command's start-up when `synth`'s defaults loaded them)."""
    code = (
        "import contextlib\nfrom eurocslam.cli import main\n"
        "with contextlib.suppress(SystemExit):\n    main(['convert', '--help'])"
    )
    loaded = modules_loaded_by(code)
    heavy = ("scipy", "gtsam", "cv2", "rosbags", "eurocslam.synth.sequence")
    assert not sorted(m for m in loaded if m in heavy or m.split(".")[0] in heavy)
    # the package's names still resolve (loaded on first use)
    from eurocslam import synth

    assert synth.Scene.__name__ == "Scene" and callable(synth.synthesize)
    with pytest.raises(AttributeError):
        _ = synth.no_such_name  # type: ignore[attr-defined]
