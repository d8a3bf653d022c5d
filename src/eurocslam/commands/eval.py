"""`eurocslam eval`: ATE/RPE of an estimate against ground truth, with reports and plots."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from eurocslam.commands._args import add_alignment_arguments, finite_float

if TYPE_CHECKING:
    from eurocslam.eval.evaluate import EvalConfig, EvalResult
    from eurocslam.eval.loaders import Loaded

NAME = "eval"
HELP = "ATE/RPE of an estimate (TUM, EuRoC CSV, run folder, MCAP) against ground truth"

EPILOG = """\
examples:
  eurocslam eval OUT/ MH_01_easy/                  final and online trajectories of a run
  eurocslam eval est.tum gt/data.csv --align posyaw --plot plots/ --json eval.json
  eurocslam eval run.mcap                          /slam/pose against /groundtruth/pose
  eurocslam eval bag.mcap gt.tum --topic /tf --child-frame base_link
  eurocslam eval OUT/ kitti/poses/00.txt --align sim3   KITTI poses, stamped by times.txt
  eurocslam eval OUT1/ MH_01/ --session OUT2/ MH_02/  two sessions, one alignment (one frame)

The headline is ATE translation RMSE after SE(3) Umeyama alignment over the whole trajectory.
RPE: per frame (evo's delta 1 frame) and over 10..50 % of the ground-truth path length (rpg).
--session adds sessions whose ground truths share the first one's frame (flights of one place):
one alignment over all of them gives the joint ATE (meaningful when the estimates claim one
frame, as a run reusing a map does), beside each session evaluated on its own.
TUM time is seconds, EuRoC CSV time is nanoseconds; mix-ups are detected from the magnitudes.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = EPILOG
    p.add_argument("estimate", type=Path, help="TUM / EuRoC CSV file, run output folder, or MCAP")
    p.add_argument(
        "groundtruth",
        type=Path,
        nargs="?",
        help="EuRoC sequence folder, state_groundtruth_estimate0/data.csv, TUM, MCAP, or KITTI "
        "poses/NN.txt or sequences/NN (default: /groundtruth/pose of the estimate's MCAP)",
    )
    p.add_argument(
        "--session",
        nargs="+",
        action="append",
        metavar=("EST", "GT"),
        help="another session: its estimate EST and ground truth GT (optional, as for the "
        "positional pair), evaluated jointly with the others under one alignment; repeatable",
    )
    p.add_argument(
        "--topic", metavar="TOPIC", help="estimate topic in an MCAP (default /slam/pose)"
    )
    p.add_argument(
        "--child-frame", metavar="FRAME", help="child frame of the estimate when --topic is tf"
    )
    p.add_argument(
        "--gt-topic",
        metavar="TOPIC",
        help="ground-truth topic in an MCAP (default /groundtruth/pose)",
    )
    p.add_argument(
        "--gt-child-frame", metavar="FRAME", help="child frame of the ground truth when it is tf"
    )
    p.add_argument(
        "--which",
        choices=("final", "online", "both"),
        default="both",
        help="for a run folder: final (smoothed), online (causal) or both (default)",
    )
    add_alignment_arguments(
        p, "alignment: se3 Umeyama (default), sim3, posyaw (4-DoF), origin (first pose), none"
    )
    p.add_argument(
        "--align-first",
        type=int,
        metavar="N",
        help="fit the alignment on the first N matched poses only",
    )
    p.add_argument(
        "--offset",
        type=finite_float,
        default=0.0,
        metavar="S",
        help="time offset added to the estimate's stamps [s]",
    )
    p.add_argument(
        "--delta", type=int, default=1, metavar="N", help="RPE delta in frames (default 1)"
    )
    p.add_argument(
        "--rpe-fractions",
        default="0.1,0.2,0.3,0.4,0.5",
        metavar="F,..",
        help="RPE sub-trajectory lengths as fractions of the GT path length",
    )
    p.add_argument(
        "--rpe-lengths",
        metavar="M,..",
        help="RPE sub-trajectory lengths in metres (overrides --rpe-fractions)",
    )
    p.add_argument(
        "--time-unit",
        choices=("auto", "s", "ns"),
        default="auto",
        help="time unit of the estimate file (auto: TUM s, EuRoC CSV ns)",
    )
    p.add_argument(
        "--gt-time-unit",
        choices=("auto", "s", "ns"),
        default="auto",
        help="time unit of the ground-truth file",
    )
    p.add_argument("--json", type=Path, metavar="PATH", help="write the results as JSON")
    p.add_argument("--md", type=Path, metavar="PATH", help="write the Markdown report")
    p.add_argument("--plot", type=Path, metavar="DIR", help="write PNG plots into DIR")
    p.add_argument("-q", "--quiet", action="store_true", help="do not print the report")


def _floats(text: str, what: str) -> tuple[float, ...]:
    from eurocslam.errors import EvalError

    try:
        vals = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise EvalError(f"{what}: expected comma-separated numbers, got '{text}'") from None
    if not vals or any(v <= 0 for v in vals):
        raise EvalError(f"{what}: values must be > 0, got '{text}'")
    return vals


def run(args: argparse.Namespace) -> int:
    from eurocslam.errors import EvalError
    from eurocslam.eval.evaluate import EvalConfig, evaluate
    from eurocslam.eval.loaders import (
        groundtruth_from_estimate_source,
        load_estimates,
        load_groundtruth,
    )
    from eurocslam.eval.report import markdown_report, to_json_dict, write_json, write_text

    if args.delta < 1:
        raise EvalError(f"--delta must be >= 1 frame, got {args.delta}")
    if (
        args.align_first is not None
        and args.align_first < 3
        and args.align not in ("origin", "none")
    ):
        raise EvalError(f"--align-first must be >= 3 for {args.align}, got {args.align_first}")
    cfg = EvalConfig(
        align=args.align,
        align_first=args.align_first,
        max_diff_s=args.max_diff,
        offset_s=args.offset,
        rpe_delta=args.delta,
        rpe_fractions=_floats(args.rpe_fractions, "--rpe-fractions"),
        rpe_lengths_m=_floats(args.rpe_lengths, "--rpe-lengths") if args.rpe_lengths else None,
    )
    if args.session:
        return _run_joint(args, cfg)
    estimates = load_estimates(
        args.estimate, args.topic, args.child_frame, args.time_unit, args.which
    )
    gt_path = args.groundtruth or groundtruth_from_estimate_source(args.estimate)
    if gt_path is None:
        raise EvalError(
            f"{args.estimate}: no ground truth given and none found in it (pass a sequence "
            "folder, data.csv, TUM file or MCAP with /groundtruth/pose)"
        )
    gt = load_groundtruth(gt_path, args.gt_topic, args.gt_child_frame, args.gt_time_unit)
    for note in dict.fromkeys([*gt.notes, *(n for e in estimates for n in e.notes)]):
        print(f"eurocslam eval: note: {note}", file=sys.stderr)

    results = [evaluate(gt.traj, e.traj, cfg, e.label) for e in estimates]
    report = markdown_report(results)
    if not args.quiet:
        print(report)
    if args.md:
        write_text(args.md, report)
    if args.json:
        write_json(args.json, to_json_dict(results, {"groundtruth": gt.source}))
    if args.plot:
        from eurocslam.eval.plots import plot_result, prefix_for

        written = []
        for r in results:
            written += plot_result(r, args.plot, prefix_for(r.label))
        print(f"eurocslam eval: wrote {len(written)} plots to {args.plot}", file=sys.stderr)
    _warn(results)
    return 0


def _warn(results: list[EvalResult]) -> None:
    """Warnings about results: uncertain alignment rotation, skipped segments."""
    from eurocslam.eval.align import UNCERTAIN_ROTATION_FIT_DEG

    for r in results:
        for seg in r.segments if r.config.align in ("se3", "sim3") else ():
            sigma = seg.rotation_fit_sigma_deg()
            # (a fit that took a rotation from the orientations says so in the report)
            if sigma > UNCERTAIN_ROTATION_FIT_DEG and not seg.alignment.note:
                print(
                    f"eurocslam eval: warning: {r.label}, segment {seg.segment}: the matched "
                    f"positions barely leave a straight line, so the {r.config.align} fit's "
                    f"rotation about it is uncertain (~{sigma:.1f} deg); ATE rotation is not "
                    "meaningful, ATE translation is (a turn about the line moves the positions "
                    "only within their lateral spread; --align posyaw keeps gravity)",
                    file=sys.stderr,
                )
        for sid, why in r.skipped:
            print(f"eurocslam eval: warning: segment {sid} skipped: {why}", file=sys.stderr)


def _session_inputs(args: argparse.Namespace) -> list[tuple[Path, Path | None]]:
    """(estimate, ground truth or None) of every session: the positional ones, then --session."""
    from eurocslam.errors import EvalError

    out: list[tuple[Path, Path | None]] = [(args.estimate, args.groundtruth)]
    for vals in args.session:
        if len(vals) > 2:
            raise EvalError(f"--session {' '.join(vals)}: expected EST [GT], got {len(vals)} paths")
        out.append((Path(vals[0]), Path(vals[1]) if len(vals) == 2 else None))
    return out


def _pair_estimates(per_session: list[list[Loaded]]) -> list[tuple[str, list[Loaded]]]:
    """Estimates of the same kind across sessions: (label, one per session). Sessions with one
    estimate each pair as they are; run folders pair final with final, online with online."""
    from eurocslam.errors import EvalError

    if all(len(x) == 1 for x in per_session):
        labels = {x[0].label for x in per_session}
        label = per_session[0][0].label if len(labels) == 1 else "estimate"
        return [(label, [x[0] for x in per_session])]
    groups: list[tuple[str, list[Loaded]]] = []
    for e in per_session[0]:
        picks = [next((o for o in x if o.label == e.label), None) for x in per_session]
        if all(p is not None for p in picks):
            groups.append((e.label, [p for p in picks if p is not None]))
    if not groups:
        kinds = "; ".join(
            f"session {k}: {', '.join(e.label for e in x)}"
            for k, x in enumerate(per_session, start=1)
        )
        raise EvalError(
            f"the sessions have no estimate of one kind in common ({kinds}); "
            "pick one with --which final|online"
        )
    return groups


def _run_joint(args: argparse.Namespace, cfg: EvalConfig) -> int:
    """Several sessions: one alignment over all of them (eval.joint), then each on its own."""
    from eurocslam.errors import EurocSlamError, EvalError
    from eurocslam.eval.joint import evaluate_joint
    from eurocslam.eval.loaders import (
        groundtruth_from_estimate_source,
        load_estimates,
        load_groundtruth,
    )
    from eurocslam.eval.report import (
        joint_json_dict,
        joint_note,
        joint_report,
        write_json,
        write_text,
    )

    per_session: list[list[Loaded]] = []
    gts: list[Loaded] = []
    notes: list[str] = []
    for k, (est_path, gt_arg) in enumerate(_session_inputs(args), start=1):
        try:
            estimates = load_estimates(
                est_path, args.topic, args.child_frame, args.time_unit, args.which
            )
            gt_path = gt_arg or groundtruth_from_estimate_source(est_path)
            if gt_path is None:
                raise EvalError(
                    f"{est_path}: no ground truth given and none found in it (pass a sequence "
                    "folder, data.csv, TUM file or MCAP with /groundtruth/pose)"
                )
            gt = load_groundtruth(gt_path, args.gt_topic, args.gt_child_frame, args.gt_time_unit)
        except EurocSlamError as e:
            raise type(e)(f"session {k}: {e}") from None
        per_session.append(estimates)
        gts.append(gt)
        notes += [*gt.notes, *(n for e in estimates for n in e.notes)]
    for note in dict.fromkeys(notes):
        print(f"eurocslam eval: note: {note}", file=sys.stderr)

    joints = [
        evaluate_joint([(g.traj, e.traj) for g, e in zip(gts, picks, strict=True)], cfg, label)
        for label, picks in _pair_estimates(per_session)
    ]
    report = joint_report(joints)
    if not args.quiet:
        print(report)
    if args.md:
        write_text(args.md, report)
    if args.json:
        inputs = [
            {"session": k, "estimates": [e.source for e in x], "groundtruth": g.source}
            for k, (x, g) in enumerate(zip(per_session, gts, strict=True), start=1)
        ]
        write_json(args.json, joint_json_dict(joints, inputs))
    if args.plot:
        from eurocslam.eval.plots import plot_joint_top, plot_result, prefix_for

        written = []
        for j in joints:
            prefix = prefix_for(j.label)
            written.append(plot_joint_top(j, args.plot / f"joint_{prefix}_top.png"))
            for s in j.sessions:
                written += plot_result(s.own, args.plot, f"s{s.session}_{prefix}")
        print(f"eurocslam eval: wrote {len(written)} plots to {args.plot}", file=sys.stderr)
    for j in joints:
        frame_note = joint_note(j)
        if frame_note:
            print(f"eurocslam eval: note: {frame_note}", file=sys.stderr)
        for s in j.sessions:
            _warn([s.own])
    return 0
