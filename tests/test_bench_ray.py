"""`eurocslam bench --executor ray` against a real Ray head started on loopback for this module
(stopped at the end, its own temp folder): the same results as local processes, the work done
by Ray workers, outputs brought back, a dying worker, the check before the start, Ctrl-C.

Needs the optional extra (`pip install -e '.[dev,ray]'`); skipped without Ray.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from bench_helpers import StderrLines, fake_run_cmd, gt_sequence

pytest.importorskip("ray")

# Ray resolves 127.0.0.1 to the machine's network address unless it is told the cluster is this
# machine alone; with this, the head, its workers and the bench talk over loopback only
LOOPBACK_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0"}


@dataclass(frozen=True)
class Head:
    address: str
    env: dict[str, str]
    logs: Path  # the head's session logs (one file per worker process)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _group(pgid: int) -> list[int]:
    """Processes of a process group (the head's: everything `ray start` started)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            pids.append(int(stat.parent.name))
    return pids


@pytest.fixture(scope="module")
def ray_head() -> Iterator[Head]:
    temp = Path(tempfile.mkdtemp(prefix="eurocslam_ray_"))  # short: Ray's socket paths
    port = _free_port()
    ray_cli = Path(sys.executable).with_name("ray")
    cmd = [str(ray_cli) if ray_cli.exists() else "ray", "start", "--head", "--block"]
    cmd += ["--node-ip-address", "127.0.0.1", "--port", str(port), "--num-cpus", "2"]
    cmd += ["--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", str(temp / "r")]
    for opt in ("--dashboard-port", "--dashboard-agent-listen-port"):
        cmd += [opt, str(_free_port())]
    env = {**os.environ, **LOOPBACK_ENV}
    log = temp / "head.log"
    with open(log, "w") as f:
        head = subprocess.Popen(
            cmd, env=env, stdout=f, stderr=subprocess.STDOUT, start_new_session=True
        )
    try:
        t_end = time.monotonic() + 90
        while "Ray runtime started" not in log.read_text():
            if head.poll() is not None or time.monotonic() > t_end:
                pytest.fail(f"ray start failed:\n{log.read_text()[-3000:]}")
            time.sleep(0.2)
        yield Head(f"127.0.0.1:{port}", env, temp / "r" / "session_latest" / "logs")
    finally:
        # the head, its workers and whatever they run are in the group `ray start` leads
        t_end = time.monotonic() + 20
        while (pids := _group(head.pid)) and time.monotonic() < t_end:
            for pid in pids:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            if head.poll() is None:
                head.wait(timeout=5)
            time.sleep(0.2)
        assert not _group(head.pid), "processes of the Ray head survived"
        shutil.rmtree(temp, ignore_errors=True)


def _bench(head: Head | None, *args: str, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "eurocslam.cli", "bench", *args]
    env = head.env if head else {**os.environ, **LOOPBACK_ENV}
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)


def _ray(head: Head, tmp: Path) -> list[str]:
    return ["--executor", "ray", "--address", head.address, "--worker-cache", str(tmp / "wc")]


def _records(out: Path) -> dict[tuple[str, str, int], dict]:
    data = json.loads((out / "bench.json").read_text())
    return {(r["config"], r["sequence"], r["run"]): r for r in data["runs"]}


def _table(out: Path) -> str:
    """bench.md without the timing columns (RTF, CPU/s), which differ from run to run."""
    md = (out / "bench.md").read_text()
    head = next(ln for ln in md.splitlines() if ln.startswith("| sequence"))
    cols = [i for i, c in enumerate(head.split("|")) if c.strip().endswith(("RTF", "CPU/s"))]
    rows = []
    for ln in md.splitlines():
        if ln.startswith("|"):
            cells = ln.split("|")
            rows.append("|".join(c for i, c in enumerate(cells) if i not in cols))
    return "\n".join(rows)


def test_ray_sweep_same_results_as_local(ray_head: Head, tmp_path: Path) -> None:
    """Two configurations over two synthetic sequences: run by local processes, then by Ray
    workers (which render the sequences from their spec); runs are deterministic, so the
    final ATEs are identical and so is the table."""
    plan = tmp_path / "plan.yaml"
    plan.write_text(
        "run_args: [--no-mcap]\n"
        "configs:\n"
        "  a: {frontend: {prefetch: false}}\n"
        "  b: {frontend: {prefetch: false, n_features: 600}}\n"
        "sequences:\n"
        "  - {name: s1, synth: {duration_s: 2.0, seed: 1}}\n"
        "  - {name: s2, synth: {duration_s: 2.0, seed: 2}}\n"
    )
    local = _bench(None, str(plan), "-o", str(tmp_path / "local"), "--jobs", "2")
    assert local.returncode == 0, local.stderr
    args = [str(plan), "-o", str(tmp_path / "ray"), "--cpus-per-run", "1"]
    ray = _bench(ray_head, *args, *_ray(ray_head, tmp_path))
    assert ray.returncode == 0, ray.stderr
    a, b = _records(tmp_path / "local"), _records(tmp_path / "ray")
    assert set(a) == set(b) and len(a) == 2 * 2
    for key in a:
        assert b[key]["final"]["ate_trans_rmse_m"] == a[key]["final"]["ate_trans_rmse_m"], key
        assert b[key]["online"]["ate_trans_rmse_m"] == a[key]["online"]["ate_trans_rmse_m"], key
        assert b[key]["summary"]["frames"] == a[key]["summary"]["frames"] > 0
    assert _table(tmp_path / "ray") == _table(tmp_path / "local")
    assert "| s1 | 1/1 |" in _table(tmp_path / "ray")
    # the work was done by this head's Ray worker processes, not by the bench process
    for r in b.values():
        w = r["worker"]
        assert w["executor"] == "ray" and w["node_ip"] == "127.0.0.1"
        assert (ray_head.logs / f"python-core-worker-{w['worker_id']}_{w['pid']}.log").exists()
    for r in a.values():
        assert r["worker"]["executor"] == "local"
    assert "Ray node 127.0.0.1" in ray.stderr
    # the workers rendered the synth sequences into their cache, not into OUT
    assert len(list((tmp_path / "wc" / "sequences").glob("s1-*/mav0"))) == 1
    assert not (tmp_path / "ray" / "sequences").exists()
    assert (tmp_path / "local" / "sequences" / "s1" / "mav0").is_dir()


