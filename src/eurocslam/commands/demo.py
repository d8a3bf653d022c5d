"""`eurocslam demo`: no dataset needed. Synthesise a sequence (cached), then run the main job.

The job is a list of steps (`STEPS`), each an ordinary eurocslam command run in this process
with the arguments it would get on the command line, so the demo shows exactly what a user would
type. Today: doctor -> run -> eval.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from eurocslam.commands._args import finite_float

NAME = "demo"
HELP = "synthesise a short sequence (cached) and run the main job on it: doctor, run, eval"


@dataclass(frozen=True)
class Step:
    name: str
    what: str
    argv: Callable[[Path, Path], list[str]]  # (sequence, out) -> command line
    outputs: Callable[[Path], list[tuple[str, Path]]]  # out -> (label, path) to print
    ok_codes: tuple[int, ...] = (0,)
    headline: Callable[[Path], list[str]] | None = None  # out -> lines for the final summary


def _eval_headline(out: Path) -> list[str]:
    """ATE per trajectory from eval.json (the full report is in eval.md)."""
    try:
        data = json.loads((out / "eval" / "eval.json").read_text())
        lines = []
        for r in data["results"]:
            ate = r["ate_trans_m"]["rmse"]
            lines.append(
                f"  {r['label']:18s} ATE {100 * ate:.1f} cm RMSE (SE(3)-aligned) over "
                f"{r['reference_length_m']:.1f} m, {r['matched']}/{r['possible']} poses"
            )
        return lines
    except (OSError, ValueError, KeyError, TypeError):
        return []


STEPS: tuple[Step, ...] = (
    Step(
        "doctor",
        "check the sequence",
        lambda seq, out: ["doctor", str(seq)],
        lambda out: [],
        ok_codes=(0, 1),
    ),
    Step(
        "run",
        "stereo-inertial SLAM",
        lambda seq, out: ["run", str(seq), "-o", str(out / "run")],
        lambda out: [
            ("MCAP for Foxglove (sensor streams + estimate)", out / "run" / "run.mcap"),
            ("trajectories, map, summary", out / "run"),
        ],
    ),
    Step(
        "eval",
        "accuracy against the exact ground truth",
        lambda seq, out: [
            "eval",
            str(out / "run"),
            str(seq),
            "--plot",
            str(out / "eval"),
            "--json",
            str(out / "eval" / "eval.json"),
            "--md",
            str(out / "eval" / "eval.md"),
            "--quiet",
        ],
        lambda out: [
            ("accuracy report", out / "eval" / "eval.md"),
            ("plots", out / "eval"),
        ],
        headline=_eval_headline,
    ),
)


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "eurocslam" / "demo"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out",
        type=Path,
        default=Path("eurocslam-demo"),
        metavar="DIR",
        help="where the job's outputs go (default: ./eurocslam-demo)",
    )
    p.add_argument(
        "--duration",
        type=finite_float,
        default=30.0,
        metavar="S",
        help="length of the synthetic sequence in seconds (default 30)",
    )
    p.add_argument("--seed", type=int, default=0, help="world/motion/noise seed (default 0)")
    p.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help=f"sequence cache (default: {cache_root()})",
    )
    p.add_argument(
        "--steps",
        default=",".join(s.name for s in STEPS),
        metavar="A,B",
        help=f"steps to run after synthesis (default: {','.join(s.name for s in STEPS)})",
    )


def cached_sequence(spec, cache: Path, progress: bool | None = None) -> tuple[Path, bool]:  # type: ignore[no-untyped-def]
    """The sequence for `spec` in `cache`, synthesised unless an identical one is there.
    Returns (path, reused)."""
    from eurocslam.synth import synthesize
    from eurocslam.synth.sequence import GENERATOR_REVISION

    want = spec.to_json()
    ident = json.dumps({"spec": want, "revision": GENERATOR_REVISION}, sort_keys=True)
    key = hashlib.sha256(ident.encode()).hexdigest()[:10]
    path = cache / f"synth-{spec.duration_s:g}s-seed{spec.seed}-{key}"
    meta = path / "synth.json"
    if meta.is_file():
        try:
            have = json.loads(meta.read_text())
            if have.get("spec") == want and have.get("generator_revision") == GENERATOR_REVISION:
                return path, True
        except (OSError, ValueError):
            pass
    cache.mkdir(parents=True, exist_ok=True)
    return synthesize(spec, path, progress, overwrite=True), False


def run(args: argparse.Namespace) -> int:
    from eurocslam.cli import build_parser
    from eurocslam.errors import EurocSlamError
    from eurocslam.synth import SynthSpec

    names = [s.strip() for s in args.steps.split(",") if s.strip()]
    known = {s.name: s for s in STEPS}
    for n in names:
        if n not in known:
            raise EurocSlamError(f"--steps: unknown step '{n}' (known: {', '.join(known)})")
    if not args.duration > 0:
        raise EurocSlamError(f"--duration {args.duration:g}: must be positive")
    spec = SynthSpec(duration_s=args.duration, seed=args.seed)
    cache = args.cache if args.cache is not None else cache_root()
    t0 = time.perf_counter()
    print(f"eurocslam demo: synthetic sequence ({args.duration:g} s, seed {args.seed})", flush=True)
    seq, reused = cached_sequence(spec, cache)
    how = "reused from the cache" if reused else f"made in {time.perf_counter() - t0:.0f} s"
    print(f"  sequence: {seq}  ({how})", flush=True)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    parser = build_parser()
    printed: list[tuple[str, Path]] = [("synthetic EuRoC sequence (ASL folder)", seq)]
    headlines: list[str] = []
    for n in names:
        step = known[n]
        argv = step.argv(seq, out)
        print(f"\n== {step.name}: {step.what}\n$ eurocslam {' '.join(argv)}", flush=True)
        sub = parser.parse_args(argv)
        code = int(sub._run(sub) or 0)
        sys.stdout.flush()
        if code not in step.ok_codes:
            raise EurocSlamError(f"step '{step.name}' failed (exit {code}); see its output above")
        printed += step.outputs(out)
        if step.headline is not None:
            headlines += step.headline(out)
            print("\n".join(headlines), flush=True)
    print(f"\neurocslam demo: done in {time.perf_counter() - t0:.0f} s.")
    if headlines:
        print("\n".join(headlines))
    print("Outputs:")
    for label, path in printed:
        print(f"  {label:48s} {path}")
    return 0
