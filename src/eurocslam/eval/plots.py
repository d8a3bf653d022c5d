"""PNG plots of an evaluation (matplotlib, Agg backend, no display needed).

`plot_result(result, out_dir, prefix)` writes four files and returns their paths:

* `{prefix}_top.png`   top view (x-y) of the aligned estimate over the ground truth;
* `{prefix}_error.png` ATE translation and rotation error over time (segments coloured);
* `{prefix}_rpe.png`   RPE translation error box plots per sub-trajectory length (and in %);
* `{prefix}_xyz.png`   x, y, z of ground truth and aligned estimate over time.

`plot_joint_top(joint, path)` draws several sessions under their one joint alignment.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.errors import OutputError
from eurocslam.eval.evaluate import EvalResult
from eurocslam.eval.joint import JointResult
from eurocslam.timebase import NS_PER_S

GT_COLOR = "0.35"
SEG_COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _t0(r: EvalResult) -> int:
    return int(min(s.t_ns[0] for s in r.segments))


def _save(fig: Any, path: Path) -> Path:
    try:
        fig.savefig(path, dpi=110, bbox_inches="tight")
    except OSError as e:
        raise OutputError(f"{path}: cannot write plot: {e}") from None
    finally:
        _plt().close(fig)
    return path


def _draw_top(ax: Any, refs: list[np.ndarray], ests: list[tuple[np.ndarray, str, str]]) -> None:
    """Ground truths (labelled once) and estimates `(positions, colour, label)` seen from above:
    on the two axes along which the ground truth spreads most (x, y in a gravity-aligned world;
    x, z in a camera-like frame with y down, as KITTI's)."""
    spread = np.ptp(np.concatenate(refs), axis=0) if refs else np.ones(3)
    i, j = sorted(int(a) for a in np.argsort(spread)[-2:])
    for k, p in enumerate(refs):
        ax.plot(p[:, i], p[:, j], color=GT_COLOR, lw=1.6, label="ground truth" if k == 0 else None)
    for p, c, lab in ests:
        ax.plot(p[:, i], p[:, j], color=c, lw=1.1, label=lab)
        ax.plot(p[0, i], p[0, j], "o", color=c, ms=5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{'xyz'[i]} [m]")
    ax.set_ylabel(f"{'xyz'[j]} [m]")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)


def _segment_label(r: EvalResult, segment: int) -> str:
    return "estimate (aligned)" if len(r.segments) == 1 else f"segment {segment}"


def plot_top(r: EvalResult, path: Path) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 6))
    _draw_top(
        ax,
        [s.p_ref for s in r.segments],
        [
            (
                s.p_est,
                SEG_COLORS[k % len(SEG_COLORS)],
                _segment_label(r, s.segment),
            )
            for k, s in enumerate(r.segments)
        ],
    )
    ax.set_title(
        f"{r.label}: top view, {r.config.align} aligned\n"
        f"ATE rmse {r.ate_trans.rmse:.3f} m over {r.matched} poses",
        fontsize=10,
    )
    return _save(fig, path)


def plot_error(r: EvalResult, path: Path) -> Path:
    plt = _plt()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    t0 = _t0(r)
    for k, s in enumerate(r.segments):
        t = (s.t_ns - t0) / NS_PER_S
        c = SEG_COLORS[k % len(SEG_COLORS)]
        lab = None if len(r.segments) == 1 else f"segment {s.segment}"
        a1.plot(t, s.ate_t, color=c, lw=1, label=lab)
        a2.plot(t, s.ate_r, color=c, lw=1)
    a1.axhline(r.ate_trans.rmse, color="k", ls="--", lw=0.8, label=f"rmse {r.ate_trans.rmse:.3f}")
    a2.axhline(r.ate_rot.rmse, color="k", ls="--", lw=0.8, label=f"rmse {r.ate_rot.rmse:.2f}")
    a1.set_ylabel("translation [m]")
    a2.set_ylabel("rotation [deg]")
    a2.set_xlabel("time since first matched pose [s]")
    for a in (a1, a2):
        a.grid(alpha=0.3)
        a.legend(loc="upper left", fontsize=8)
        a.set_ylim(bottom=0)
    a1.set_title(f"{r.label}: ATE over time ({r.config.align} aligned)", fontsize=10)
    return _save(fig, path)


