"""The loop gate: is a loop's drift one the estimate could have accumulated?

A loop recognised by appearance measures where the query keyframe is on the old map; the
difference with the estimate is the drift `D` (a world-frame move, `T_measured @
inv(T_estimated)`). An inlier count says how many points agree on it, not whether the pose they
agree on is plausible: the gate asks the estimator. With the query's and the recognised
keyframe's estimated poses perturbed on the left by xi_q and xi_c (world frame, [rotation,
translation]), the loop measures D ~ exp(xi_q - xi_c) plus the match's own error, so log(D) is
tested against the covariance of that difference (`loop_gate`). With an IMU, roll and pitch are
observed and a loop moves only yaw and position (`yaw_and_translation`), as ORB-SLAM3 and
VINS-Fusion correct 4 DoF. A loop is acted on only when its drift is also one the match tells
from its own error (`loop_significance`; with an IMU and `places.loop_significance_4dof`, the
correction that is applied, `applied_significance`).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2 as chi2_dist

from eurocslam.geometry import F64, make_T, rot_z, se3_exp, se3_log, yaw_of


def loop_gate(D: F64, cov_query: F64, cov_cand: F64, cov_match: F64) -> float:
    """The chi-square (6 DoF) of a loop's drift `D` against what the estimate allows.

    With the query's and the recognised keyframe's estimated poses perturbed on the left by
    xi_q and xi_c (world frame), the loop measures D ~ exp(xi_q - xi_c) plus the match's own
    error. The drift accumulated between the two keyframes is the part of the query's
    covariance the recognised keyframe did not already have (`cov_query - cov_cand`: both come
    from the same estimator, whose uncertainty only grows in the directions nothing observes:
    with an IMU, yaw and position; roll and pitch stay as small as gravity makes them), and the
    match adds its own (`cov_match`). A correction of degrees in roll or pitch, or of decimetres
    where the estimate is sure to centimetres, gives a large value."""
    S = psd(cov_query - cov_cand) + cov_match
    xi = se3_log(D)
    try:
        return float(xi @ np.linalg.solve(S, xi))
    except np.linalg.LinAlgError:
        return float("inf")


def loop_significance(D: F64, cov_match: F64) -> float:
    """The chi-square (6 DoF) of a loop's drift `D` against the match's own error alone: how
    far the measured drift is from none. The gate (`loop_gate`) asks whether the estimate could
    have drifted that much; this asks whether the loop saw a drift at all. A blurred view or
    few, far points measure a pose to degrees: a drift of a degree is then noise, and acting on
    it moves a good estimate away."""
    xi = se3_log(D)
    try:
        return float(xi @ np.linalg.solve(cov_match, xi))
    except np.linalg.LinAlgError:  # a match without error: any drift is seen
        return float("inf")


def applied_significance(D: F64, p: F64, cov_match: F64) -> float:
    """The chi-square (4 DoF) of the correction an IMU run applies (`yaw_and_translation`: the
    yaw about gravity and the move of the query's position `p`) against the match's covariance
    carried to it (first order). The 6-DoF test counts the drift's roll and pitch, which the
    IMU rules out and the correction drops; but a match's tilt error moves `p` through its
    lever arm, and the two are correlated in the match's covariance. V2_02 replica, world 101,
    with `backend.refound_prior_views`: 1.1 deg of measured tilt made a 0.9 deg / 6 cm match
    error significant on 6 DoF (17.6); the applied part, yaw -0.38 deg and 7.3 cm at the
    query, is 10.5 on 4 DoF against 13.3 at the same probability."""
    p = np.asarray(p, dtype=np.float64)

    def applied(T: F64) -> F64:
        return np.asarray(np.r_[yaw_of(T[:3, :3]), T[:3, :3] @ p + T[:3, 3] - p], np.float64)

    xi = se3_log(D)
    J = np.empty((4, 6))
    h = 1e-6
    for i in range(6):
        e = np.zeros(6)
        e[i] = h
        J[:, i] = (applied(se3_exp(xi + e)) - applied(se3_exp(xi - e))) / (2 * h)
    y = applied(D)
    try:
        return float(y @ np.linalg.solve(J @ cov_match @ J.T, y))
    except np.linalg.LinAlgError:
        return float("inf")


def drift_significant(D: F64, cov_match: F64, chi2: float, p_query: F64 | None = None) -> bool:
    """The loop's drift `D` is one its match tells from its own error: the 6-DoF
    `loop_significance` above `chi2`, or, with the query's position `p_query` (an IMU run with
    `places.loop_significance_4dof`), the applied correction's `applied_significance` above the
    4-DoF chi-square of the same probability."""
    if p_query is None:
        return loop_significance(D, cov_match) > chi2
    bound = float(chi2_dist.ppf(chi2_dist.cdf(chi2, 6), 4))
    return applied_significance(D, p_query, cov_match) > bound


def psd(M: F64) -> F64:
    """The nearest positive semi-definite matrix (negative eigenvalues set to 0)."""
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    return np.asarray((V * np.maximum(w, 0.0)) @ V.T, dtype=np.float64)


def yaw_and_translation(D: F64, p: F64) -> F64:
    """The part of a world-frame correction `D` an IMU leaves open: the rotation about world z
    (gravity) that D gives, and the translation that takes the point `p` where D takes it
    (roll and pitch are observed: a loop does not move them)."""
    R = rot_z(yaw_of(D[:3, :3]))
    return make_T(R, D[:3, :3] @ p + D[:3, 3] - R @ p)
