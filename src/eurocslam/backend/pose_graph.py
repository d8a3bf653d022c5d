"""The keyframes of a segment as a pose graph: the starting point of the final batch after loop
closures.

A loop closure moves the online estimate at once (`KeyframeEstimator.reanchor`): the keyframes
after it are in the corrected frame, those before it in the drifted one. Started from such
values, the final batch would have to close the loop from a jump. Instead the keyframe poses are
first spread over the loop: odometry edges between consecutive keyframes (their online relative
poses; across a correction, the pose before it), loop edges from place recognition, one prior on
the first keyframe; Levenberg-Marquardt on that graph is fast (poses only). Every other variable
moves with the keyframe it belongs to.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from eurocslam.backend.factors import pose
from eurocslam.geometry import F64, inv_T


@dataclass(frozen=True)
class LoopEdge:
    """Keyframe `k_query` seen from keyframe `k_cand`: `T_cand_query` (body to body)."""

    k_cand: int
    k_query: int
    T_cand_query: F64


def spread_loops(
    poses: dict[int, F64],
    before: dict[int, F64],
    loops: list[LoopEdge],
    rot_sigma: float,
    pos_sigma: float,
) -> dict[int, F64]:
    """Keyframe poses with the loops closed. `poses`: the online estimates (index -> pose);
    `before`: for each keyframe where a correction was applied, its pose before it."""
    keys = sorted(poses)
    if len(keys) < 2 or not loops:
        return dict(poses)
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.array([rot_sigma] * 3 + [pos_sigma] * 3))
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(X(keys[0]), pose(poses[keys[0]]), odo))
    for a, b in itertools.pairwise(keys):
        T_b = before.get(b, poses[b])
        graph.add(gtsam.BetweenFactorPose3(X(a), X(b), pose(inv_T(poses[a]) @ T_b), odo))
    for e in loops:
        if e.k_cand in poses and e.k_query in poses:
            graph.add(
                gtsam.BetweenFactorPose3(X(e.k_cand), X(e.k_query), pose(e.T_cand_query), odo)
            )
    for k in keys:
        values.insert(X(k), pose(poses[k]))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    try:
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    except RuntimeError:
        return dict(poses)
    return {k: result.atPose3(X(k)).matrix() for k in keys}
