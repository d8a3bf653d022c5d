"""`eurocslam bench` with an injected fake run command (fast): tables, sweeps over
configurations, resume, Ctrl-C; and for real on a tiny synthetic sequence (slow)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench_helpers import StderrLines, calls, fake_run_cmd, gt_sequence
from eurocslam.cli import main
from eurocslam.errors import ConfigError
from eurocslam.eval.bench import load_plan, published_key


@pytest.fixture
def fake(tmp_path: Path) -> str:
    return fake_run_cmd(tmp_path)


def test_published_keys() -> None:
    assert published_key("MH_01_easy") == "MH01"
    assert published_key("V1_02_medium") == "V102"
    assert published_key("/x/V2_03_difficult") == "V203"
    assert published_key("synth_a") is None


def test_bench_with_fake_run_command(tmp_path: Path, fake: str, capsys) -> None:
    a = gt_sequence(tmp_path, "MH_01_easy", 1)
    b = gt_sequence(tmp_path, "seq_b", 2)
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
    run2 = out / "runs/default/seq_b/run_2"
    assert (run2 / "run.log").exists()
    assert (run2 / "eval.md").read_text().startswith("## Trajectory evaluation")
    assert (out / "bench.md").read_text().startswith("## Benchmark")
    assert all(r["worker"]["executor"] == "local" for r in data["runs"])


def test_bench_yaml_no_imu_and_failed_runs(tmp_path: Path, fake: str, capsys) -> None:
    gt_sequence(tmp_path, "V1_01_easy", 3)
    gt_sequence(tmp_path, "broken_seq", 4)
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
    p.write_text("sequences:\n  - {name: s, synth: {duration_s: 2, trajectory: gt.csv}}\n")
    spec = load_plan(p).sequences[0].synth
    assert spec == {"duration_s": 2, "trajectory": str((tmp_path / "gt.csv").resolve())}


def _sweep_plan(tmp_path: Path) -> Path:
    gt_sequence(tmp_path, "MH_01_easy", 1)
    gt_sequence(tmp_path, "seq_b", 2)
    (tmp_path / "n500.yaml").write_text("frontend:\n  n_features: 500\n")
    plan = tmp_path / "plan.yaml"
    plan.write_text(
        "configs:\n"
        "  base: ~\n"
        "  n2000: {frontend: {n_features: 2000}}\n"
        "  n500: n500.yaml\n"
        "sequences: [MH_01_easy, seq_b]\n"
    )
    return plan


def test_sweep_of_configurations(tmp_path: Path, fake: str, capsys) -> None:
    plan = _sweep_plan(tmp_path)
    (tmp_path / "cli.yaml").write_text("frontend: {n_features: 1000}\nbackend: {lag_s: 2.0}\n")
    out = tmp_path / "out"
    argv = ["bench", str(plan), "-o", str(out), "--runs", "2", "--run-cmd", fake]
    assert main([*argv, "--config", f"cli={tmp_path / 'cli.yaml'}"]) == 0
    md = capsys.readouterr().out
    # a column group per configuration, in the order given (YAML first, then --config)
    head = next(ln for ln in md.splitlines() if ln.startswith("| sequence"))
    groups = [c.split(":")[0].strip() for c in head.split("|")[2:] if ":" in c]
    assert list(dict.fromkeys(groups)) == ["base", "n2000", "n500", "cli"]
    for g in ("ATE final", "ATE online", "coverage", "resets", "RTF", "CPU/s"):
        assert f"| n500: {g} |" in head
    data = json.loads((out / "bench.json").read_text())
    assert len(data["runs"]) == 2 * 4 * 2  # sequences x configurations x runs, every run kept
    assert set(data["configs"]) == {"base", "n2000", "n500", "cli"}
    rows = {(r["sequence"], r["config"]): r for r in data["table"]}
    # the fake's noise scales with 1000 / n_features: each run got its own configuration
    ate = {c: rows[("seq_b", c)]["ate_final_m"] for c in ("base", "n2000", "n500", "cli")}
    assert ate["n500"] > 1.5 * ate["base"] and ate["base"] > 1.5 * ate["n2000"]
    assert ate["cli"] == pytest.approx(ate["base"])
    given = (out / "runs/n2000/seq_b/run_1/bench_config.yaml").read_text()
    assert "n_features: 2000" in given
    assert not (out / "runs/base/seq_b/run_1/bench_config.yaml").exists()  # no --config
    # base runs get no --config at all: today's command line
    assert sum("--config" not in c for c in calls(tmp_path)) == 2 * 2


def test_sweep_config_errors(tmp_path: Path, fake: str, capsys) -> None:
    plan = _sweep_plan(tmp_path)
    text = plan.read_text()
    plan.write_text(text.replace("n_features: 2000", "n_feature: 2000"))
    assert main(["bench", str(plan), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert str(plan) in err and "configs.n2000" in err and "n_feature" in err
    assert len(err.splitlines()) == 1
    plan.write_text(text.replace("lag", "x").replace("n2000: {frontend", "n2000: {backend"))
    assert main(["bench", str(plan), "-o", str(tmp_path / "o")]) == 2
    assert "backend.n_features" in capsys.readouterr().err
    plan.write_text(text)
    argv = ["bench", str(plan), "-o", str(tmp_path / "o"), "--run-cmd", fake]
    assert main([*argv, "--config", f"base={tmp_path / 'n500.yaml'}"]) == 2
    assert "'base'] given twice" in capsys.readouterr().err
    assert main([*argv, "--config", "x=/no/such.yaml"]) == 2
    assert "config file /no/such.yaml not found" in capsys.readouterr().err
    assert main([*argv, "--config", f"a/b={tmp_path / 'n500.yaml'}"]) == 2
    assert "configuration name 'a/b'" in capsys.readouterr().err
    assert main([*argv, "--address", "h:1"]) == 2
    assert "--address is an option of --executor ray" in capsys.readouterr().err
    assert main([*argv, "--executor", "ray", "--jobs", "2"]) == 2
    assert "--jobs is an option of --executor local" in capsys.readouterr().err
    assert not (tmp_path / "o" / "runs").exists()  # nothing ran


def test_resume_keeps_finished_runs(tmp_path: Path, fake: str, capsys) -> None:
    plan = _sweep_plan(tmp_path)
    gt_sequence(tmp_path, "broken_seq", 5)
    plan.write_text(plan.read_text().replace("seq_b]", "seq_b, broken_seq]"))
    out = tmp_path / "out"
    argv = ["bench", str(plan), "-o", str(out), "--run-cmd", fake]
    assert main(argv) == 1  # broken_seq fails
    first = json.loads((out / "bench.json").read_text())
    assert len(calls(tmp_path)) == 9
    # again: the finished runs are kept, the failed ones run again
    assert main(argv) == 1
    assert "resuming: 6 of 9 runs" in capsys.readouterr().err
    assert len(calls(tmp_path)) == 9 + 3
    again = json.loads((out / "bench.json").read_text())
    assert [r["final"] for r in again["runs"]] == [r["final"] for r in first["runs"]]
    assert sum(r["resumed"] for r in again["runs"]) == 6
    # a configuration that changed runs again; the others are kept
    plan.write_text(plan.read_text().replace("n_features: 2000", "n_features: 3000"))
    assert main(argv) == 1
    assert "made with other settings" in capsys.readouterr().err
    new = calls(tmp_path)[12:]
    assert len(new) == 3 + 2  # n2000's three runs, base's and n500's broken_seq runs
    assert sum("broken_seq" in c for c in new) == 3
    # --force runs everything
    assert main([*argv, "--force"]) == 1
    assert len(calls(tmp_path)) == 12 + 5 + 9


def test_ctrl_c_stops_running_runs_and_keeps_finished(tmp_path: Path, fake: str) -> None:
    """A real SIGINT to the bench alone (as when its runs are not in the terminal's process
    group): the running run is stopped, the bench writes what finished and exits 130."""
    gt_sequence(tmp_path, "fast", 1)
    gt_sequence(tmp_path, "slow", 2)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "eurocslam.cli", "bench", str(tmp_path / "fast")]
    cmd += [str(tmp_path / "slow"), "-o", str(out), "--jobs", "2", "--run-cmd", fake]
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = StderrLines(p)
    err.wait_for("fast run 0: ATE", timeout=60)
    slow_pid = out / "runs/default/slow/run_0/fake_pid"
    t_end = time.monotonic() + 30
    while not slow_pid.exists():
        assert time.monotonic() < t_end
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    p.wait(timeout=30)
    assert p.returncode == 130, err.text()
    assert "interrupted after 1 of 2 runs" in err.text()
    data = json.loads((out / "bench.json").read_text())
    assert [r["sequence"] for r in data["runs"]] == ["fast"]
    pid = int(slow_pid.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # the slow run was stopped (and reaped), not left running
    assert (out / "runs/default/slow/run_0/fake_interrupted").exists()  # by a SIGINT


def test_a_test_s_processes_handle_sigint_when_pytest_ignores_it() -> None:
    """The Ctrl-C tests' SIGINT must reach their processes also when pytest was started with
    SIGINT ignored (a background job of a script): conftest's pytest_configure handles it, so
    a child starts with the default and Python raises KeyboardInterrupt there."""
    child = "import signal; print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
    prog = "\n".join(
        [
            "import signal, subprocess, sys",
            "signal.signal(signal.SIGINT, signal.SIG_IGN)  # as pytest in a background job",
            "def child():",
            f"    r = subprocess.run([sys.executable, '-c', {child!r}], capture_output=True)",
            "    return r.stdout.decode().strip()",
            "print(child())  # the ignored SIGINT is inherited: no KeyboardInterrupt there",
            "sys.path.insert(0, sys.argv[1])",
            "import conftest",
            "conftest.pytest_configure(None)",
            "print(child())",
        ]
    )
    r = subprocess.run(
        [sys.executable, "-c", prog, str(Path(__file__).parent)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.stdout.split() == ["False", "True"], r.stderr


def test_ray_executor_without_ray_says_how_to_install(
    tmp_path: Path, fake: str, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as if not installed
    seq = gt_sequence(tmp_path, "a", 1)
    rc = main(["bench", str(seq), "-o", str(tmp_path / "o"), "--executor", "ray"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "pip install 'eurocslam[ray]'" in err and "pip install -e '.[ray]'" in err


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
    assert run["summary"]["frames"] > 0 and run["summary"]["realtime_factor"] > 0
    assert "| tiny | 1/1 |" in md
