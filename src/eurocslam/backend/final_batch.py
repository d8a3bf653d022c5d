"""The final batch of a segment: one Levenberg-Marquardt over every factor the smoother saw, the
variance check of the IMU against the vision, and IMU-bridged poses between keyframes.

The smoother (`estimator.py`) fills a `SegmentGraph` as it goes: every factor it was given (a
landmark under its first key however often the smoother let it go), the latest estimate of every
keyframe variable, and the stereo observations beyond the smoother's cap that only this batch
takes (`final_only`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X

from eurocslam.backend.factors import ImuModel, StereoModel, pose
from eurocslam.backend.landmarks import LandmarkKeys, landmark_indices
from eurocslam.backend.preintegration import bias, integrate
from eurocslam.backend.types import ImuCheck, NavEstimate
from eurocslam.geometry import F64, make_T, so3_exp, so3_log

REWEIGHT_ROUNDS = 3  # variance-component rounds of the final batch, at most
REWEIGHT_DONE = 1.25  # they stop once the IMU/stereo residual ratio is below this


@dataclass
class SegmentGraph:
    """Everything the final batch of one segment needs, filled by the smoother."""

    graph: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    values: dict[int, Any] = field(default_factory=dict)  # key -> latest estimate (gtsam)
    kf_times: list[int] = field(default_factory=list)
    kf_index0: int = 0
    # stereo observations beyond the smoother's cap, for the final batch:
    # (keyframe index, global landmark key, uL, uR, v, sigma scale)
    final_only: list[tuple[int, int, float, float, float, float]] = field(default_factory=list)

    def add_keyframe(self, t_ns: int) -> None:
        """The next keyframe's time."""
        self.kf_times.append(t_ns)

    def add_factor(self, factor: gtsam.NonlinearFactor) -> None:
        self.graph.add(factor)

    def set_state(self, k: int, pose: gtsam.Pose3, v: Any, b: Any) -> None:
        """Keyframe `k`'s latest estimate: pose, velocity, biases (gtsam values)."""
        self.values[X(k)] = pose
        self.values[V(k)] = v
        self.values[B(k)] = b

    def move_state(self, k: int, T_world_body: F64, R_new_old: F64) -> None:
        """Keyframe `k` moved to `T_world_body`, its velocity turned by `R_new_old`."""
        self.values[X(k)] = pose(T_world_body)
        if V(k) in self.values:
            self.values[V(k)] = R_new_old @ np.asarray(self.values[V(k)])


@dataclass(frozen=True)
class FinalBatchResult:
    poses: dict[int, F64]  # keyframe index -> T_world_body
    states: dict[int, NavEstimate]  # keyframe index -> final state (empty if it failed)
    landmarks: dict[int, F64]  # global landmark key -> position
    imu_check: ImuCheck | None


def final_batch(
    seg: SegmentGraph,
    lms: LandmarkKeys,
    kf_estimates: dict[int, NavEstimate],
    stereo: StereoModel,
    imu: ImuModel | None,
    reweight_above: float,
    max_iterations: int = 5,
) -> FinalBatchResult:
    """Full Levenberg-Marquardt over every factor of the segment and the stereo observations
    kept for it alone (`_final_graph`).

    With the IMU (`imu` given), a variance-component estimate follows: the IMU factors'
    chi-square per redundancy against the stereo factors' (`imu_check`). When the IMU disagrees
    with the vision by more than `reweight_above` times what its noise model allows (a real
    accelerometer whose bias wanders faster than its datasheet says), the accelerometer's noise
    and bias-walk covariances are scaled by the ratio and the batch takes one more iteration from
    the last result, until the ratio is near 1 (at most `REWEIGHT_ROUNDS` rounds); then it
    converges at that scale (`max_iterations`). On V1_01 the accelerometer carries the
    disagreement (its residual components 15x a simulated IMU's, the gyro's 5x): scaling the
    gyro's too left the keyframes 0.2-0.35 mm worse.

    Falls back to the smoother's estimates if the batch fails to converge."""
    vals = gtsam.Values()
    for key, v in seg.values.items():
        if chr(gtsam.Symbol(key).chr()) == "v":
            vals.insert(key, np.asarray(v, dtype=float))
        else:
            vals.insert(key, v)
    graph = _final_graph(seg, lms, stereo)
    # one variable per landmark: its first key (its later keys' factors were re-keyed)
    gkeys = landmark_indices(graph.keyVector())
    positions = {int(i): lms.pos[i].copy() for i in gkeys}
    for i, p in positions.items():
        vals.insert(L(i), gtsam.Point3(*p))  # type: ignore[no-untyped-call]
    poses = {kk: e.T_world_body for kk, e in kf_estimates.items()}
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-4)
    # the elimination order Levenberg-Marquardt would compute, once for every round (a
    # rescaled graph has the same structure)
    params.setOrdering(graph.orderingCOLAMD())
    result = optimize(graph, vals, params, kf_estimates)
    if result is None:
        return FinalBatchResult(poses, {}, positions, None)
    imu_check = None
    if imu is not None:
        result, imu_check = _reweight_imu(
            seg, graph, result, params, kf_estimates, imu, reweight_above
        )
    out = {}
    states = {}
    for kk, e in kf_estimates.items():
        if result.exists(X(kk)):
            T = result.atPose3(X(kk)).matrix()
            out[kk] = T
            v, b = np.asarray(result.atVector(V(kk))), result.atConstantBias(B(kk))
            bg, ba = np.asarray(b.gyroscope()), np.asarray(b.accelerometer())
            states[kk] = NavEstimate(e.t_ns, T, v, bg, ba)
    lm_out = {}
    for key_i in positions:
        if result.exists(L(key_i)):
            lm_out[key_i] = np.asarray(result.atPoint3(L(key_i)))
    return FinalBatchResult(out, states, lm_out, imu_check)


