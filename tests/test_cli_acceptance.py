"""Bad input at the command line, found in acceptance review: each case must end in one line
naming the option/file and a non-zero exit, never an internal error, never lost output."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from eurocslam.cli import main


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["convert", "SEQ", "-o", "OUT.mcap", "--start", "nan"], "--start"),
        (["convert", "SEQ", "-o", "OUT.mcap", "--end", "inf"], "--end"),
        (["eval", "a.tum", "b.tum", "--max-diff", "nan"], "--max-diff"),
        (["eval", "a.tum", "b.tum", "--offset", "inf"], "--offset"),
        (["bench", "SEQ", "-o", "OUT", "--max-diff", "nan"], "--max-diff"),
        (["bench", "SEQ", "-o", "OUT", "--max-diff", "-0.5"], "--max-diff"),
        (["eval", "a.tum", "b.tum", "--max-diff", "-1"], "--max-diff"),
        (["bench", "SEQ", "-o", "OUT", "--timeout", "-1"], "--timeout"),
        (["bench", "SEQ", "-o", "OUT", "--timeout", "0"], "--timeout"),
        (["synth", "OUT", "--duration", "nan"], "--duration"),
        (["synth", "OUT", "--start", "-inf"], "--start"),
        (["demo", "--duration", "inf"], "--duration"),
    ],
)
def test_non_finite_numbers_are_usage_errors(
    argv: list[str], option: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert f"argument {option}" in last and "internal error" not in err


def test_finite_float_accepts_plain_numbers() -> None:
    from eurocslam.commands._args import finite_float, positive_float

    assert finite_float("-1.5") == -1.5 and finite_float("1e18") == 1e18
    assert positive_float("0.25") == 0.25
    for bad in ("x", "nan", "NaN", "inf", "-inf"):
        with pytest.raises(argparse.ArgumentTypeError):
            finite_float(bad)


def test_eval_help_shows_a_plain_percent(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    out = capsys.readouterr().out
    assert "10..50 % of the ground-truth path length" in out and "%%" not in out
    assert "[--child-frame FRAME]" in out and "CHILD_FRAME" not in out


def test_bench_output_that_cannot_be_a_folder(
    mh01_first5: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    assert main(["bench", str(mh01_first5), "-o", str(afile)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("eurocslam bench: error:") and str(afile) in err
    assert len(err.splitlines()) == 1 and afile.read_text() == "keep me"
    assert main(["bench", str(mh01_first5), "-o", str(afile / "sub")]) == 2
    assert "cannot create the output folder" in capsys.readouterr().err


def test_convert_keeps_an_existing_output(
    mh01_first5: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "o.mcap"
    out.write_bytes(b"earlier result")
    assert main(["convert", str(mh01_first5), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "already exists" in err and "--force" in err and str(out) in err
    assert out.read_bytes() == b"earlier result"
    # a bad input is named first, even when the output exists
    assert main(["convert", str(tmp_path / "nope"), "-o", str(out)]) == 2
    assert "nope: no such file" in capsys.readouterr().err
    assert main(["convert", str(mh01_first5), "-o", str(out), "--no-progress", "--force"]) == 0
    assert out.stat().st_size > 1000
    capsys.readouterr()
    # the input itself, even with --force, and a folder are refused
    assert main(["convert", str(out), "-o", str(out), "--force"]) == 2
    assert "is the input" in capsys.readouterr().err
    (tmp_path / "d.mcap").mkdir()
    assert main(["convert", str(mh01_first5), "-o", str(tmp_path / "d.mcap")]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_convert_empty_time_range_message(
    mh01_first5: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "o.mcap"
    assert main(["convert", str(mh01_first5), "-o", str(out), "--start", "100"]) == 2
    err = capsys.readouterr().err
    assert "no data in the selected time range" in err and "None" not in err


def test_eval_unit_hint_names_the_ground_truth_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    est = tmp_path / "est.tum"
    gt_s = tmp_path / "gt_seconds.csv"
    lines = [f"{1.4e9 + 0.05 * k:.3f} {0.1 * k} {0.02 * k * k} 0 0 0 0 1" for k in range(20)]
    est.write_text("\n".join(lines) + "\n")
    gt_s.write_text("#timestamp,px,py,pz,qw,qx,qy,qz\n" + "\n".join(
        f"{1.4e9 + 0.05 * k:.3f},{0.1 * k},{0.02 * k * k},0,1,0,0,0" for k in range(20)
    ) + "\n")  # fmt: skip
    assert main(["eval", str(est), str(gt_s), "-q"]) == 2
    err = capsys.readouterr().err
    assert "gt_seconds.csv:" in err and "pass --gt-time-unit s" in err
    assert main(["eval", str(gt_s), str(est), "-q"]) == 2  # the same file as the estimate
    assert "pass --time-unit s" in capsys.readouterr().err


def test_shared_alignment_choices_match_the_evaluator() -> None:
    from eurocslam.commands._args import ALIGN_MODES
    from eurocslam.eval.align import ALIGN_MODES as EVAL_MODES

    assert ALIGN_MODES == EVAL_MODES


def test_convert_summary_columns_line_up_with_long_topic_names(
    mh01_first5: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "png.mcap"
    assert main(["convert", str(mh01_first5), "-o", str(out), "--images", "png"]) == 0
    lines = capsys.readouterr().out.splitlines()
    head = lines[0]
    rows = [ln for ln in lines[1:] if ln.startswith("/")]
    assert any("/cam0/image_raw/compressed" in r for r in rows)
    end = head.index("messages") + len("messages")
    for r in rows:  # the count ends under the header, the type starts under 'type'
        assert r[:end].rstrip()[-1].isdigit() and r[end] == " "
        assert r[head.index("type")] != " " and r[head.index("type") - 1] == " "


def test_trajectories_with_a_byte_order_mark(tmp_path: Path) -> None:
    """Windows editors and spreadsheets start files with a UTF-8 BOM; the ASL reader accepted it
    but TUM/EuRoC CSV trajectories failed on their first line."""
    from eurocslam.errors import EvalError
    from eurocslam.io.trajectory_io import read_trajectory

    bom = "\ufeff"
    tum_lines = [f"{1.4e9 + 0.05 * k:.2f} {0.1 * k} 0 0 0 0 0 1" for k in range(5)]
    for name, text in {
        "hdr.tum": bom + "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(tum_lines),
        "plain.tum": bom + "\n".join(tum_lines),
        "gt.csv": bom
        + "#timestamp,px,py,pz,qw,qx,qy,qz\n"
        + "\n".join(
            f"{1400000000000000000 + 50000000 * k},{0.1 * k},0,0,1,0,0,0" for k in range(5)
        ),
    }.items():
        p = tmp_path / name
        p.write_text(text, encoding="utf-8")
        t = read_trajectory(p)
        assert len(t.t_ns) == 5 and t.t_ns[0] == 1400000000000000000, name
    bad = tmp_path / "latin1.tum"
    bad.write_bytes(("\n".join(tum_lines) + "\n# caf\xe9\n").encode("latin-1"))
    with pytest.raises(EvalError, match=r"latin1.tum:6: not a text file"):
        read_trajectory(bad)


def test_bench_keeps_finished_runs_on_ctrl_c(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    import eurocslam.eval.bench.local as local
    from eurocslam.eval.bench import RunRecord

    def fake_run(task, seq, out_dir, worker, cancel):
        if task.sequence == "second":
            raise KeyboardInterrupt
        return RunRecord(task.sequence, task.index, out_dir, error="exit 1 (log: run.log)")

    monkeypatch.setattr(local, "execute", fake_run)
    for name in ("first", "second"):
        gt = tmp_path / name / "mav0" / "state_groundtruth_estimate0"
        gt.mkdir(parents=True)
        (gt / "data.csv").write_text("#timestamp,px,py,pz,qw,qx,qy,qz\n")
    out = tmp_path / "out"
    argv = ["bench", str(tmp_path / "first"), str(tmp_path / "second"), "-o", str(out)]
    assert main([*argv, "--jobs", "1"]) == 130
    err = capsys.readouterr().err
    assert "interrupted after 1 of 2 runs" in err and err.strip().endswith("interrupted")
    data = json.loads((out / "bench.json").read_text())
    assert [r["sequence"] for r in data["runs"]] == ["first"]
    assert "first" in (out / "bench.md").read_text()


def test_calib_folder_may_be_the_sequence_folder(v101_micro: Path) -> None:
    """`--calib V1_01_easy/` (the folder holding mav0/, as SEQUENCE takes it) works like
    `--calib V1_01_easy/mav0/` for convert/run/doctor on bags and for synth."""
    from eurocslam.dataset.calib import load_rig

    a, b = load_rig(v101_micro), load_rig(v101_micro / "mav0")
    assert (a.cam0.K == b.cam0.K).all() and (a.cam1.T_body_cam == b.cam1.T_body_cam).all()


def test_synth_staging_folder_is_never_someone_elses(tmp_path: Path) -> None:
    """synth stages OUT.partial: a leftover of an interrupted synth is replaced, anything else
    (a file, a folder with other content) is an error, not an internal error or a deletion."""
    from eurocslam.errors import OutputError
    from eurocslam.synth.writer import prepare_folder

    out = tmp_path / "seq"
    stage = tmp_path / "seq.partial"
    stage.write_text("a file")
    with pytest.raises(OutputError, match=r"seq.partial: exists and is not an unfinished"):
        prepare_folder(out, overwrite=False)
    stage.unlink()
    (stage / "notes").mkdir(parents=True)
    (stage / "notes" / "keep.txt").write_text("mine")
    with pytest.raises(OutputError, match="move it away"):
        prepare_folder(out, overwrite=True)
    assert (stage / "notes" / "keep.txt").read_text() == "mine"
    other = tmp_path / "other"
    (tmp_path / "other.partial" / "mav0" / "cam0").mkdir(parents=True)  # interrupted synth
    assert prepare_folder(other, overwrite=False) == tmp_path / "other.partial"
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(OutputError, match="afile: is a file"):
        prepare_folder(afile, overwrite=True)


def test_eval_error_names_both_inputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = tmp_path / "gt.tum"
    est = tmp_path / "two.tum"
    lines = [f"{1.4e9 + 0.05 * k:.2f} {0.1 * k} {0.01 * k * k} 0 0 0 0 1" for k in range(20)]
    gt.write_text("\n".join(lines) + "\n")
    est.write_text("\n".join(lines[:2]) + "\n")
    assert main(["eval", str(est), str(gt), "-q"]) == 2
    err = capsys.readouterr().err
    assert "two.tum vs " in err and "gt.tum" in err and "at least 3 matched poses" in err


def test_eval_warns_when_the_path_is_too_straight_for_se3_rotation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A 2 s take-off (nearly a straight line) with 3 mm of noise: the SE(3) fit turns the
    estimate about the line and ATE rotation reads degrees of error that are not there."""
    import numpy as np

    rng = np.random.default_rng(0)
    k = np.arange(41)
    for name, bend in (("straight", 0.01), ("curved", 1.0)):
        p = np.stack([0.03 * k, bend * np.sin(k / 10.0), np.zeros(41)], axis=1)
        noisy = p + rng.normal(0, 0.003, p.shape)
        for fname, pts in (("gt", p), ("est", noisy)):
            rows = [
                f"{1.4e9 + 0.05 * i:.2f} {x} {y} {z} 0 0 0 1" for i, (x, y, z) in enumerate(pts)
            ]
            (tmp_path / f"{name}_{fname}.tum").write_text("\n".join(rows) + "\n")
        est, gt = tmp_path / f"{name}_est.tum", tmp_path / f"{name}_gt.tum"
        assert main(["eval", str(est), str(gt), "-q"]) == 0
        err = capsys.readouterr().err
        assert ("barely leave a straight line" in err) == (name == "straight"), err
        assert main(["eval", str(est), str(gt), "-q", "--align", "posyaw"]) == 0
        assert "straight line" not in capsys.readouterr().err


