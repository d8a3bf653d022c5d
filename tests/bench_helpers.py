"""Helpers for the bench tests: a fake `eurocslam run` (fast, scriptable by sequence name) and
sequences that hold only a ground truth."""

from __future__ import annotations

import sys
from pathlib import Path

from eurocslam.eval.synthetic import smooth_trajectory
from eurocslam.io.trajectory_io import write_euroc_csv

# argv: SEQ OUT [--no-imu] [extra run args...]. Writes a perturbed ground truth as the run's
# trajectories; its noise follows --no-imu and the config's frontend.n_features (so configs
# differ); every call is logged in CALLS (beside the sequences). By sequence name: "broken"
# exits 3, "slow" sleeps, "dies" kills its parent (the Ray worker that runs it).
FAKE_RUN = """
import os, signal, sys, time, pathlib
import yaml
from eurocslam.eval.synthetic import perturb, random_similarity
from eurocslam.io.trajectory_io import read_trajectory, write_tum
seq, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
with open(seq.parent / "calls.txt", "a") as f:
    f.write(" ".join(sys.argv[1:]) + "\\n")
(out / "fake_pid").write_text(str(os.getpid()))
if "broken" in seq.name:
    print("fake run: simulated crash", file=sys.stderr)
    sys.exit(3)
if "slow" in seq.name:
    time.sleep(60)
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