def _final_graph(
    seg: SegmentGraph, lms: LandmarkKeys, stereo: StereoModel
) -> gtsam.NonlinearFactorGraph:
    """The segment's factors plus its final-only stereo observations of landmarks seen
    at least twice (one observation only adds a landmark, no constraint)."""
    extra = [o for o in seg.final_only if lms.nobs[o[1]] >= 2]
    if not extra:
        return seg.graph
    graph = gtsam.NonlinearFactorGraph(seg.graph)
    for k, gkey, ul, ur, v, scale in extra:
        graph.add(stereo.factor(k, gkey, ul, ur, v, float(scale)))
    return graph


def optimize(
    graph: gtsam.NonlinearFactorGraph,
    vals: gtsam.Values,
    params: gtsam.LevenbergMarquardtParams,
    kf_estimates: dict[int, NavEstimate],
) -> gtsam.Values | None:
    """Levenberg-Marquardt; None if it fails or any keyframe pose comes out non-finite."""
    try:
        result = gtsam.LevenbergMarquardtOptimizer(graph, vals, params).optimize()
    except RuntimeError:
        return None
    for kk in kf_estimates:
        if result.exists(X(kk)) and not np.all(np.isfinite(result.atPose3(X(kk)).matrix())):
            return None
    return result


def _reweight_imu(
    seg: SegmentGraph,
    graph: gtsam.NonlinearFactorGraph,
    result: gtsam.Values,
    params: gtsam.LevenbergMarquardtParams,
    kf_estimates: dict[int, NavEstimate],
    imu: ImuModel,
    above: float,
) -> tuple[gtsam.Values, ImuCheck]:
    """Variance-component rounds on the accelerometer (see `final_batch`): the batch
    converged at the scale of the last round that succeeded, and the check; the batch as it
    came when no round succeeded or it did not converge at that scale."""
    groups = _Groups.of(graph)
    ratio = first = groups.imu_ratio(graph, result)
    if not 0.0 < above < ratio:
        return result, ImuCheck(first, 1.0, math.nan)
    # a round needs only the residuals at its scale, not a converged batch: one iteration each,
    # then the batch converges at the last scale (on V1_01: 8 iterations instead of 10)
    converged = result
    iterations = params.getMaxIterations()
    params.setMaxIterations(1)
    scale, g = 1.0, graph
    try:
        for _ in range(REWEIGHT_ROUNDS):
            trial = scale * ratio
            g_trial = _imu_rescaled(seg, graph, groups.imu_at, imu, trial)
            again = optimize(g_trial, result, params, kf_estimates)
            if again is None:
                break
            scale, result, g = trial, again, g_trial
            ratio = groups.imu_ratio(g, result)
            if not ratio >= REWEIGHT_DONE:  # near 1, or NaN
                break
    finally:
        params.setMaxIterations(iterations)
    final = None if g is graph else optimize(g, result, params, kf_estimates)
    if final is None:  # no round, or no convergence at the last scale: the batch before them
        return converged, ImuCheck(first, 1.0, math.nan)
    return final, ImuCheck(first, scale, groups.imu_ratio(g, final))


