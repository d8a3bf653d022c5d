"""Several sessions under one alignment: multi-session evaluation.

Flights of one place (EuRoC's five Machine Hall sequences, the V1_* and V2_* Vicon rooms, or
`synth --world-from` replicas) have ground truths in one frame. A SLAM system that reuses a map
puts a later session in the map's frame, so its sessions' estimates share a frame too. Whether
they really do is what a joint evaluation measures: each session's estimate is associated with
its own ground truth, the matched pairs of all sessions are stacked, and one alignment
(`EvalConfig.align`, fitted over the whole stack, `align_first` counting from the first
session's first pose) maps them all. Reported:

* the joint ATE over every pair of every session;
* each session's ATE under that joint alignment;
* each session evaluated on its own (`evaluate`: its own alignment, segments aligned each on
  its own, RPE), and the sessions' own-alignment ATE errors pooled, for comparison.

A session's segments (a run that reset and did not merge back) are not aligned separately in the
joint figure: one frame for everything is the claim being checked. When the estimates do not
share a frame the joint ATE is much larger than the sessions' own (`ratio`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eurocslam.errors import EvalError
from eurocslam.eval.align import Alignment, align
from eurocslam.eval.associate import Association
from eurocslam.eval.evaluate import EvalConfig, EvalResult, evaluate
from eurocslam.eval.metrics import Stats, ate_errors
from eurocslam.geometry import F64, make_T
from eurocslam.trajectory import Trajectory

# the joint ATE over the sessions' own above this factor suggests the frames are not shared
SHARED_FRAME_RATIO = 2.0


@dataclass(frozen=True)
class SessionJoint:
    """One session's matched poses under the joint alignment, and its own evaluation."""

    session: int  # 1-based, in the order given
    association: Association
    t_ns: np.ndarray  # reference stamps of the matched pairs
    p_ref: F64
    R_ref: F64
    p_est: F64  # under the joint alignment
    R_est: F64
    ate_t: F64  # per pose [m], joint alignment
    ate_r: F64  # per pose [deg], joint alignment
    own: EvalResult  # the session evaluated on its own

    @property
    def own_ate_t(self) -> F64:
        """Per-pose ATE translation errors under the session's own alignment(s)."""
        return np.concatenate([s.ate_t for s in self.own.segments])

    def to_dict(self) -> dict[str, object]:
        return {
            "session": self.session,
            "estimate": self.own.est_name,
            "reference": self.own.ref_name,
            "association": self.association.summary(),
            "ate_trans_m": Stats.of(self.ate_t).to_dict(),
            "ate_rot_deg": Stats.of(self.ate_r).to_dict(),
            "own_ate_trans_m": self.own.ate_trans.to_dict(),
            "own_ate_rot_deg": self.own.ate_rot.to_dict(),
        }


@dataclass(frozen=True)
class JointResult:
    label: str  # e.g. "final (smoothed)"
    config: EvalConfig
    alignment: Alignment
    sessions: list[SessionJoint]
    ate_trans: Stats  # every pair of every session, joint alignment
    ate_rot: Stats
    own_ate_trans: Stats  # the sessions' own-alignment errors, pooled
    # where the joint alignment took its rotation from the orientations: the joint ATE under the
    # position-only (evo) fit (`Alignment.position_fit`)
    ate_trans_position_fit: Stats | None = None

    @property
    def matched(self) -> int:
        return sum(s.association.matched for s in self.sessions)

    @property
    def ratio(self) -> float:
        """Joint ATE RMSE over the pooled own-alignment ATE RMSE (>= about 1)."""
        own = self.own_ate_trans.rmse
        return float(self.ate_trans.rmse / own) if own > 0 else float("inf")

    def frames_look_shared(self) -> bool:
        return self.ratio <= SHARED_FRAME_RATIO

    def to_dict(self) -> dict[str, object]:
        return {
            "label": self.label,
            "config": self.config.to_dict(),
            "alignment": self.alignment.summary(),
            "matched": self.matched,
            "ate_trans_m": self.ate_trans.to_dict(),
            "ate_rot_deg": self.ate_rot.to_dict(),
            "own_ate_trans_m": self.own_ate_trans.to_dict(),
            "ate_trans_position_fit_m": (
                None
                if self.ate_trans_position_fit is None
                else self.ate_trans_position_fit.to_dict()
            ),
            "ratio_joint_to_own": self.ratio,
            "sessions": [s.to_dict() for s in self.sessions],
        }


def _sorted(t: Trajectory) -> Trajectory:
    order = np.argsort(t.t_ns, kind="stable")
    if np.array_equal(order, np.arange(len(t))):
        return t
    return Trajectory(t.t_ns[order], t.p[order], t.q_wxyz[order], None, t.name)


def evaluate_joint(
    pairs: list[tuple[Trajectory, Trajectory]],
    cfg: EvalConfig | None = None,
    label: str = "estimate",
) -> JointResult:
    """Evaluate sessions `(reference, estimate)` under one alignment (see the module
    docstring). Errors name the session and its inputs."""
    cfg = cfg or EvalConfig()
    if len(pairs) < 1:
        raise EvalError("joint evaluation needs at least one session")
    own: list[EvalResult] = []
    assoc: list[Association] = []
    refs: list[tuple[F64, F64, np.ndarray]] = []
    ests: list[tuple[F64, F64]] = []
    for k, (ref, est) in enumerate(pairs, start=1):
        try:
            own.append(evaluate(ref, est, cfg, label))
            r, e = _sorted(ref), _sorted(est)
            a = cfg.associate(r, e)
        except EvalError as err:
            raise EvalError(f"session {k}: {err}") from None
        assoc.append(a)
        refs.append((r.p[a.idx_ref], r.rotations()[a.idx_ref], r.t_ns[a.idx_ref]))
        ests.append((e.p[a.idx_est], e.rotations()[a.idx_est]))
    P_ref = np.concatenate([r[0] for r in refs])
    P_est = np.concatenate([e[0] for e in ests])
    R_ref0, R_est0 = refs[0][1][0], ests[0][1][0]
    try:
        al = align(
            cfg.align,
            P_ref,
            P_est,
            make_T(R_ref0, refs[0][0][0]),
            make_T(R_est0, ests[0][0][0]),
            cfg.align_first,
            np.concatenate([r[1] for r in refs]),
            np.concatenate([e[1] for e in ests]),
        )
    except EvalError as err:
        raise EvalError(f"joint alignment of {len(pairs)} sessions: {err}") from None
    sessions: list[SessionJoint] = []
    for k, ((p_r, R_r, t), (p_e, R_e), a, o) in enumerate(
        zip(refs, ests, assoc, own, strict=True), start=1
    ):
        p_al, R_al = al.apply(p_e, R_e)
        e_t, e_r = ate_errors(p_r, R_r, p_al, R_al)
        sessions.append(SessionJoint(k, a, t, p_r, R_r, p_al, R_al, e_t, e_r, o))
    cat = np.concatenate
    position_fit = None
    if al.position_fit is not None:
        p_pos = al.position_fit.apply_positions(P_est)
        position_fit = Stats.of(np.linalg.norm(p_pos - P_ref, axis=1))
    return JointResult(
        label=label,
        config=cfg,
        alignment=al,
        sessions=sessions,
        ate_trans=Stats.of(cat([s.ate_t for s in sessions])),
        ate_rot=Stats.of(cat([s.ate_r for s in sessions])),
        own_ate_trans=Stats.of(cat([s.own_ate_t for s in sessions])),
        ate_trans_position_fit=position_fit,
    )
