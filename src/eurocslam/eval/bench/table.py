"""The bench's results: one row per sequence, a column group per configuration (medians over
the successful runs), the published stereo-inertial numbers beside; `bench.md` and `bench.json`
(every run kept)."""

from __future__ import annotations

import math
import re
import statistics
from pathlib import Path
from typing import Any

from eurocslam.eval.bench.plan import BenchPlan
from eurocslam.eval.bench.task import RunRecord
from eurocslam.eval.evaluate import EvalConfig
from eurocslam.eval.report import write_json, write_text

SCHEMA = "eurocslam.bench/2"

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


def published_key(name: str) -> str | None:
    """'MH_01_easy' -> 'MH01', 'V1_02_medium' -> 'V102'; None when not a EuRoC name."""
    m = _KEY_RE.search(name)
    return f"{m.group(1).upper()}0{m.group(2)}" if m else None


def _median(vals: list[Any]) -> float | None:
    v = [x for x in vals if isinstance(x, (int, float)) and math.isfinite(x)]
    return statistics.median(v) if v else None


def _fig(r: RunRecord, key: str) -> Any:
    return (r.summary or {}).get(key)


def summarize(plan: BenchPlan, records: list[RunRecord]) -> list[dict[str, Any]]:
    """One row per (sequence, configuration): medians over its successful runs."""
    rows = []
    for s in plan.sequences:
        key = published_key(s.name)
        for c in plan.config_names:
            rs = [r for r in records if r.sequence == s.name and r.config == c]
            ok = [r for r in rs if r.ok]
            fin = [r.final for r in ok if r.final]
            rows.append(
                {
                    "sequence": s.name,
                    "config": c,
                    "runs": len(rs),
                    "runs_ok": len(ok),
                    "ate_final_m": _median([f["ate_trans_rmse_m"] for f in fin]),
                    "ate_online_m": _median([r.online["ate_trans_rmse_m"] for r in ok if r.online]),
                    "rpe_delta_m": _median([f["rpe_delta_trans_rmse_m"] for f in fin]),
                    "drift_pct": _median([f["drift_pct"] for f in fin]),
                    "coverage": _median([f["coverage"] for f in fin]),
                    "resets": _median([_fig(r, "resets") for r in ok]),
                    "realtime_factor": _median([_fig(r, "realtime_factor") for r in ok]),
                    "cpu_per_data_s": _median([_fig(r, "cpu_per_data_s") for r in ok]),
                    "wall_s": _median([r.wall_s for r in rs]),
                    "errors": [f"run {r.index}: {r.error}" for r in rs if r.error],
                    "published_key": key,
                    "published": {m: (v.get(key) if key else None) for m, v in PUBLISHED.items()},
                }
            )
    return rows


def _f(v: float | None, d: int = 3) -> str:
    return "–" if v is None else f"{v:.{d}f}"


GROUP = ("runs ok", "ATE final", "ATE online", "coverage", "resets", "RTF", "CPU/s")


def _group(r: dict[str, Any]) -> list[str]:
    cov = "–" if r["coverage"] is None else f"{100 * r['coverage']:.0f} %"
    return [
        f"{r['runs_ok']}/{r['runs']}",
        _f(r["ate_final_m"]),
        _f(r["ate_online_m"]),
        cov,
        _f(r["resets"], 0 if r["resets"] is None or r["resets"] == int(r["resets"]) else 1),
        _f(r["realtime_factor"], 2),
        _f(r["cpu_per_data_s"], 2),
    ]


def markdown_table(rows: list[dict[str, Any]], cfg: EvalConfig, runs: int) -> str:
    methods = list(PUBLISHED)
    configs = list(dict.fromkeys(r["config"] for r in rows))
    sequences = list(dict.fromkeys(r["sequence"] for r in rows))
    by = {(r["sequence"], r["config"]): r for r in rows}
    many = len(configs) > 1
    head = [f"{c}: {g}" for c in configs for g in GROUP] if many else list(GROUP)
    out = [
        f"ATE RMSE [m] after {cfg.align} alignment, median of {runs} run(s) per sequence"
        + (f" and configuration ({', '.join(configs)})" if many else "")
        + " (final = smoothed, online = causal); coverage of the ground truth, resets, "
        "real-time factor and CPU seconds per data second of the runs; published "
        "stereo-inertial numbers beside.",
        "",
        "| sequence | " + " | ".join(head) + " | " + " | ".join(methods) + " |",
        "|---|" + "---|" * (len(head) + len(methods)),
    ]
    for s in sequences:
        cells = [c for cf in configs for c in _group(by[(s, cf)])]
        pub = [_f(by[(s, configs[0])]["published"][m]) for m in methods]
        out.append(f"| {s} | " + " | ".join(cells + pub) + " |")
    errs = [(r["sequence"], r["config"], e) for r in rows for e in r["errors"]]
    if errs:
        out += ["", "Failed runs:", ""] + [
            f"- {s}{f' ({c})' if many else ''}: {e}" for s, c, e in errs
        ]
    return "\n".join(out) + "\n"


def write_results(
    out_dir: Path,
    plan: BenchPlan,
    records: list[RunRecord],
    cfg: EvalConfig,
    runs: int,
    executor: dict[str, Any] | None = None,
) -> tuple[str, dict[str, Any]]:
    rows = summarize(plan, records)
    md = "## Benchmark\n\n" + markdown_table(rows, cfg, runs)
    data = {
        "schema": SCHEMA,
        "config": cfg.to_dict(),
        "executor": executor or {"name": "local"},
        "runs_per_sequence": runs,
        "configs": {c.name: {"source": c.source, "text": c.text} for c in plan.resolved_configs()},
        "table": rows,
        "runs": [r.to_dict() for r in records],
    }
    write_text(out_dir / "bench.md", md)
    write_json(out_dir / "bench.json", data)
    return md, data