def test_run_and_play_reject_non_finite_options(capsys):
    from eurocslam import cli

    with pytest.raises(SystemExit) as e:
        cli.main(["run", "SEQ", "-o", "OUT", "--start", "nan"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        cli.main(["play", "x.mcap", "--live", "--rate", "nan"])
    assert e.value.code == 2
    assert "not a finite number" in capsys.readouterr().err


def test_run_replaces_a_previous_runs_outputs(v101_micro, tmp_path, capsys):
    """A second run into the same OUT (here without MCAP) leaves no stale run.mcap behind."""
    from eurocslam import cli

    out = tmp_path / "out"
    assert cli.main(["run", str(v101_micro), "-o", str(out), "--end", "0.3", "--no-progress"]) == 0
    assert (out / "run.mcap").is_file()
    args = ["run", str(v101_micro), "-o", str(out), "--end", "0.3", "--no-mcap", "--no-progress"]
    assert cli.main(args) == 0
    assert not (out / "run.mcap").exists()
    assert (out / "trajectory_final.tum").is_file()
    assert "replacing the outputs of a previous run" in capsys.readouterr().err


def test_run_as_a_process_ends_without_teardown_and_loses_no_output(v101_micro, tmp_path):
    """`eurocslam run` as its own process ends right after the command (QUICK_EXIT: no
    interpreter teardown, so an atexit hook never runs), with everything it printed on a pipe
    and every output on disk; another command ends as usual (its atexit hook runs)."""
    import json
    import subprocess
    import sys

    script = (
        "import atexit, sys; atexit.register(lambda: print('TEARDOWN', file=sys.stderr)); "
        "from eurocslam.cli import main; sys.argv = ['eurocslam', *sys.argv[1:]]; "
        "sys.exit(main())"
    )
    out = tmp_path / "out"
    run = [str(v101_micro), "-o", str(out), "--end", "0.5", "--no-progress"]
    r = subprocess.run(
        [sys.executable, "-c", script, "run", *run], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr
    assert "TEARDOWN" not in r.stderr
    assert r.stdout.rstrip().endswith(f"outputs in {out}")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] > 0
    for name in ("run.mcap", "trajectory_final.tum", "trajectory_online.csv", "map.ply", "map"):
        assert (out / name).exists(), name
    missing = str(tmp_path / "missing.tum")
    r = subprocess.run(
        [sys.executable, "-c", script, "eval", missing, missing],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0 and "error" in r.stderr
    assert "TEARDOWN" in r.stderr
