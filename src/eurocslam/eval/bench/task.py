"""One bench run: `eurocslam run` in a subprocess, then `eval` of its trajectories.

A `RunTask` says everything a run needs and is small and picklable: the same task runs in a
thread of the bench process (`--executor local`) or on a Ray worker. `execute` runs it into a
given folder and returns a `RunRecord`: plain JSON-able fields (the run's summary figures and the
evaluation's), also written as `bench_run.json` beside the outputs so a later bench resumes.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shlex
import socket
import sys
import threading
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from eurocslam.dataset.kitti_files import is_kitti_sequence
from eurocslam.errors import ConfigError, EurocSlamError
from eurocslam.eval.bench.process import last_line, run_process
from eurocslam.eval.evaluate import EvalConfig, EvalResult, evaluate
from eurocslam.eval.kitti_gt import kitti_groundtruth
from eurocslam.eval.loaders import RUN_FINAL, RUN_ONLINE, groundtruth_csv_of
from eurocslam.eval.report import markdown_report, to_json_dict, write_json, write_text
from eurocslam.trajectory_io import read_trajectory

RECORD_FILE = "bench_run.json"  # written last: its presence means the run finished
CONFIG_FILE = "bench_config.yaml"  # the configuration the run was given
LOG_FILE = "run.log"


def default_run_cmd() -> list[str]:
    """`{python}` is the interpreter of the process that runs the task (a worker's own)."""
    return [
        "{python}",
        "-m",
        "eurocslam.cli",
        "run",
        "{seq}",
        "-o",
        "{out}",
        "--no-progress",
        "{no_imu}",
    ]


def parse_run_cmd(text: str) -> list[str]:
    cmd = shlex.split(text)
    if not any("{seq}" in c for c in cmd) or not any("{out}" in c for c in cmd):
        raise ConfigError(f"--run-cmd must contain {{seq}} and {{out}}: '{text}'")
    return cmd


def expand_cmd(
    template: list[str] | tuple[str, ...],
    seq: Path,
    out: Path,
    no_imu: bool,
    extra: list[str] | tuple[str, ...],
) -> list[str]:
    cmd = []
    for c in template:
        if c == "{no_imu}":
            if no_imu:
                cmd.append("--no-imu")
            continue
        cmd.append(
            c.replace("{python}", sys.executable)
            .replace("{seq}", str(seq))
            .replace("{out}", str(out))
        )
    return cmd + list(extra)


@dataclass(frozen=True)
class RunTask:
    """Run `index` of `sequence` with configuration `config`. The sequence is a folder
    (`seq_path`) or a synth spec rendered where the task runs (`synth`)."""

    sequence: str
    config: str
    index: int
    out_dir: Path  # in OUT; where the outputs end up
    seq_path: Path | None
    synth: dict[str, Any] | None
    config_text: str | None
    cmd_template: tuple[str, ...]
    run_args: tuple[str, ...]
    no_imu: bool
    eval_cfg: EvalConfig
    timeout_s: float | None

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.config, self.sequence, self.index)

    @property
    def label(self) -> str:
        return f"{self.sequence} {self.config} run {self.index}"

    def fingerprint(self) -> str:
        """What decides the run's result: a finished run with the same fingerprint is reused.
        The eurocslam code is part of it (a run made by other code is not this bench's)."""
        from eurocslam.eval.bench.sequences import synth_key

        what = {
            "code": package_digest()[1],
            "sequence": str(self.seq_path) if self.seq_path else synth_key(self.synth or {}),
            "config": self.config_text,
            "cmd": list(self.cmd_template),
            "run_args": list(self.run_args),
            "no_imu": self.no_imu,
            "eval": self.eval_cfg.to_dict(),
        }
        blob = json.dumps(what, sort_keys=True, default=str).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


@functools.lru_cache(maxsize=1)
def package_digest() -> tuple[str, str]:
    """(folder, hash of every .py file) of the eurocslam package this process imports: Ray
    nodes must run the same code, and a finished run is reused only when made by it."""
    import eurocslam

    root = Path(eurocslam.__file__).resolve().parent
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return str(root), h.hexdigest()[:16]


def _brief(r: EvalResult | None) -> dict[str, Any] | None:
    if r is None:
        return None
    return {
        "ate_trans_rmse_m": float(r.ate_trans.rmse),
        "ate_rot_rmse_deg": float(r.ate_rot.rmse),
        "rpe_delta_trans_rmse_m": float(r.rpe_delta_trans.rmse),
        "drift_pct": None if r.drift_pct is None else float(r.drift_pct),
        "matched": int(r.matched),
        "possible": int(r.possible),
        "coverage": float(r.coverage),
        "segments": len(r.segments),
    }


def _summary_figures(path: Path) -> dict[str, Any] | None:
    """The run's own figures from its summary.json (None when it wrote none)."""
    try:
        s = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    dur = s.get("duration_s") or 0.0
    cpu = s.get("cpu_s")
    return {
        "mode": s.get("mode"),
        "frames": s.get("frames"),
        "coverage": s.get("coverage"),
        "resets": len(s.get("resets") or []),
        "segments": s.get("segments"),
        "duration_s": dur,
        "wall_s": s.get("wall_s"),
        "realtime_factor": s.get("realtime_factor"),
        "cpu_s": cpu,
        "cpu_per_data_s": cpu / dur if cpu is not None and dur > 0 else None,
        "peak_rss_mb": s.get("peak_rss_mb"),
    }


