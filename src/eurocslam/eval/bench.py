"""`eurocslam bench`: `run` + `eval` over many sequences, N runs each, one results table.

Each run is a separate process (`eurocslam run SEQ -o OUT [--no-imu]` by default), so runs of
different sequences go in parallel and a crash in one run is recorded, not fatal. Each run's
`OUT/trajectory_final.tum` (and `trajectory_online.tum` when present) is evaluated against the
sequence's ground truth; the table reports the median over the successful runs beside the
published stereo-inertial numbers (GUIDE section 4).

Sequence list (YAML)::

    runs: 3                        # optional; --runs overrides
    run_args: [--no-mcap]          # optional extra arguments for every run
    sequences:
      - /data/euroc/MH_01_easy     # an EuRoC folder (name from the folder)
      - {name: V101, path: /data/euroc/V1_01_easy}
      - {name: synth_a, synth: {duration_s: 20, seed: 3}}   # eurocslam.synth.SynthSpec

Relative paths are relative to the YAML file. Synthetic sequences are generated once into
`OUT/sequences/NAME` and reused when already there. Each run leaves its outputs, `run.log`,
`eval.json` and `eval.md` in `OUT/runs/NAME/run_K`.

Run command: a template list with `{seq}`, `{out}` and `{no_imu}` (expands to `--no-imu` or to
nothing); the default is `[python, -m, eurocslam.cli, run, {seq}, -o, {out}, --no-progress,
{no_imu}]`. Tests inject a fake one.
"""

from __future__ import annotations

import json
import math
import os
import re
import shlex
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from eurocslam.errors import ConfigError, EurocSlamError, EvalError, OutputError
from eurocslam.eval.evaluate import EvalConfig, EvalResult, evaluate
from eurocslam.eval.loaders import RUN_FINAL, RUN_ONLINE, groundtruth_csv_of
from eurocslam.eval.report import markdown_report, to_json_dict, write_json, write_text
from eurocslam.io.trajectory_io import read_trajectory

# GUIDE section 4: published stereo-inertial ATE RMSE [m] after SE(3) alignment
PUBLISHED: dict[str, dict[str, float | None]] = {
    "ORB-SLAM3": {
        "MH01": 0.037,
        "MH02": 0.031,
        "MH03": 0.026,
        "MH04": 0.059,
        "MH05": 0.086,
        "V101": 0.037,
        "V102": 0.014,
        "V103": 0.023,
        "V201": 0.037,
        "V202": 0.014,
        "V203": 0.029,
    },
    "Basalt VIO": {
        "MH01": 0.07,
        "MH02": 0.06,
        "MH03": 0.07,
        "MH04": 0.13,
        "MH05": 0.11,
        "V101": 0.04,
        "V102": 0.05,
        "V103": 0.10,
        "V201": 0.04,
        "V202": 0.05,
        "V203": None,
    },
    "VINS-Fusion": {
        "MH01": 0.166,
        "MH02": 0.152,
        "MH03": 0.125,
        "MH04": 0.280,
        "MH05": 0.284,
        "V101": 0.076,
        "V102": 0.069,
        "V103": 0.114,
        "V201": 0.066,
        "V202": 0.091,
        "V203": 0.096,
    },
}
_KEY_RE = re.compile(r"(MH|V1|V2)[_-]?0?([1-5])", re.IGNORECASE)

KNOWN_KEYS = {"runs", "run_args", "sequences"}
SEQ_KEYS = {"name", "path", "synth"}


def published_key(name: str) -> str | None:
    """'MH_01_easy' -> 'MH01', 'V1_02_medium' -> 'V102'; None when not a EuRoC name."""
    m = _KEY_RE.search(name)
    return f"{m.group(1).upper()}0{m.group(2)}" if m else None


@dataclass(frozen=True)
class BenchSequence:
    name: str
    path: Path | None = None
    synth: dict[str, Any] | None = None


@dataclass(frozen=True)
class BenchPlan:
    sequences: list[BenchSequence]
    runs: int | None = None
    run_args: list[str] = field(default_factory=list)


