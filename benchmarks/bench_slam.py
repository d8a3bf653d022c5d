#!/usr/bin/env python3
"""Accuracy, coverage, speed and memory of `eurocslam run` on semi-real replicas of EuRoC.

For each of the 11 EuRoC sequences, `eurocslam synth` renders a replica from the real ground
truth (`../shared/data/euroc/groundtruth`): real motion, rendered stereo through the real camera
model, simulated IMU (V1_01: its real IMU rows). Each replica is then run twice, stereo-inertial
and `--no-imu`, each in its own subprocess with MCAP writing (peak RSS: the run's and its
extraction workers', from its summary; `os.wait4` if it failed), and the
final trajectory is evaluated against the replica's exact ground truth: translation ATE RMSE
after SE(3) Umeyama alignment. The published numbers beside them are stereo-inertial results on
the REAL images (GUIDE section 4), for scale only: a replica is easier (no motion blur,
exposure changes are milder, no rolling shutter).

Full-length replicas of all 11 sequences take long on 2 cores: `--duration S` crops each replica
to its first S seconds (MH sequences then include the pick-up: a dynamic initialisation), and
`--cache DIR` keeps the rendered replicas between runs. The header states exactly what ran.

usage: .venv/bin/python benchmarks/bench_slam.py [--duration 20] [--sequences V1_01 MH_01]
       [--cache /tmp/eurocslam_replicas] [--no-vo] [--no-mcap] [--config FILE]
The machine is shared and noisy: real-time factors are indicative; compare within one run.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import multiprocessing
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))
GT_DIR = SHARED / "groundtruth"
V101_IMU = SHARED / "V1_01_easy_micro" / "mav0" / "imu0" / "data.csv"
EXE = REPO / ".venv" / "bin" / "eurocslam"

SEQUENCES = {
    "MH_01": "MH_01_easy",
    "MH_02": "MH_02_easy",
    "MH_03": "MH_03_medium",
    "MH_04": "MH_04_difficult",
    "MH_05": "MH_05_difficult",
    "V1_01": "V1_01_easy",
    "V1_02": "V1_02_medium",
    "V1_03": "V1_03_difficult",
    "V2_01": "V2_01_easy",
    "V2_02": "V2_02_medium",
    "V2_03": "V2_03_difficult",
}
# published stereo-inertial ATE RMSE [m] on the real sequences (GUIDE section 4)
PUBLISHED = {
    "MH_01": (0.037, 0.07, 0.166),
    "MH_02": (0.031, 0.06, 0.152),
    "MH_03": (0.026, 0.07, 0.125),
    "MH_04": (0.059, 0.13, 0.280),
    "MH_05": (0.086, 0.11, 0.284),
    "V1_01": (0.037, 0.04, 0.076),
    "V1_02": (0.014, 0.05, 0.069),
    "V1_03": (0.023, 0.10, 0.114),
    "V2_01": (0.037, 0.04, 0.066),
    "V2_02": (0.014, 0.05, 0.091),
    "V2_03": (0.029, None, 0.096),
}


def gt_file(full: str) -> Path:
    csv = GT_DIR / f"{full}.csv"
    return csv if csv.exists() else GT_DIR / f"{full}.txt"


def make_replica(
    short: str,
    cache: Path,
    duration: float | None,
    seed: int,
    blur: bool = False,
    rig: str = "euroc",
) -> Path:
    """The replica of `short` in world `seed` (rendered into `cache` once); `blur`: with motion
    blur (8 ms exposures, 5x the rendering time); `rig`: "tumvi" renders TUM-VI's stereo fisheye
    along the same motion, in the same world (`synth --rig tumvi`, a TUM-VI folder)."""
    tag = f"{short}_{'full' if duration is None else f'{duration:g}s'}_s{seed}"
    tag += "_blur" if blur else ""
    tag += f"_{rig}" if rig != "euroc" else ""
    out = cache / tag
    # one render per replica: another benchmark asking for it at the same time waits for it
    cache.mkdir(parents=True, exist_ok=True)
    with open(cache / f"{tag}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _render_once(short, out, duration, seed, blur, rig)


def _render_once(
    short: str, out: Path, duration: float | None, seed: int, blur: bool, rig: str = "euroc"
) -> Path:
    from eurocslam.synth import SynthSpec, synthesize
    from eurocslam.synth.sequence import GENERATOR_REVISION

    tag = out.name
    if (out / "mav0").is_dir():
        # a replica rendered by an older generator is stale: render it again
        try:
            revision = json.loads((out / "synth.json").read_text()).get("generator_revision")
        except (OSError, ValueError):
            revision = None
        if revision == GENERATOR_REVISION:
            return out
        print(
            f"  {tag}: cached replica has generator revision {revision}, "
            f"the generator is at {GENERATOR_REVISION}: rendering it again",
            file=sys.stderr,
            flush=True,
        )
    spec = SynthSpec(
        trajectory=gt_file(SEQUENCES[short]),
        imu=V101_IMU if short == "V1_01" and V101_IMU.exists() and rig == "euroc" else None,
        duration_s=duration,
        seed=seed,
        motion_blur=blur,
        rig=rig,
    )
    t = time.perf_counter()
    # in a child process: rendering makes this process large, and a child started later
    # inherits that high-water mark in ru_maxrss (it survives exec), spoiling the RSS column
    ctx = multiprocessing.get_context("spawn")
    proc = ctx.Process(
        target=synthesize, args=(spec, out), kwargs={"progress": False, "overwrite": True}
    )
    proc.start()
    proc.join()
    if proc.exitcode != 0:
        raise SystemExit(f"synthesising {tag} failed (exit {proc.exitcode})")
    print(f"  synth {tag}: {time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
    return out


def run_one(
    seq: Path,
    out: Path,
    no_imu: bool,
    mcap: bool,
    config: Path | None = None,
    extra_args: Sequence[str] = (),
    env: dict[str, str] | None = None,
) -> dict[str, object]:
    """`eurocslam run` in a subprocess (`env`: its environment, e.g. a PYTHONPATH with other
    code); wall time, CPU (with its reaped extraction workers), summary, peak RSS, ATE. The
    subprocess runner is the one `eurocslam bench` uses."""
    from eurocslam.eval.bench.process import last_line, run_process

    cmd = [str(EXE), "run", str(seq), "-o", str(out), "--no-progress", *extra_args]
    if config is not None:
        cmd += ["--config", str(config)]
    if no_imu:
        cmd.append("--no-imu")
    if not mcap:
        cmd.append("--no-mcap")
    with tempfile.TemporaryDirectory(prefix="bench_run_log_") as tmp:
        log = Path(tmp) / "run.log"
        p = run_process(cmd, log, env=env, header=False)
        error = last_line(log)
    rc = p.returncode
    res: dict[str, object] = {
        "rc": rc,
        "wall_s": p.wall_s,
        "cpu_s": p.cpu_s,
        "rss_mb": p.max_rss_mb,
    }
    if rc != 0:
        res["error"] = [error or "?"]
        return res
    summary = json.loads((out / "summary.json").read_text())
    res["summary"] = summary
    # the run's own peak plus its extraction workers' (separate processes, each its own VmHWM)
    if summary.get("peak_rss_mb"):
        res["rss_mb"] = summary["peak_rss_mb"]
    res["rss_mb"] += sum(m or 0.0 for m in summary.get("worker_peak_rss_mb", []))
    res["ate_final"] = ate(seq, out / "trajectory_final.tum")
    res["ate_online"] = ate(seq, out / "trajectory_online.tum")
    return res


def ate(seq: Path, est_path: Path) -> float:
    from eurocslam.eval.evaluate import EvalConfig, evaluate
    from eurocslam.eval.loaders import groundtruth_csv_of
    from eurocslam.trajectory_io import read_euroc_csv, read_tum

    gt_csv = groundtruth_csv_of(seq)  # a TUM-VI replica's is mocap0
    if gt_csv is None:
        raise SystemExit(f"{seq}: no ground truth")
    gt = read_euroc_csv(gt_csv)
    est = read_tum(est_path)
    return float(evaluate(gt, est, EvalConfig(align="se3")).ate_trans.rmse)


def imu_ratio(summary: dict[str, Any]) -> str:
    """The final batch's IMU check of the first segment: '0.31', or '4.2>1.1' re-weighted."""
    checks = summary.get("imu_check") or []
    if not checks:
        return "-"
    c = checks[0]
    if c.get("ratio") is None:  # too few factors to check
        return "n/a"
    after = c.get("ratio_after")
    return f"{c['ratio']:.2f}" if after is None else f"{c['ratio']:.1f}>{after:.1f}"