def plot_rpe(r: EvalResult, path: Path) -> Path:
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.2))
    lens = [L for L in r.lengths if L.trans.n > 0]
    if lens:
        labels = [f"{L.length_m:.1f}" for L in lens]
        a1.boxplot([L.trans_errors for L in lens], showfliers=False)
        a2.boxplot([100 * L.trans_errors / L.length_m for L in lens], showfliers=False)
        for a in (a1, a2):
            a.set_xticks(range(1, len(lens) + 1), labels)
            a.set_xlabel("sub-trajectory length [m]")
            a.grid(alpha=0.3, axis="y")
    else:
        a1.text(
            0.5, 0.5, "trajectory too short for distance RPE", ha="center", transform=a1.transAxes
        )
    a1.set_ylabel("translation error [m]")
    a2.set_ylabel("translation error [% of length]")
    fig.suptitle(f"{r.label}: relative pose error per sub-trajectory length", fontsize=10)
    return _save(fig, path)


def plot_xyz(r: EvalResult, path: Path) -> Path:
    plt = _plt()
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    t0 = _t0(r)
    for k, s in enumerate(r.segments):
        t = (s.t_ns - t0) / NS_PER_S
        c = SEG_COLORS[k % len(SEG_COLORS)]
        for i, a in enumerate(axes):
            a.plot(
                t, s.p_ref[:, i], color=GT_COLOR, lw=1.6, label="ground truth" if k == 0 else None
            )
            a.plot(
                t,
                s.p_est[:, i],
                color=c,
                lw=1,
                label=_segment_label(r, s.segment),
            )
    for i, a in enumerate(axes):
        a.set_ylabel(f"{'xyz'[i]} [m]")
        a.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time since first matched pose [s]")
    axes[0].set_title(f"{r.label}: positions ({r.config.align} aligned)", fontsize=10)
    return _save(fig, path)


def plot_joint_top(j: JointResult, path: Path) -> Path:
    """Top view of every session's estimate under the joint alignment, over the ground truths."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 6))
    _draw_top(
        ax,
        [s.p_ref for s in j.sessions],
        [
            (s.p_est, SEG_COLORS[k % len(SEG_COLORS)], f"session {s.session}")
            for k, s in enumerate(j.sessions)
        ],
    )
    ax.set_title(
        f"{j.label}: {len(j.sessions)} sessions, one {j.config.align} alignment\n"
        f"joint ATE rmse {j.ate_trans.rmse:.3f} m over {j.matched} poses",
        fontsize=10,
    )
    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{out.parent}: cannot create plot folder: {e}") from None
    return _save(fig, out)


def plot_result(r: EvalResult, out_dir: Path | str, prefix: str) -> list[Path]:
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{out}: cannot create plot folder: {e}") from None
    return [
        plot_top(r, out / f"{prefix}_top.png"),
        plot_error(r, out / f"{prefix}_error.png"),
        plot_rpe(r, out / f"{prefix}_rpe.png"),
        plot_xyz(r, out / f"{prefix}_xyz.png"),
    ]


def prefix_for(label: str) -> str:
    """'final (smoothed)' -> 'final'."""
    head = label.split()[0] if label.split() else "estimate"
    return "".join(ch for ch in head if ch.isalnum() or ch in "-_") or "estimate"


__all__ = [
    "plot_error",
    "plot_joint_top",
    "plot_result",
    "plot_rpe",
    "plot_top",
    "plot_xyz",
    "prefix_for",
]