@dataclass(frozen=True)
class _Groups:
    """The final graph's IMU factors (their positions) and stereo factors (a graph of their
    own, sharing them), and each group's redundancy, for the chi-square ratio of the IMU
    check. A rescaled graph (`_imu_rescaled`) keeps every factor's position.

    Redundancy per group, each parameter counted in the group that determines it: an IMU
    factor has 15 residuals, 9 of which fix its keyframe's velocity and biases (6 left); the
    stereo observations have 3 residuals each, less 3 per landmark and 6 per keyframe pose."""

    imu_at: list[int]
    stereo: gtsam.NonlinearFactorGraph
    r_imu: int
    r_st: int

    @staticmethod
    def of(graph: gtsam.NonlinearFactorGraph) -> _Groups:
        imu_at = []
        stereo = gtsam.NonlinearFactorGraph()
        landmarks: set[int] = set()
        poses: set[int] = set()
        for i in range(graph.size()):
            f = graph.at(i)
            if isinstance(f, gtsam.CombinedImuFactor):
                imu_at.append(i)
            elif isinstance(f, gtsam.GenericStereoFactor3D):
                stereo.add(f)
                pose_key, lm_key = f.keys()
                poses.add(pose_key)
                landmarks.add(lm_key)
        r_st = 3 * stereo.size() - 3 * len(landmarks) - 6 * len(poses)
        return _Groups(imu_at, stereo, 6 * len(imu_at), r_st)

    def imu_ratio(self, graph: gtsam.NonlinearFactorGraph, result: gtsam.Values) -> float:
        """Chi-square per redundancy of the IMU factors of `graph` over that of the stereo
        factors (Huber: stereo outliers count linearly)."""
        chi_imu = 0.0
        for i in self.imu_at:
            chi_imu += 2.0 * graph.at(i).error(result)
        chi_st = 2.0 * self.stereo.error(result)  # in C++, summed in the same order
        if self.r_imu <= 0 or self.r_st <= 0 or chi_st <= 0.0:
            return math.nan
        return (chi_imu / self.r_imu) / (chi_st / self.r_st)


def _imu_rescaled(
    seg: SegmentGraph,
    graph: gtsam.NonlinearFactorGraph,
    imu_at: list[int],
    imu: ImuModel,
    accel_scale: float,
) -> gtsam.NonlinearFactorGraph:
    """The graph with every IMU factor (at the positions `imu_at`) preintegrated again, the
    accelerometer's covariances scaled; the other factors are shared."""
    params = imu.params_scaled(accel_scale)
    t = seg.kf_times
    out = gtsam.NonlinearFactorGraph(graph)
    for i in imu_at:
        f = graph.at(i)
        assert isinstance(f, gtsam.CombinedImuFactor)
        x0, v0, x1, v1, b0, b1 = f.keys()
        k = gtsam.Symbol(x1).index() - seg.kf_index0
        pim = gtsam.PreintegratedCombinedMeasurements(
            params, f.preintegratedMeasurements().biasHat()
        )
        integrate(pim, imu.data, t[k - 1], t[k])
        out.replace(i, gtsam.CombinedImuFactor(x0, v0, x1, v1, b0, b1, pim))
    return out


def imu_bridge(
    states: dict[int, NavEstimate],
    n_keyframes: int,
    k: int,
    t_ns: list[int],
    imu: ImuModel,
) -> list[F64] | None:
    """Poses at `t_ns` (sorted, after final keyframe k and not after k+1) from the IMU:
    preintegrated from keyframe k's final state, with the residual at k+1 (its final pose
    against the prediction) spread linearly in time; after the last keyframe, the
    prediction alone. None with a dropout, or outside that span."""
    a, b = states.get(k), states.get(k + 1)
    if a is None or not t_ns or t_ns[0] < a.t_ns:
        return None
    if b is None and k + 1 < n_keyframes:
        return None  # k + 1 exists but has no final state
    if b is not None and t_ns[-1] > b.t_ns:
        return None
    ab = bias(a.bg, a.ba)
    pim = gtsam.PreintegratedCombinedMeasurements(imu.params, ab)
    nav = gtsam.NavState(
        gtsam.Rot3(a.T_world_body[:3, :3]),
        gtsam.Point3(*a.T_world_body[:3, 3]),  # type: ignore[no-untyped-call]
        a.v_world,
    )
    pred, t_prev = [], a.t_ns
    for t in [*t_ns] + ([b.t_ns] if b is not None else []):
        if not integrate(pim, imu.data, t_prev, t).ok(imu.cfg.max_gap_s):
            return None
        t_prev = t
        pred.append(pim.predict(nav, ab).pose().matrix())
    if b is None:
        return pred
    end = pred.pop()
    dp = b.T_world_body[:3, 3] - end[:3, 3]
    dw = so3_log(b.T_world_body[:3, :3] @ end[:3, :3].T)
    span = float(b.t_ns - a.t_ns)
    out = []
    for t, T in zip(t_ns, pred, strict=True):
        s = (t - a.t_ns) / span
        out.append(make_T(so3_exp(s * dw) @ T[:3, :3], T[:3, 3] + s * dp))
    return out