def test_ray_outputs_brought_back_and_a_dying_worker(ray_head: Head, tmp_path: Path) -> None:
    gt_sequence(tmp_path, "good", 1)
    gt_sequence(tmp_path, "dies", 2)
    out = tmp_path / "out"
    args = [str(tmp_path / "good"), str(tmp_path / "dies"), "-o", str(out), "--cpus-per-run", "1"]
    args += ["--run-cmd", fake_run_cmd(tmp_path), "--ray-outputs", "fetch"]
    r = _bench(ray_head, *args, *_ray(ray_head, tmp_path))
    assert r.returncode == 1, r.stderr  # one run failed; the bench finished
    assert "outputs brought back into OUT" in r.stderr
    recs = _records(out)
    good, dead = recs[("default", "good", 0)], recs[("default", "dies", 0)]
    assert good["final"] is not None and good["error"] is None
    run = out / "runs/default/good/run_0"
    files = {p.name for p in run.iterdir()}
    assert {"run.log", "eval.md", "eval.json", "trajectory_final.tum"} <= files
    assert json.loads((run / "bench_run.json").read_text())["out_dir"] == str(run)
    assert dead["error"].startswith("the Ray worker died")
    md = (out / "bench.md").read_text()
    assert "| dies | 0/1 |" in md and "Failed runs" in md


def test_ray_checks_before_the_start(ray_head: Head, tmp_path: Path) -> None:
    plan = tmp_path / "plan.yaml"
    plan.write_text("sequences:\n  - {name: ghost, path: /no/such/euroc/MH_01_easy}\n")
    r = _bench(ray_head, str(plan), "-o", str(tmp_path / "o"), *_ray(ray_head, tmp_path))
    assert r.returncode == 2
    err = r.stderr.strip().splitlines()
    assert len(err) == 1, r.stderr
    assert re.search(
        r"Ray node 127\.0\.0\.1 \(.*\) cannot read sequence 'ghost': "
        r"/no/such/euroc/MH_01_easy does not exist: Ray workers read sequence folders at the "
        r"same path",
        err[0],
    ), err[0]
    assert not (tmp_path / "o" / "runs").exists()
    # a head that does not answer: an error at once, not ray.init's endless retry
    t = time.monotonic()
    nobody = f"127.0.0.1:{_free_port()}"
    r = _bench(None, str(plan), "-o", str(tmp_path / "o"), "--executor", "ray", "--address", nobody)
    assert r.returncode == 2 and "cannot reach the Ray head at 127.0.0.1:" in r.stderr
    assert time.monotonic() - t < 30


def test_ray_ctrl_c_cancels_and_keeps_finished(ray_head: Head, tmp_path: Path) -> None:
    gt_sequence(tmp_path, "fast", 1)
    gt_sequence(tmp_path, "slow", 2)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "eurocslam.cli", "bench", str(tmp_path / "fast")]
    cmd += [str(tmp_path / "slow"), "-o", str(out), "--cpus-per-run", "1"]
    cmd += ["--run-cmd", fake_run_cmd(tmp_path), *_ray(ray_head, tmp_path)]
    pipes = {"stdout": subprocess.DEVNULL, "stderr": subprocess.PIPE, "text": True}
    p = subprocess.Popen(cmd, env=ray_head.env, **pipes)
    err = StderrLines(p)
    err.wait_for("fast run 0: ATE", timeout=90)
    slow_pid = out / "runs/default/slow/run_0/fake_pid"
    t_end = time.monotonic() + 60
    while not slow_pid.exists():
        assert time.monotonic() < t_end
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    p.wait(timeout=60)
    assert p.returncode == 130, err.text()
    assert "cancelling 1 Ray task(s)" in err.text()
    assert "interrupted after 1 of 2 runs" in err.text()
    assert [r[1] for r in _records(out)] == ["fast"]
    pid = int(slow_pid.read_text())
    t_end = time.monotonic() + 10
    while Path(f"/proc/{pid}").exists() and time.monotonic() < t_end:
        time.sleep(0.1)
    assert not Path(f"/proc/{pid}").exists(), "the cancelled run is still running"
    # stopped by a SIGINT it could handle (Ray workers block SIGINT; the run must not inherit
    # that, or it could only be killed)
    assert (out / "runs/default/slow/run_0/fake_interrupted").exists()
