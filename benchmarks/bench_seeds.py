#!/usr/bin/env python3
"""Accuracy and CPU of `eurocslam run` variants over several worlds of the same replicas.

A change that alters what the frontend extracts or tracks moves the final ATE of a single
replica by 10-50 % either way in one world (RESULTS.md, "How far the final ATE moves by
itself"), so one world cannot tell a cost from luck, and worlds used for tuning cannot tell a
rule from a fit (`worlds.py`: development and held-out worlds). This runs every variant on every
world of every replica, stereo-inertial and visual-only (`--modes`), and prints per mode and
replica the final ATE of each world, the means of final and online ATE and of CPU seconds per
data second, their change against the first variant; then, per variant, the gate of
`worlds.py`: over all replicas, both modes, final and online, the mean no worse and no
replica's mean worse by more than 10 %.

A variant is NAME=REV[:ARGS] as in `bench_ab.py` (`base=HEAD new=.`, `te2=.:"--config
te2.yaml"`). Replicas are rendered when their turn comes into --cache (`<SEQ>_<60s|full>_s<SEED>`,
as `bench_slam.py` names them). `--json FILE` keeps every run's figures, written after each
run: run again with the same file and the runs it holds (same code, arguments, replica, world,
mode) are taken from it, so an interrupted protocol resumes and a new variant is measured
against stored ones without running them again.

usage: .venv/bin/python benchmarks/bench_seeds.py [--set dev|heldout | --seeds 0,1,2]
       [--sequences all|MH_04,V1_03] [--modes si,vo] [--duration 60] [--mcap]
       [--rig euroc|tumvi] [--json runs.json] [--report-only] NAME=REV[:ARGS] [...]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from scipy.stats import t as student_t

from bench_ab import Variant, checked_out, parse_variant, run_once
from bench_slam import EXE, REPO, SEQUENCES, make_replica
from worlds import GATE_REPLICA_WORSE, PROTOCOL_DURATION_S, SETS

MODES = {"si": "stereo-inertial", "vo": "visual-only"}
Run = dict[str, float]


def int_list(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: comma-separated integers") from None


def sequence_list(text: str) -> list[str]:
    if text == "all":
        return list(SEQUENCES)
    names = [x.strip() for x in text.split(",") if x.strip()]
    bad = [n for n in names if n not in SEQUENCES]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"{text!r}: 'all' or some of {','.join(SEQUENCES)}")
    return names


def mode_list(text: str) -> list[str]:
    names = [x.strip() for x in text.split(",") if x.strip()]
    if not names or any(n not in MODES for n in names):
        raise argparse.ArgumentTypeError(f"{text!r}: some of {','.join(MODES)}")
    return names


def code_id(rev: str) -> str:
    """What code a revision is: its commit, or for '.' the commit plus a hash of the working
    tree's changes under src/ (tracked and untracked), so stored runs are reused only for the
    same code."""

    def git(*a: str) -> bytes:
        return subprocess.run(["git", "-C", str(REPO), *a], capture_output=True, check=True).stdout

    if rev != ".":
        try:
            return git("rev-parse", "--verify", f"{rev}^{{commit}}").decode().strip()
        except subprocess.CalledProcessError:
            raise SystemExit(f"git revision {rev!r} not found") from None
    h = hashlib.sha1(git("diff", "HEAD", "--", "src"))
    for name in sorted(git("ls-files", "--others", "--exclude-standard", "src").decode().split()):
        h.update(name.encode() + (REPO / name).read_bytes())
    return f"{git('rev-parse', 'HEAD').decode().strip()}+{h.hexdigest()[:12]}"


@dataclass(frozen=True)
class Job:
    variant: Variant
    code: str
    seq: str
    seed: int
    mode: str
    rig: str = "euroc"

    def key(self, duration: float | None, mcap: bool) -> str:
        span = "full" if duration is None else f"{duration:g}s"
        args = " ".join(self.variant.args)
        rig = f"|rig={self.rig}" if self.rig != "euroc" else ""
        return (
            f"{self.code}|{args}|{self.seq}|{span}|s{self.seed}|{self.mode}|mcap={int(mcap)}{rig}"
        )


class Store:
    """Every run's figures by `Job.key`, in a JSON file rewritten (atomically) after each run."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.runs: dict[str, Run] = {}
        if path is not None and path.exists():
            try:
                self.runs = json.loads(path.read_text())["runs"]
            except (OSError, ValueError, KeyError, TypeError) as e:
                raise SystemExit(f"{path}: not a bench_seeds.py results file ({e})") from None

    def put(self, key: str, run: Run) -> None:
        self.runs[key] = run
        if self.path is not None:
            tmp = self.path.with_name(self.path.name + ".partial")
            tmp.write_text(json.dumps({"runs": self.runs}, indent=1, sort_keys=True))
            os.replace(tmp, self.path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="+", help="NAME=REV[:ARGS]; the first is the reference")
    ap.add_argument("--set", choices=list(SETS), default="dev", help="worlds (worlds.py)")
    ap.add_argument("--seeds", type=int_list, help="these worlds instead of --set's")
    ap.add_argument("--sequences", type=sequence_list, default=list(SEQUENCES))
    ap.add_argument("--modes", type=mode_list, default=list(MODES))
    ap.add_argument(
        "--duration", type=float, default=PROTOCOL_DURATION_S, help="first S seconds (0: all)"
    )
    ap.add_argument("--mcap", action="store_true", help="write run.mcap as a default run does")
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "eurocslam_replicas"
    )
    ap.add_argument("--json", type=Path, help="keep every run here; reuse the runs it holds")
    ap.add_argument(
        "--rig",
        choices=("euroc", "tumvi"),
        default="euroc",
        help="the replicas' rig: tumvi renders TUM-VI's stereo fisheye along the same motions",
    )
    ap.add_argument("--report-only", action="store_true", help="only the runs in --json")
    args = ap.parse_args()
    variants = [parse_variant(t) for t in args.variants]
    if len({v.name for v in variants}) != len(variants):
        raise SystemExit("variant names must differ")
    seeds = args.seeds if args.seeds is not None else list(SETS[args.set])
    if not seeds:
        raise SystemExit("--seeds: at least one")
    if args.report_only and args.json is None:
        raise SystemExit("--report-only needs --json")
    if not EXE.exists():
        raise SystemExit(f"no {EXE} (set up the virtual environment: see README)")
    duration = args.duration or None
    store = Store(args.json)
    codes = {v.name: code_id(v.rev) for v in variants}
    jobs = [
        Job(v, codes[v.name], s, seed, mode, args.rig)
        for seed in seeds  # world after world: the replicas are rendered in that order
        for s in args.sequences
        for mode in args.modes
        for v in variants
    ]
    todo = [j for j in jobs if j.key(duration, args.mcap) not in store.runs]
    if todo and args.report_only:
        raise SystemExit(f"--report-only: {len(todo)} of {len(jobs)} runs are not in {args.json}")
    if todo:
        args.cache.mkdir(parents=True, exist_ok=True)
        print(
            f"  {len(jobs) - len(todo)} of {len(jobs)} runs from {args.json}, {len(todo)} to run",
            file=sys.stderr,
            flush=True,
        )
        with (
            tempfile.TemporaryDirectory(prefix="bench_seeds_") as tmp,
            checked_out([v for v in variants if any(j.variant is v for j in todo)], Path(tmp)),
        ):
            for n, j in enumerate(todo, 1):
                # rendered when its turn comes (about 1 GB per minute of data), not all first
                seq = make_replica(j.seq, args.cache, duration, j.seed, rig=j.rig)
                v = Variant(j.variant.name, j.variant.rev, [*j.variant.args], j.variant.src)
                if j.mode == "vo":
                    v.args.append("--no-imu")
                r = run_once(v, seq, Path(tmp) / f"out_{v.name}", duration, mcap=args.mcap)
                store.put(j.key(duration, args.mcap), r)
                print(
                    f"  [{n}/{len(todo)}] {j.seq} world {j.seed} {j.mode} {v.name:<10} final "
                    f"{r['ate_mm']:.2f} mm, online {r['online_mm']:.2f} mm, "
                    f"{r['cpu_per_s']:.3f} CPU s per data s",
                    file=sys.stderr,
                    flush=True,
                )
    results: dict[tuple[str, str, str], list[Run]] = {
        (j.variant.name, j.seq, j.mode): [] for j in jobs
    }
    for j in jobs:
        results[(j.variant.name, j.seq, j.mode)].append(store.runs[j.key(duration, args.mcap)])
    span = "full length" if duration is None else f"first {duration:g} s"
    world_set = args.set if args.seeds is None else "given"
    print(
        f"# eurocslam run over worlds {'/'.join(map(str, seeds))} ({world_set}), {span}, "
        f"{args.rig} rig, "
        f"{'MCAP' if args.mcap else 'no MCAP'}; variants: "
        + ", ".join(f"{v.name}={v.rev}@{codes[v.name][:12]} {' '.join(v.args)}" for v in variants)
    )
    for mode in args.modes:
        table(mode, args.sequences, variants, results)
    gate(args.modes, args.sequences, variants, results, len(seeds))
    return 0


