"""Evaluation reports: JSON (machine readable) and Markdown (for people and PRs)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from eurocslam.errors import OutputError
from eurocslam.eval.align import Alignment
from eurocslam.eval.evaluate import MIN_FRACTION_LENGTH_M, EvalResult
from eurocslam.eval.joint import JointResult
from eurocslam.eval.metrics import Stats
from eurocslam.timebase import NS_PER_S

SCHEMA = "eurocslam.eval/1"


def to_json_dict(results: list[EvalResult], extra: dict[str, Any] | None = None) -> dict[str, Any]:
    d: dict[str, Any] = {"schema": SCHEMA, "results": [r.to_dict() for r in results]}
    if extra:
        d.update(extra)
    return d


def _clean(o: Any) -> Any:
    """NaN/inf -> None so the JSON is strict."""
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_clean(v) for v in o]
    return o


def write_json(path: Path | str, data: dict[str, Any]) -> None:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(_clean(data), indent=2, allow_nan=False) + "\n")
    except OSError as e:
        raise OutputError(f"{path}: cannot write: {e}") from None


def write_text(path: Path | str, text: str) -> None:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    except OSError as e:
        raise OutputError(f"{path}: cannot write: {e}") from None


def fmt(v: float | None, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:.{digits}f}"


def _row(name: str, s: Stats, digits: int = 4) -> str:
    vals = [s.rmse, s.mean, s.median, s.std, s.min, s.max]
    return f"| {name} | " + " | ".join(fmt(v, digits) for v in vals) + f" | {s.n} |"


def _align_text(r: EvalResult) -> str:
    cfg = r.config
    a = cfg.align + (f" on the first {cfg.align_first} poses" if cfg.align_first else "")
    if len(r.segments) > 1:
        a += f", each of the {len(r.segments)} segments aligned on its own"
    else:
        al = r.segments[0].alignment
        if al.mode == "sim3":
            a += f", scale {al.s:.4f}"
        if al.mode in ("posyaw", "se3", "sim3", "origin"):
            a += f", yaw {al.yaw_deg:+.2f} deg"
        if al.note:
            a += f" ({al.note})"
    return a


def _headline_text(r: EvalResult) -> str | None:
    """Which ATE figure is the headline, when the alignment took its rotation from the
    orientations (otherwise the position fit, evo's, is the only one)."""
    if not r.from_orientations:
        return None
    return (
        f"ATE headline {fmt(r.ate_trans.rmse)} m RMSE, with the rotation from the orientations; "
        + _position_fit_text(r.ate_trans_position_fit, r.segments[0].alignment, len(r.segments))
    )


def _position_fit_text(pos: Stats | None, al: Alignment, n_segments: int) -> str:
    """The position-only figure beside an orientation-based headline, and why it is not the
    headline."""
    if pos is None:
        return "a position-only fit (evo's) is not defined here (one side does not move)"
    scale = ""
    if al.mode == "sim3" and al.position_fit is not None and n_segments == 1:
        scale = f", scale {al.position_fit.s:.4f}"
    return (
        f"the position-only fit (evo's definition{scale}) gives {fmt(pos.rmse)} m RMSE, but "
        "its rotation is arbitrary there: it turns the estimate's noise onto the reference's"
    )


def markdown(r: EvalResult, title: str | None = None) -> str:
    """One result as Markdown: header lines, statistics table, segment table when relevant."""
    cfg = r.config
    out = [f"### {title or r.label}", ""]
    out.append(f"- estimate: `{r.est_name}` ({r.label})")
    out.append(f"- ground truth: `{r.ref_name}`")
    out.append(
        f"- association: {r.matched} of {r.possible} possible pairs matched "
        f"(max diff {cfg.max_diff_s:g} s, offset {cfg.offset_s:g} s)"
    )
    out.append(f"- alignment: {_align_text(r)}")
    headline = _headline_text(r)
    if headline:
        out.append(f"- {headline}")
    out.append(
        f"- coverage: {100 * r.coverage:.1f} % of the {r.ref_span_s:.1f} s ground truth; "
        f"ground-truth path {r.ref_length_m:.2f} m"
    )
    if r.drift_pct is not None:
        out.append(f"- drift: {r.drift_pct:.2f} % of distance travelled (mean over RPE lengths)")
    elif not r.lengths:
        out.append(
            f"- drift: none measured (the matched ground-truth path, "
            f"{sum(s.gt_length_m for s in r.segments):.3f} m, has no RPE length of "
            f"{MIN_FRACTION_LENGTH_M:g} m or more)"
        )
    out += [
        "",
        "| metric | rmse | mean | median | std | min | max | n |",
        "|---|---|---|---|---|---|---|---|",
        _row("ATE translation [m]", r.ate_trans),
        *(
            [_row("ATE translation, position-only fit (evo) [m]", r.ate_trans_position_fit)]
            if r.ate_trans_position_fit is not None
            else []
        ),
        _row("ATE rotation [deg]", r.ate_rot, 3),
        _row(f"RPE {cfg.rpe_delta} frame translation [m]", r.rpe_delta_trans),
        _row(f"RPE {cfg.rpe_delta} frame rotation [deg]", r.rpe_delta_rot, 3),
    ]
    for L in r.lengths:
        tag = f"{L.length_m:.2f} m" + (f" ({100 * L.fraction:.0f} %)" if L.fraction else "")
        out.append(_row(f"RPE {tag} translation [m]", L.trans))
        out.append(_row(f"RPE {tag} translation [%]", L.trans_pct, 2))
        out.append(_row(f"RPE {tag} rotation [deg]", L.rot, 3))
    if len(r.segments) > 1 or r.skipped:
        out += [
            "",
            "| segment | matched / possible | duration [s] | GT length [m] | ATE rmse [m] "
            "| RPE rmse [m] | alignment |",
            "|---|---|---|---|---|---|---|",
        ]
        for s in r.segments:
            a = s.association
            dur = (s.t_ns[-1] - s.t_ns[0]) / NS_PER_S
            al = s.alignment
            out.append(
                f"| {s.segment} | {a.matched} / {a.possible} | {dur:.1f} | {s.gt_length_m:.2f} "
                f"| {fmt(Stats.of(s.ate_t).rmse)} | {fmt(Stats.of(s.rpe_t).rmse)} "
                f"| {al.mode}, yaw {al.yaw_deg:+.1f} deg, scale {al.s:.3f}"
                + (", rotation from the orientations" if al.from_orientations else "")
                + " |"
            )
        for sid, why in r.skipped:
            out.append(f"| {sid} | skipped: {why} | | | | | |")
    return "\n".join(out) + "\n"


def markdown_summary(results: list[EvalResult]) -> str:
    """Side-by-side headline figures (e.g. final vs online)."""
    out = [
        "| trajectory | ATE rmse [m] | ATE rot rmse [deg] | RPE 1 frame rmse [m] | drift [%] "
        "| matched / possible | coverage |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        mark = " *" if r.from_orientations else ""
        out.append(
            f"| {r.label} | {fmt(r.ate_trans.rmse)}{mark} | {fmt(r.ate_rot.rmse, 3)} "
            f"| {fmt(r.rpe_delta_trans.rmse)} | {fmt(r.drift_pct, 2)} "
            f"| {r.matched} / {r.possible} | {100 * r.coverage:.1f} % |"
        )
    if any(r.from_orientations for r in results):
        out += [
            "",
            "\\* rotation of the alignment from the orientations (the positions do not decide "
            "it); the position-only figure is in the section below",
        ]
    return "\n".join(out) + "\n"


def markdown_report(results: list[EvalResult]) -> str:
    parts = ["## Trajectory evaluation", ""]
    if len(results) > 1:
        parts += [markdown_summary(results), ""]
    for r in results:
        parts.append(markdown(r))
    return "\n".join(parts)


# ---- several sessions under one alignment (eval.joint) ---------------------------------------
def joint_note(j: JointResult) -> str | None:
    """A note when the joint ATE is much larger than the sessions' own: frames not shared?"""
    if j.frames_look_shared():
        return None
    return (
        f"{j.label}: the joint ATE ({fmt(j.ate_trans.rmse)} m) is {j.ratio:.1f}x the sessions' "
        f"own-alignment ATE ({fmt(j.own_ate_trans.rmse)} m): do the estimates share a frame? "
        "(a run that reuses a map puts its session in the map's frame)"
    )


def joint_markdown(j: JointResult) -> str:
    """One joint evaluation: the alignment, a per-session table and the joint statistics."""
    cfg, al = j.config, j.alignment
    a = cfg.align + (f" on the first {cfg.align_first} poses" if cfg.align_first else "")
    if al.mode == "sim3":
        a += f", scale {al.s:.4f}"
    if al.mode in ("posyaw", "se3", "sim3", "origin"):
        a += f", yaw {al.yaw_deg:+.2f} deg"
    if al.note:
        a += f" ({al.note})"
    n = len(j.sessions)
    out = [f"### Joint: {n} sessions under one alignment, {j.label}", ""]
    out.append(f"- alignment: one {a}, over the {j.matched} matched poses of all sessions")
    if al.from_orientations:
        out.append(
            f"- joint ATE headline {fmt(j.ate_trans.rmse)} m RMSE, with the rotation from the "
            "orientations; " + _position_fit_text(j.ate_trans_position_fit, al, 1)
        )
    out.append(
        f"- ATE rmse {fmt(j.ate_trans.rmse)} m joint vs {fmt(j.own_ate_trans.rmse)} m with "
        f"each session aligned on its own ({j.ratio:.2f}x)"
    )
    note = joint_note(j)
    if note:
        out.append(f"- note: {note}")
    out += [
        "",
        "| session | estimate | ground truth | matched / possible | ATE rmse joint [m] "
        "| ATE rmse own [m] | ATE rot rmse joint [deg] |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in j.sessions:
        st, sr = Stats.of(s.ate_t), Stats.of(s.ate_r)
        out.append(
            f"| {s.session} | `{s.own.est_name}` | `{s.own.ref_name}` "
            f"| {s.association.matched} / {s.association.possible} | {fmt(st.rmse)} "
            f"| {fmt(s.own.ate_trans.rmse)} | {fmt(sr.rmse, 3)} |"
        )
    out.append(
        f"| all | | | {j.matched} | {fmt(j.ate_trans.rmse)} | {fmt(j.own_ate_trans.rmse)} "
        f"| {fmt(j.ate_rot.rmse, 3)} |"
    )
    out += [
        "",
        "| metric (joint alignment) | rmse | mean | median | std | min | max | n |",
        "|---|---|---|---|---|---|---|---|",
        _row("ATE translation [m]", j.ate_trans),
        _row("ATE rotation [deg]", j.ate_rot, 3),
    ]
    return "\n".join(out) + "\n"


def joint_report(joints: list[JointResult]) -> str:
    """The joint sections, then every session evaluated on its own."""
    parts = ["## Trajectory evaluation", ""]
    parts += [joint_markdown(j) for j in joints]
    n = len(joints[0].sessions) if joints else 0
    for k in range(n):
        for j in joints:
            r = j.sessions[k].own
            parts.append(markdown(r, f"Session {k + 1} on its own: {r.label}"))
    return "\n".join(parts)


def joint_json_dict(
    joints: list[JointResult], sessions: list[dict[str, Any]] | None = None
) -> dict[str, Any]:
    """JSON of a joint evaluation: `joint` (one entry per estimate kind), `results` (every
    session on its own, with its `session` number) and the `sessions`' inputs."""
    n = len(joints[0].sessions) if joints else 0
    results = [{"session": k + 1, **j.sessions[k].own.to_dict()} for k in range(n) for j in joints]
    d: dict[str, Any] = {
        "schema": SCHEMA,
        "joint": [j.to_dict() for j in joints],
        "results": results,
    }
    if sessions is not None:
        d["sessions"] = sessions
    return d