@dataclass
class RunRecord:
    sequence: str
    index: int
    out_dir: Path
    config: str = "default"
    returncode: int | None = None
    wall_s: float = 0.0
    cpu_s: float | None = None  # the run process's (and its reaped workers') CPU time
    error: str | None = None
    final: dict[str, Any] | None = None
    online: dict[str, Any] | None = None
    summary: dict[str, Any] | None = None
    command: list[str] = field(default_factory=list)
    worker: dict[str, Any] = field(default_factory=dict)  # who ran it: executor, host, pid...
    fingerprint: str = ""
    resumed: bool = False  # taken from a previous bench in the same folder

    @property
    def ok(self) -> bool:
        return self.error is None and self.final is not None

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.config, self.sequence, self.index)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["out_dir"] = str(self.out_dir)
        d["run"] = d.pop("index")
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunRecord:
        d = dict(d)
        d["index"] = d.pop("run")
        d["out_dir"] = Path(d["out_dir"])
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


def worker_identity(executor: str) -> dict[str, Any]:
    """Where a task runs: the executor, the host and the process (a Ray worker adds its node)."""
    return {"executor": executor, "host": socket.gethostname(), "pid": os.getpid()}


def _evaluate_run(rec: RunRecord, seq: Path, cfg: EvalConfig) -> None:
    if is_kitti_sequence(seq):  # poses/NN.txt stamped by times.txt
        gt, gt_file, _ = kitti_groundtruth(seq)
    else:
        gt_csv = groundtruth_csv_of(seq)
        if gt_csv is None:
            rec.error = (
                f"{seq}: no ground truth (mav0/state_groundtruth_estimate0 or mocap0) to "
                "evaluate against"
            )
            return
        gt, gt_file = read_trajectory(gt_csv), gt_csv
    final = rec.out_dir / RUN_FINAL
    if not final.exists():
        rec.error = f"run wrote no {RUN_FINAL}"
        return
    res_final = evaluate(gt, read_trajectory(final), cfg, "final (smoothed)")
    online = rec.out_dir / RUN_ONLINE
    res_online = (
        evaluate(gt, read_trajectory(online), cfg, "online (causal)") if online.exists() else None
    )
    rec.final, rec.online = _brief(res_final), _brief(res_online)
    results = [r for r in (res_final, res_online) if r is not None]
    write_json(rec.out_dir / "eval.json", to_json_dict(results, {"groundtruth": str(gt_file)}))
    write_text(rec.out_dir / "eval.md", markdown_report(results))


def write_record(rec: RunRecord) -> None:
    write_json(rec.out_dir / RECORD_FILE, rec.to_dict())


def read_record(run_dir: Path) -> RunRecord | None:
    """The record of a finished run in `run_dir`, or None (none, unreadable, or failed)."""
    try:
        rec = RunRecord.from_dict(json.loads((run_dir / RECORD_FILE).read_text()))
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return rec


def execute(
    task: RunTask,
    seq: Path,
    out_dir: Path,
    worker: dict[str, Any],
    cancel: threading.Event | None = None,
) -> RunRecord:
    """Run the task's `eurocslam run` on `seq` into `out_dir`, evaluate it, write its record.
    A failing run is a record with an error, never an exception (Ctrl-C and cancels excepted:
    `cancel` set stops the run with a KeyboardInterrupt)."""
    rec = RunRecord(
        task.sequence,
        task.index,
        out_dir,
        task.config,
        worker=worker,
        fingerprint=task.fingerprint(),
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / RECORD_FILE).unlink(missing_ok=True)  # not finished until written again
    extra = list(task.run_args)
    if task.config_text is not None:
        (out_dir / CONFIG_FILE).write_text(task.config_text)
        extra += ["--config", str(out_dir / CONFIG_FILE)]
    cmd = expand_cmd(task.cmd_template, seq, out_dir, task.no_imu, extra)
    rec.command = cmd
    log = out_dir / LOG_FILE
    try:
        p = run_process(cmd, log, timeout_s=task.timeout_s, cancel=cancel)
    except OSError as e:
        rec.error = f"cannot start '{cmd[0]}': {e}"
        return rec
    rec.worker["run_pid"] = p.pid
    rec.returncode, rec.wall_s, rec.cpu_s = p.returncode, p.wall_s, p.cpu_s
    if p.timed_out:
        rec.error = f"timed out after {task.timeout_s} s (log: {log})"
    elif p.returncode != 0:
        rec.error = f"exit {p.returncode}: {last_line(log)} (log: {log})"
    rec.summary = _summary_figures(out_dir / "summary.json")
    if rec.error is None:
        try:
            _evaluate_run(rec, seq, task.eval_cfg)
        except EurocSlamError as e:
            rec.error = f"eval: {e}"
    if rec.ok:
        write_record(rec)
    return rec