def load_plan(path: Path | str) -> BenchPlan:
    """Read a bench YAML (see module docstring). Unknown keys are errors."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"{path}: cannot read YAML: {e}") from None
    if isinstance(data, list):
        data = {"sequences": data}
    if not isinstance(data, dict) or "sequences" not in data:
        raise ConfigError(f"{path}: expected a mapping with a 'sequences' list")
    unknown = set(data) - KNOWN_KEYS
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {sorted(unknown)} (known: {sorted(KNOWN_KEYS)})")
    seqs = []
    for i, item in enumerate(data["sequences"] or []):
        where = f"{path} (sequences[{i}])"
        if isinstance(item, str):
            p = (path.parent / item).resolve() if not Path(item).is_absolute() else Path(item)
            seqs.append(BenchSequence(p.name, p))
            continue
        if not isinstance(item, dict):
            raise ConfigError(f"{where}: expected a path or a mapping")
        bad = set(item) - SEQ_KEYS
        if bad:
            raise ConfigError(f"{where}: unknown key(s) {sorted(bad)} (known: {sorted(SEQ_KEYS)})")
        if ("path" in item) == ("synth" in item):
            raise ConfigError(f"{where}: give exactly one of 'path' or 'synth'")
        if "path" in item:
            p = Path(str(item["path"]))
            p = p if p.is_absolute() else (path.parent / p).resolve()
            seqs.append(BenchSequence(str(item.get("name") or p.name), p))
        else:
            if not isinstance(item["synth"], dict):
                raise ConfigError(f"{where}: 'synth' must be a mapping of SynthSpec fields")
            if "name" not in item:
                raise ConfigError(f"{where}: a synth sequence needs a 'name'")
            seqs.append(BenchSequence(str(item["name"]), None, dict(item["synth"])))
    if not seqs:
        raise ConfigError(f"{path}: 'sequences' is empty")
    names = [s.name for s in seqs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"{path}: duplicate sequence name(s) {sorted(dup)}")
    runs = data.get("runs")
    if runs is not None and (not isinstance(runs, int) or runs < 1):
        raise ConfigError(f"{path}: 'runs' must be a positive integer, got {runs!r}")
    run_args = data.get("run_args") or []
    if not isinstance(run_args, list):
        raise ConfigError(f"{path}: 'run_args' must be a list of strings")
    return BenchPlan(seqs, runs, [str(a) for a in run_args])


def default_run_cmd() -> list[str]:
    return [
        sys.executable,
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
    template: list[str], seq: Path, out: Path, no_imu: bool, extra: list[str]
) -> list[str]:
    cmd = []
    for c in template:
        if c == "{no_imu}":
            if no_imu:
                cmd.append("--no-imu")
            continue
        cmd.append(c.replace("{seq}", str(seq)).replace("{out}", str(out)))
    return cmd + list(extra)


@dataclass
class RunRecord:
    sequence: str
    index: int
    out_dir: Path
    returncode: int | None = None
    wall_s: float = 0.0
    error: str | None = None
    final: EvalResult | None = None
    online: EvalResult | None = None

    @property
    def ok(self) -> bool:
        return self.error is None and self.final is not None

    def to_dict(self) -> dict[str, Any]:
        def brief(r: EvalResult | None) -> dict[str, Any] | None:
            if r is None:
                return None
            return {
                "ate_trans_rmse_m": r.ate_trans.rmse,
                "ate_rot_rmse_deg": r.ate_rot.rmse,
                "rpe_delta_trans_rmse_m": r.rpe_delta_trans.rmse,
                "drift_pct": r.drift_pct,
                "matched": r.matched,
                "possible": r.possible,
                "coverage": r.coverage,
                "segments": len(r.segments),
            }

        return {
            "sequence": self.sequence,
            "run": self.index,
            "out_dir": str(self.out_dir),
            "returncode": self.returncode,
            "wall_s": self.wall_s,
            "error": self.error,
            "final": brief(self.final),
            "online": brief(self.online),
        }


def prepare_sequences(plan: BenchPlan, out_dir: Path, progress: bool | None) -> dict[str, Path]:
    """Folder of every sequence; synth sequences are generated (once) under OUT/sequences."""
    paths: dict[str, Path] = {}
    for s in plan.sequences:
        if s.path is not None:
            if not s.path.exists():
                raise ConfigError(f"sequence '{s.name}': {s.path} does not exist")
            if groundtruth_csv_of(s.path) is None:
                raise ConfigError(
                    f"sequence '{s.name}': {s.path} has no "
                    "mav0/state_groundtruth_estimate0/data.csv to evaluate against"
                )
            paths[s.name] = s.path
            continue
        from eurocslam.synth import SynthSpec, synthesize

        dest = out_dir / "sequences" / s.name
        spec_file = dest / "bench_synth_spec.json"
        try:
            spec = SynthSpec(**s.synth)  # type: ignore[arg-type]
        except TypeError as e:
            raise ConfigError(f"sequence '{s.name}': bad synth spec: {e}") from None
        want = json.dumps(s.synth, sort_keys=True)
        if not (spec_file.exists() and spec_file.read_text() == want):
            print(f"eurocslam bench: generating synthetic sequence '{s.name}'", file=sys.stderr)
            # one rendering process: the fork pool of synthesize() was seen to deadlock when
            # started from a process that already runs threads (reported); bench
            # parallelises over runs anyway
            synthesize(spec, dest, progress, workers=1, overwrite=True)
            spec_file.write_text(want)
        paths[s.name] = dest
    return paths


def _evaluate_run(rec: RunRecord, seq: Path, cfg: EvalConfig) -> None:
    gt_csv = groundtruth_csv_of(seq)
    assert gt_csv is not None
    gt = read_trajectory(gt_csv)
    final = rec.out_dir / RUN_FINAL
    if not final.exists():
        rec.error = f"run wrote no {RUN_FINAL}"
        return
    rec.final = evaluate(gt, read_trajectory(final), cfg, "final (smoothed)")
    online = rec.out_dir / RUN_ONLINE
    if online.exists():
        rec.online = evaluate(gt, read_trajectory(online), cfg, "online (causal)")
    results = [r for r in (rec.final, rec.online) if r is not None]
    write_json(rec.out_dir / "eval.json", to_json_dict(results, {"groundtruth": str(gt_csv)}))
    write_text(rec.out_dir / "eval.md", markdown_report(results))


def _one_run(
    rec: RunRecord, seq: Path, cmd: list[str], cfg: EvalConfig, timeout_s: float | None
) -> RunRecord:
    rec.out_dir.mkdir(parents=True, exist_ok=True)
    log = rec.out_dir / "run.log"
    t0 = time.perf_counter()
    try:
        with open(log, "w") as f:
            f.write("$ " + shlex.join(cmd) + "\n")
            f.flush()
            p = subprocess.run(
                cmd, stdout=f, stderr=subprocess.STDOUT, timeout=timeout_s, check=False
            )
        rec.returncode = p.returncode
    except subprocess.TimeoutExpired:
        rec.error = f"timed out after {timeout_s} s (log: {log})"
    except OSError as e:
        rec.error = f"cannot start '{cmd[0]}': {e}"
    rec.wall_s = time.perf_counter() - t0
    if rec.error is None and rec.returncode != 0:
        tail = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
        rec.error = f"exit {rec.returncode}: {tail[-1] if tail else ''} (log: {log})"
    if rec.error is None:
        try:
            _evaluate_run(rec, seq, cfg)
        except EurocSlamError as e:
            rec.error = f"eval: {e}"
    return rec


def run_bench(
    plan: BenchPlan,
    out_dir: Path | str,
    runs: int = 1,
    jobs: int | None = None,
    run_cmd: list[str] | None = None,
    no_imu: bool = False,
    cfg: EvalConfig | None = None,
    timeout_s: float | None = None,
    progress: bool | None = None,
) -> list[RunRecord]:
    """Run every sequence `runs` times (in parallel processes) and evaluate each run."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder (the output folder of bench)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{out}: cannot create the output folder: {e.strerror or e}") from None
    cfg = cfg or EvalConfig()
    template = run_cmd or default_run_cmd()
    seq_paths = prepare_sequences(plan, out, progress)
    recs: list[tuple[RunRecord, Path, list[str]]] = []
    for s in plan.sequences:
        for k in range(runs):
            d = out / "runs" / s.name / f"run_{k}"
            cmd = expand_cmd(template, seq_paths[s.name], d, no_imu, plan.run_args)
            recs.append((RunRecord(s.name, k, d), seq_paths[s.name], cmd))
    n_jobs = max(1, min(jobs or (os.cpu_count() or 1), len(recs)))
    from eurocslam.progress import bar

    done: list[RunRecord] = []
    with (
        ThreadPoolExecutor(max_workers=n_jobs) as pool,
        bar(total=len(recs), desc="bench runs", unit="run", enabled=progress) as b,
    ):
        futs = [pool.submit(_one_run, r, seq, cmd, cfg, timeout_s) for r, seq, cmd in recs]
        try:
            for fut in as_completed(futs):
                rec = fut.result()
                done.append(rec)
                b.update(1)
                ok = rec.ok and rec.final
                status = f"ATE {rec.final.ate_trans.rmse:.3f} m" if ok else rec.error
                print(
                    f"eurocslam bench: {rec.sequence} run {rec.index}: {status} "
                    f"({rec.wall_s:.1f} s)",
                    file=sys.stderr,
                )
        except KeyboardInterrupt:
            for fut in futs:  # runs not started yet never start; running ones end with Ctrl-C
                fut.cancel()
            raise BenchInterrupted(_in_plan_order(plan, runs, done), len(recs)) from None
    return _in_plan_order(plan, runs, done)