def _mean(runs: list[Run], key: str) -> float:
    return statistics.mean(r[key] for r in runs)


def table(
    mode: str,
    sequences: list[str],
    variants: list[Variant],
    results: dict[tuple[str, str, str], list[Run]],
) -> None:
    first = variants[0].name
    print(f"\n## {MODES[mode]}: ATE mm (mean over the worlds), CPU s per data s")
    print("| replica | variant | final per world | final | change | online | change | CPU/s |")
    print("|---|---|---|---|---|---|---|---|")
    for s in sequences:
        ref = results[(first, s, mode)]
        for v in variants:
            runs = results[(v.name, s, mode)]
            fin, onl = _mean(runs, "ate_mm"), _mean(runs, "online_mm")
            d_fin = 100 * (fin / _mean(ref, "ate_mm") - 1)
            d_onl = 100 * (onl / _mean(ref, "online_mm") - 1)
            per = " / ".join(f"{r['ate_mm']:.2f}" for r in runs)
            print(
                f"| {s} | {v.name} | {per} | {fin:.2f} | {d_fin:+.1f} % | {onl:.2f} "
                f"| {d_onl:+.1f} % | {_mean(runs, 'cpu_per_s'):.3f} |"
            )
    for v in variants:
        runs = [r for s in sequences for r in results[(v.name, s, mode)]]
        print(
            f"{v.name}: mean final {_mean(runs, 'ate_mm'):.2f} mm, online "
            f"{_mean(runs, 'online_mm'):.2f} mm, CPU {_mean(runs, 'cpu_per_s'):.3f} s per data s"
            + (
                f", {sum(r.get('loops_corrected', 0) for r in runs):.0f} loops corrected online"
                if any("loops_corrected" in r for r in runs)
                else ""
            )
        )


