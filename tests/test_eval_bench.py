"""`eurocslam bench` with an injected fake run command (fast), and for real on a tiny synthetic
sequence (slow)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from eurocslam.cli import main
from eurocslam.errors import ConfigError
from eurocslam.eval.bench import load_plan, published_key
from eurocslam.eval.synthetic import smooth_trajectory
from eurocslam.io.trajectory_io import write_euroc_csv

FAKE_RUN = """
import sys, pathlib
import numpy as np
from eurocslam.eval.synthetic import perturb, random_similarity
from eurocslam.io.trajectory_io import read_trajectory, write_tum
seq, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
if "broken" in seq.name:
    print("fake run: simulated crash", file=sys.stderr)
    sys.exit(3)
gt = read_trajectory(seq / "mav0/state_groundtruth_estimate0/data.csv")
noise = 0.05 if "--no-imu" in sys.argv else 0.01
seed = int(out.name.split("_")[-1]) + 1
write_tum(out / "trajectory_final.tum",
          perturb(gt, random_similarity(seed), step=10, noise_m=noise, seed=seed))
write_tum(out / "trajectory_online.tum",
          perturb(gt, random_similarity(seed), step=10, noise_m=2 * noise, seed=seed + 7))
"""


def _sequence(root: Path, name: str, seed: int) -> Path:
    seq = root / name
    gt = smooth_trajectory(1500, 200.0, seed=seed)
    write_euroc_csv(seq / "mav0/state_groundtruth_estimate0/data.csv", gt)
    return seq


@pytest.fixture
def fake(tmp_path: Path) -> str:
    script = tmp_path / "fake_run.py"
    script.write_text(FAKE_RUN)
    return f"{sys.executable} {script} {{seq}} {{out}} {{no_imu}}"


def test_published_keys() -> None:
    assert published_key("MH_01_easy") == "MH01"
    assert published_key("V1_02_medium") == "V102"
    assert published_key("/x/V2_03_difficult") == "V203"
    assert published_key("synth_a") is None


def test_bench_with_fake_run_command(tmp_path: Path, fake: str, capsys) -> None:
    a = _sequence(tmp_path, "MH_01_easy", 1)
    b = _sequence(tmp_path, "seq_b", 2)
    out = tmp_path / "out"
    rc = main(
        ["bench", str(a), str(b), "-o", str(out), "--runs", "3", "--jobs", "3", "--run-cmd", fake]
    )
    assert rc == 0
    md = capsys.readouterr().out
    assert "| MH_01_easy | 3/3 |" in md and "| seq_b | 3/3 |" in md
    assert "0.037" in md  # ORB-SLAM3's MH01 beside ours
    data = json.loads((out / "bench.json").read_text())
    rows = {r["sequence"]: r for r in data["table"]}
    assert rows["MH_01_easy"]["published"]["ORB-SLAM3"] == 0.037
    assert rows["seq_b"]["published_key"] is None
    ates = [r["final"]["ate_trans_rmse_m"] for r in data["runs"] if r["sequence"] == "seq_b"]
    assert len(ates) == 3
    assert rows["seq_b"]["ate_final_m"] == pytest.approx(sorted(ates)[1])  # median of 3
    assert rows["seq_b"]["ate_online_m"] > rows["seq_b"]["ate_final_m"]
    assert (out / "runs/seq_b/run_2/run.log").exists()
    assert (out / "runs/seq_b/run_2/eval.md").read_text().startswith("## Trajectory evaluation")
    assert (out / "bench.md").read_text().startswith("## Benchmark")


def test_bench_yaml_no_imu_and_failed_runs(tmp_path: Path, fake: str, capsys) -> None:
    _sequence(tmp_path, "V1_01_easy", 3)
    _sequence(tmp_path, "broken_seq", 4)
    plan = tmp_path / "plan.yaml"
    plan.write_text("runs: 2\nsequences:\n  - V1_01_easy\n  - {name: broken, path: broken_seq}\n")
    out = tmp_path / "out"
    rc = main(["bench", str(plan), "-o", str(out), "--run-cmd", fake, "--no-imu"])
    assert rc == 1  # a sequence failed: reported, not fatal
    md = capsys.readouterr().out
    assert "| broken | 0/2 |" in md and "simulated crash" in md
    data = json.loads((out / "bench.json").read_text())
    v = next(r for r in data["table"] if r["sequence"] == "V1_01_easy")
    assert v["runs_ok"] == 2
    assert 0.03 < v["ate_final_m"] < 0.15  # the fake's --no-imu noise (5 cm per axis)


def test_bench_plan_errors(tmp_path: Path) -> None:
    p = tmp_path / "p.yaml"
    p.write_text("sequences:\n  - {name: a, synth: {duration_s: 2}, path: x}\n")
    with pytest.raises(ConfigError, match="exactly one"):
        load_plan(p)
    p.write_text("sequence: []\n")
    with pytest.raises(ConfigError, match="sequences"):
        load_plan(p)
    p.write_text("sequences: [a, a]\nruns: 2\n")
    with pytest.raises(ConfigError, match="duplicate"):
        load_plan(p)
    p.write_text("sequences: [a]\nruns: 0\n")
    with pytest.raises(ConfigError, match="runs"):
        load_plan(p)
    p.write_text("sequences:\n  - {name: s, synth: {duration_s: 2}}\n")
    assert load_plan(p).sequences[0].synth == {"duration_s": 2}


@pytest.mark.slow
def test_bench_real_run_on_tiny_synthetic_sequence(tmp_path: Path, capsys) -> None:
    plan = tmp_path / "plan.yaml"
    plan.write_text("sequences:\n  - {name: tiny, synth: {duration_s: 4.0, seed: 3}}\n")
    out = tmp_path / "out"
    rc = main(["bench", str(plan), "-o", str(out), "--runs", "1", "--no-mcap"])
    md = capsys.readouterr().out
    data = json.loads((out / "bench.json").read_text())
    run = data["runs"][0]
    assert rc == 0, md
    assert run["final"] is not None and run["final"]["matched"] > 20
    assert run["final"]["ate_trans_rmse_m"] < 0.5
    assert "| tiny | 1/1 |" in md