class BenchInterrupted(KeyboardInterrupt):
    """Ctrl-C during `run_bench`: carries the runs that had finished (in plan order)."""

    def __init__(self, records: list[RunRecord], planned: int) -> None:
        super().__init__(f"{len(records)} of {planned} runs finished")
        self.records = records
        self.planned = planned


def _in_plan_order(plan: BenchPlan, runs: int, records: list[RunRecord]) -> list[RunRecord]:
    order = {(s.name, k): i for i, s in enumerate(plan.sequences) for k in range(runs)}
    return sorted(records, key=lambda r: order[(r.sequence, r.index)])


def _median(vals: list[float | None]) -> float | None:
    v = [x for x in vals if x is not None and math.isfinite(x)]
    return statistics.median(v) if v else None


def summarize(plan: BenchPlan, records: list[RunRecord]) -> list[dict[str, Any]]:
    """One row per sequence: medians over successful runs and the published numbers."""
    rows = []
    for s in plan.sequences:
        rs = [r for r in records if r.sequence == s.name]
        ok = [r for r in rs if r.ok]
        key = published_key(s.name)
        rows.append(
            {
                "sequence": s.name,
                "runs": len(rs),
                "runs_ok": len(ok),
                "ate_final_m": _median([r.final.ate_trans.rmse for r in ok if r.final]),
                "ate_online_m": _median([r.online.ate_trans.rmse for r in ok if r.online]),
                "rpe_delta_m": _median([r.final.rpe_delta_trans.rmse for r in ok if r.final]),
                "drift_pct": _median([r.final.drift_pct for r in ok if r.final]),
                "coverage": _median([r.final.coverage for r in ok if r.final]),
                "wall_s": _median([r.wall_s for r in rs]),
                "errors": [r.error for r in rs if r.error],
                "published_key": key,
                "published": {m: (v.get(key) if key else None) for m, v in PUBLISHED.items()},
            }
        )
    return rows