def gate(
    modes: list[str],
    sequences: list[str],
    variants: list[Variant],
    results: dict[tuple[str, str, str], list[Run]],
    n_worlds: int,
) -> None:
    """The verdict of `worlds.py`'s rule for every variant against the first."""
    first = variants[0].name
    print(
        f"\n## Gate against {first} (mean no worse; no replica worse by > {GATE_REPLICA_WORSE:.0%})"
    )
    for v in variants[1:]:
        failures = []
        for mode in modes:
            for key, what in (("ate_mm", "final"), ("online_mm", "online")):
                mine = [_mean(results[(v.name, s, mode)], key) for s in sequences]
                ref = [_mean(results[(first, s, mode)], key) for s in sequences]
                change = statistics.mean(mine) / statistics.mean(ref) - 1
                worse = [
                    f"{s} {100 * (a / b - 1):+.0f} %"
                    for s, a, b in zip(sequences, mine, ref, strict=True)
                    if a > (1 + GATE_REPLICA_WORSE) * b
                ]
                line = (
                    f"{MODES[mode]} {what}: mean {statistics.mean(ref):.2f} -> "
                    f"{statistics.mean(mine):.2f} mm ({100 * change:+.1f} %)"
                    + (f"; worse by > 10 %: {', '.join(worse)}" if worse else "")
                )
                ok = change <= 0 and not worse
                print(f"- {v.name}: {'ok  ' if ok else 'FAIL'} {line}")
                if not ok:
                    failures.append(line)
        for mode in modes:
            for key, what in (("ate_mm", "final"), ("online_mm", "online")):
                print(
                    f"  {MODES[mode]} {what}: "
                    + paired(results, first, v.name, mode, key, sequences)
                )
        complete = len(sequences) == len(SEQUENCES) and len(modes) == len(MODES) and n_worlds >= 3
        verdict = "holds" if not failures else f"fails ({len(failures)} of {2 * len(modes)})"
        print(
            f"**{v.name}: the gate {verdict}**"
            + ("" if complete else " (not the whole protocol: 11 replicas, 3 worlds, both modes)")
        )


def paired(
    results: dict[tuple[str, str, str], list[Run]],
    first: str,
    name: str,
    mode: str,
    key: str,
    sequences: list[str],
) -> str:
    """The change as the runs measure it, with its uncertainty: the geometric mean of the paired
    ratios (same replica, same world) and its 90 % interval (Student's t over the pairs), and how
    far a replica's mean ratio over its worlds scatters by itself (the pooled spread of the
    ratios between the worlds of one replica: a ratio moves 20-50 % between worlds with no change
    of code, RESULTS.md "Held-out worlds"). A per-replica bar below that scatter fails by chance."""
    logs: list[float] = []
    spread: list[float] = []
    n_worlds = 0
    for s in sequences:
        mine, ref = results[(name, s, mode)], results[(first, s, mode)]
        r = [math.log(a[key] / b[key]) for a, b in zip(mine, ref, strict=True)]
        logs += r
        n_worlds = max(n_worlds, len(r))
        if len(r) > 1:
            spread.append(statistics.variance(r))
    if len(logs) < 2:
        return "too few runs for an interval"
    m, se = statistics.mean(logs), statistics.stdev(logs) / math.sqrt(len(logs))
    q = float(student_t.ppf(0.95, len(logs) - 1))
    line = (
        f"paired ratio x{math.exp(m):.3f} (90 %: {math.exp(m - q * se):.3f}-"
        f"{math.exp(m + q * se):.3f}, {len(logs)} pairs)"
    )
    if spread:
        sd = math.sqrt(statistics.mean(spread) / n_worlds)
        line += f"; a replica's mean over {n_worlds} worlds scatters by +-{100 * sd:.0f} % (1 sd)"
    return line


if __name__ == "__main__":
    sys.exit(main())