def machine_speed(seq: Path, n_images: int = 20) -> float:
    """A yardstick of the machine's speed at the moment: milliseconds of the frontend's ORB per
    image, in one thread, on the first left images of a replica (median of 3 passes). The
    machines here are shared; the same code has measured 5-6 ms and 10+ ms in different hours,
    and every real-time factor scales with it."""
    import statistics

    import cv2

    from eurocslam.dataset.images import read_image
    from eurocslam.frontend.config import FrontendConfig
    from eurocslam.frontend.features import OrbExtractor

    files = sorted((seq / "mav0" / "cam0" / "data").glob("*.png"))[:n_images]
    images = [im for im in (read_image(f) for f in files) if im is not None]
    if not images:
        return float("nan")
    orb = OrbExtractor(FrontendConfig(), images[0].shape[1], images[0].shape[0])
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        passes = []
        for _ in range(3):
            t = time.perf_counter()
            for im in images:
                orb.extract(im)
            passes.append((time.perf_counter() - t) * 1e3 / len(images))
    finally:
        cv2.setNumThreads(threads)
    return statistics.median(passes)


def fmt(v: float | None, spec: str = ".3f") -> str:
    return "-" if v is None else format(v, spec)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--duration",
        type=float,
        default=20.0,
        help="crop each replica to its first S seconds (0: full length)",
    )
    ap.add_argument("--sequences", nargs="+", choices=list(SEQUENCES), default=list(SEQUENCES))
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "eurocslam_replicas"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-vo", action="store_true", help="skip the visual-only runs")
    ap.add_argument("--no-mcap", action="store_true", help="runs without writing run.mcap")
    ap.add_argument("--config", type=Path, help="a configuration file for every run")
    ap.add_argument("--json", type=Path, help="also save every result as JSON here")
    args = ap.parse_args()
    if not GT_DIR.is_dir():
        print(f"ground truth folder not found: {GT_DIR}", file=sys.stderr)
        return 2
    duration = args.duration if args.duration > 0 else None
    args.cache.mkdir(parents=True, exist_ok=True)
    span = "full length" if duration is None else f"first {duration:g} s"
    print(
        f"# eurocslam run on semi-real replicas ({span} of each sequence, seed {args.seed}, "
        f"MCAP {'off' if args.no_mcap else 'on'}"
        + (f", config {args.config}" if args.config else "")
        + f"); replicas in {args.cache}"
    )
    rows = []
    results: dict[str, dict[str, object]] = {}
    probes: list[float] = []
    for short in args.sequences:
        seq = make_replica(short, args.cache, duration, args.seed)
        if not probes:
            probes.append(machine_speed(seq))
        with tempfile.TemporaryDirectory(prefix="bench_slam_") as tmp:
            mcap = not args.no_mcap
            vio = run_one(seq, Path(tmp) / "vio", False, mcap, args.config)
            vo = None if args.no_vo else run_one(seq, Path(tmp) / "vo", True, mcap, args.config)
        results[short] = {"vio": vio, "vo": vo}
        rows.append((short, vio, vo))
        probes.append(machine_speed(seq))
        print(
            f"  {short}: VIO {fmt(vio.get('ate_final'))} m"
            + (f", VO {fmt(vo.get('ate_final'))} m" if vo else ""),
            file=sys.stderr,
            flush=True,
        )

    hdr = (
        f"{'seq':<6}{'dur s':>6}{'VIO ATE':>9}{'online':>8}{'VO ATE':>8}{'VIO<VO':>7}"
        f"{'pose %':>8}{'resets':>7}{'init':>8}{'IMU x':>9}{'RTF':>6}{'max':>6}{'CPU/s':>6}"
        f"{'RSS MB':>8}"
        f"{'ORB3*':>7}{'Basalt*':>8}{'VINS*':>7}"
    )
    print(hdr)
    print("-" * len(hdr))
    for short, vio, vo in rows:
        s = vio.get("summary") or {}
        vo_ate = vo.get("ate_final") if vo else None
        better = (
            "-"
            if vo_ate is None or "ate_final" not in vio
            else ("yes" if vio["ate_final"] < vo_ate else "NO")
        )
        pub = PUBLISHED[short]
        if vio.get("rc") != 0:
            print(f"{short:<6} FAILED: {vio.get('error')}")
            continue
        print(
            f"{short:<6}{s.get('duration_s', 0):>6.1f}{fmt(vio['ate_final'], '.4f'):>9}"
            f"{fmt(vio['ate_online'], '.4f'):>8}{fmt(vo_ate, '.4f'):>8}{better:>7}"
            f"{100 * s.get('coverage', 0):>8.1f}{len(s.get('resets', [])):>7}"
            f" {','.join(s.get('init_modes', [])):>7}{imu_ratio(s):>9}"
            f"{s.get('realtime_factor', 0):>6.2f}"
            f"{fmt((s.get('realtime_bounds') or {}).get('cores'), '.2f'):>6}"
            f"{s.get('cpu_s', 0) / max(s.get('duration_s', 1), 1e-9):>6.2f}"
            f"{vio['rss_mb']:>8.0f}{fmt(pub[0]):>7}{fmt(pub[1], '.2f'):>8}{fmt(pub[2]):>7}"
        )
    print("ATE: translation RMSE [m] after SE(3) alignment, final trajectory (online: causal).")
    print("* published stereo-inertial results on the REAL EuRoC images (not these replicas).")
    print(
        "IMU x: the final batch's IMU residuals over the stereo residuals (chi-square per "
        "redundancy; above 2 the accelerometer is re-weighted, '>': how far)."
    )
    print(
        "RTF: data seconds per wall second (MCAP writing included); max: the RTF this CPU time "
        "allows with every core busy (the summary's bound); CPU/s: CPU seconds (all threads and "
        "worker processes) per data second; RTF 1.5 on 2 idle cores needs CPU/s below 1.33. "
        "RSS: peak memory of the run plus its extraction workers."
    )
    print(
        "machine speed (ORB ms per image, one thread; before the first run and after each "
        "sequence): " + " ".join(f"{p:.1f}" for p in probes)
    )
    # per-stage timings of the stereo-inertial runs (medians over sequences)
    stages: dict[str, list[float]] = {}
    for _, vio, _ in rows:
        for k, v in ((vio.get("summary") or {}).get("timings") or {}).items():
            stages.setdefault(k, []).append(v["median_ms"])
    if stages:
        print(
            "per-stage median ms per call (median over sequences): "
            + ", ".join(f"{k} {sorted(v)[len(v) // 2]:.1f}" for k, v in stages.items())
        )
    if args.json:
        results["machine_speed_orb_ms"] = probes  # type: ignore[assignment]
        args.json.write_text(json.dumps(results, indent=2, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
