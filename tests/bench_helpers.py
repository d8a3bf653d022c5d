"""Helpers for the bench tests: a fake `eurocslam run` (fast, scriptable by sequence name) and
sequences that hold only a ground truth."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from eurocslam.eval.synthetic import smooth_trajectory
from eurocslam.trajectory_io import write_euroc_csv

# argv: SEQ OUT [--no-imu] [extra run args...]. Writes a perturbed ground truth as the run's
# trajectories; its noise follows --no-imu and the config's frontend.n_features (so configs
# differ); every call is logged in CALLS (beside the sequences). By sequence name: "broken"
# exits 3, "slow" sleeps, "dies" kills its parent (the Ray worker that runs it).
FAKE_RUN = """
import os, signal, sys, time, pathlib
import yaml
from eurocslam.eval.synthetic import perturb, random_similarity
from eurocslam.trajectory_io import read_trajectory, write_tum
seq, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
with open(seq.parent / "calls.txt", "a") as f:
    f.write(" ".join(sys.argv[1:]) + "\\n")
(out / "fake_pid").write_text(str(os.getpid()))
if "broken" in seq.name:
    print("fake run: simulated crash", file=sys.stderr)
    sys.exit(3)
if "slow" in seq.name:
    try:
        time.sleep(60)
    except KeyboardInterrupt:  # stopped as a Ctrl-C stops a run: it can clean up
        (out / "fake_interrupted").write_text("SIGINT")
        raise
if "dies" in seq.name:
    os.kill(os.getppid(), signal.SIGKILL)
    sys.exit(9)
noise = 0.05 if "--no-imu" in sys.argv else 0.01
if "--config" in sys.argv:
    cfg = yaml.safe_load(open(sys.argv[sys.argv.index("--config") + 1])) or {}
    noise *= 1000 / (cfg.get("frontend") or {}).get("n_features", 1000)
seed = int(out.name.split("_")[-1]) + 1
gt = read_trajectory(seq / "mav0/state_groundtruth_estimate0/data.csv")
write_tum(out / "trajectory_final.tum",
          perturb(gt, random_similarity(seed), step=10, noise_m=noise, seed=seed))
write_tum(out / "trajectory_online.tum",
          perturb(gt, random_similarity(seed), step=10, noise_m=2 * noise, seed=seed + 7))
"""


def gt_sequence(root: Path, name: str, seed: int) -> Path:
    """A sequence folder with only a ground truth (what the fake run and eval read)."""
    seq = root / name
    gt = smooth_trajectory(1500, 200.0, seed=seed)
    write_euroc_csv(seq / "mav0/state_groundtruth_estimate0/data.csv", gt)
    return seq


def fake_run_cmd(tmp: Path) -> str:
    script = tmp / "fake_run.py"
    script.write_text(FAKE_RUN)
    return f"{sys.executable} {script} {{seq}} {{out}} {{no_imu}}"


def calls(root: Path) -> list[str]:
    f = root / "calls.txt"
    return f.read_text().splitlines() if f.exists() else []


class StderrLines:
    """Collects a running process's stderr lines in a thread (to wait for a progress line)."""

    def __init__(self, p: subprocess.Popen[str]) -> None:
        import threading

        self.lines: list[str] = []
        self._p = p
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        assert self._p.stderr is not None
        for line in self._p.stderr:
            self.lines.append(line)

    def wait_for(self, text: str, timeout: float) -> None:
        t_end = time.monotonic() + timeout
        while not any(text in ln for ln in self.lines):
            if self._p.poll() is not None or time.monotonic() > t_end:
                raise AssertionError(f"no {text!r} in the output:\n{''.join(self.lines)}")
            time.sleep(0.05)

    def text(self) -> str:
        self._t.join(timeout=30)
        return "".join(self.lines)