def _f(v: float | None, d: int = 3) -> str:
    return "–" if v is None else f"{v:.{d}f}"


def markdown_table(rows: list[dict[str, Any]], cfg: EvalConfig, runs: int) -> str:
    methods = list(PUBLISHED)
    out = [
        f"ATE RMSE [m] after {cfg.align} alignment, median of {runs} run(s) per sequence "
        f"(final = smoothed, online = causal); published stereo-inertial numbers beside.",
        "",
        "| sequence | runs ok | ATE final | ATE online | RPE 1 frame [m] | drift [%] | coverage "
        "| time [s] | " + " | ".join(methods) + " |",
        "|---|---|---|---|---|---|---|---|" + "---|" * len(methods),
    ]
    for r in rows:
        pub = " | ".join(_f(r["published"][m]) for m in methods)
        cov = "–" if r["coverage"] is None else f"{100 * r['coverage']:.0f} %"
        out.append(
            f"| {r['sequence']} | {r['runs_ok']}/{r['runs']} | {_f(r['ate_final_m'])} "
            f"| {_f(r['ate_online_m'])} | {_f(r['rpe_delta_m'], 4)} | {_f(r['drift_pct'], 2)} "
            f"| {cov} | {_f(r['wall_s'], 1)} | {pub} |"
        )
    errs = [(r["sequence"], e) for r in rows for e in r["errors"]]
    if errs:
        out += ["", "Failed runs:", ""] + [f"- {s}: {e}" for s, e in errs]
    return "\n".join(out) + "\n"


def write_results(
    out_dir: Path, plan: BenchPlan, records: list[RunRecord], cfg: EvalConfig, runs: int
) -> tuple[str, dict[str, Any]]:
    rows = summarize(plan, records)
    md = "## Benchmark\n\n" + markdown_table(rows, cfg, runs)
    data = {
        "schema": "eurocslam.bench/1",
        "config": cfg.to_dict(),
        "runs_per_sequence": runs,
        "table": rows,
        "runs": [r.to_dict() for r in records],
    }
    write_text(out_dir / "bench.md", md)
    write_json(out_dir / "bench.json", data)
    return md, data


def plan_from_args(yaml_or_folders: list[Path]) -> BenchPlan:
    """A YAML file, or sequence folders given directly on the command line."""
    if len(yaml_or_folders) == 1 and yaml_or_folders[0].suffix.lower() in (".yaml", ".yml"):
        return load_plan(yaml_or_folders[0])
    seqs = []
    for p in yaml_or_folders:
        if not p.is_dir():
            raise EvalError(f"{p}: not a sequence folder (or give one .yaml sequence list)")
        seqs.append(BenchSequence(p.resolve().name, p.resolve()))
    return BenchPlan(seqs)
