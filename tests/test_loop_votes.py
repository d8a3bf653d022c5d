"""When a recognised loop moves the online estimate (pipeline/places.py `PlaceStage.loop`): the
verified matches are given (a stand-in recognizer), so that only the stage's rules are tested:
consistency over keyframes, and the gate of the drift against the estimator's uncertainty."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest
from gtsam import Pose3

from eurocslam.config import PlacesConfig
from eurocslam.geometry import F64, make_T, se3_log, so3_exp, so3_log
from eurocslam.pipeline.frames import WorldFrames
from eurocslam.pipeline.places import PlaceStage
from eurocslam.pipeline.records import PlaceEvent
from eurocslam.places.loop_gate import loop_gate, loop_significance, yaw_and_translation
from eurocslam.places.recognizer import PlaceMatch, PlaceView
from eurocslam.places.vocabulary import BowVector


class GivenMatches:
    """Answers every query with `match` (when the stage accepts its key)."""

    def __init__(self) -> None:
        self.match: PlaceMatch | None = None

    def add(self, view: PlaceView) -> None:
        pass

    def find(
        self, view: PlaceView, accept: Callable[[int], bool], points: object, min_score: float
    ) -> PlaceMatch | None:
        m = self.match
        return m if m is not None and accept(m.key) else None


def _view(key: int, t_s: float) -> PlaceView:
    z = np.zeros((0, 3))
    return PlaceView(
        key,
        round(t_s * 1e9),
        z,
        np.zeros((0, 32), np.uint8),
        np.zeros(0, np.int64),
        np.zeros(0, np.int32),
        z,
        BowVector(np.zeros(0, np.int32), np.zeros(0)),
    )


def _cov(rot_deg: tuple[float, float, float], pos_m: float) -> F64:
    return np.diag([*np.radians(rot_deg) ** 2, *[pos_m**2] * 3])


# a visual-only estimate 20 s after the recognised keyframe: 2 deg and 20 cm of drift allowed
LOOSE = _cov((2.0, 2.0, 2.0), 0.2)
# a match of many inliers: 0.1 deg, 1 cm
TIGHT_MATCH = _cov((0.1, 0.1, 0.1), 0.01)
DRIFT = make_T(so3_exp(np.radians([0.0, 0.0, 1.5])), np.array([0.12, 0.0, 0.0]))


def _corrections(
    cfg: PlacesConfig,
    cov_query: F64 | None = LOOSE,
    drift: F64 = DRIFT,
    inliers: int = 200,
    cov_match: F64 = TIGHT_MATCH,
    inertial: bool = False,
) -> tuple[list[F64 | None], list[PlaceEvent]]:
    """Two keyframes 20 s after a filed one (covariance zero) each recognise it; the match puts
    them `drift` away from where the estimate has them, the estimator's covariance of their
    pose is `cov_query` (None: no gate). The D acted on, per keyframe, and the events."""
    given = GivenMatches()
    frames = WorldFrames()
    frames.new_segment()
    stage = PlaceStage(given, cfg, frames, lambda seg, ids: np.full((ids.size, 3), np.nan))  # type: ignore[arg-type]
    stage.file(_view(0, 0.0), 0, 0, np.eye(4), np.zeros((6, 6)))
    out, events = [], []
    for i in range(2):
        T_est = make_T(np.eye(3), np.array([0.5 * i, 0.0, 0.0]))
        given.match = PlaceMatch(0, 0.5, drift @ T_est, inliers, cov_match)
        asked = None if cov_query is None else (lambda: cov_query)
        answer = stage.loop(_view(i + 1, 20.0 + i), 0, T_est, asked, inertial=inertial)
        events += answer.events
        out.append(None if answer.loop is None else answer.loop.D)
    return out, events


def test_two_agreeing_loops_within_the_estimates_uncertainty_correct_the_drift() -> None:
    fixes, events = _corrections(PlacesConfig())
    assert fixes[0] is None  # one keyframe is not enough
    assert fixes[1] is not None
    np.testing.assert_allclose(np.degrees(np.linalg.norm(so3_log(fixes[1][:3, :3]))), 1.5)
    (e,) = events
    assert (e.kind, round(e.correction_deg, 6), e.refused) == ("loop", 1.5, False)
    assert 0 < e.gate_chi2 < PlacesConfig().loop_gate_chi2


def test_a_loop_with_many_inliers_that_the_estimate_cannot_have_drifted_is_refused() -> None:
    """200 inliers agree on 1.5 deg and 12 cm, twice; the estimator is sure of its pose to 0.2
    deg and 1 cm since that keyframe: the loop is reported as refused, nothing moves."""
    fixes, events = _corrections(PlacesConfig(), cov_query=_cov((0.2, 0.2, 0.2), 0.01))
    assert fixes == [None, None]
    (e,) = events
    assert e.refused and e.correction_m == 0.0 and e.n_inliers == 200
    assert e.gate_chi2 > 5 * PlacesConfig().loop_gate_chi2
    assert e.drift_m == pytest.approx(0.12, abs=1e-9)
    assert e.drift_deg == pytest.approx(1.5, abs=1e-9)
    assert e.to_dict()["refused"] is True


def test_a_drift_within_the_matchs_own_error_moves_nothing() -> None:
    """The same drift from a match that measures it only to 2 deg and 20 cm (a blurred view,
    few or far points): the gate passes it (the estimate cannot call it wrong either), but the
    loop cannot tell 1.5 deg / 12 cm from no drift at all: reported, not applied, not refused."""
    tight = _cov((0.2, 0.2, 0.2), 0.01)
    fixes, events = _corrections(PlacesConfig(), cov_query=tight, cov_match=LOOSE)
    assert fixes == [None, None]
    (e,) = events
    assert not e.refused and e.gate_chi2 < PlacesConfig().loop_gate_chi2
    assert e.correction_m == 0.0 and e.drift_deg == pytest.approx(1.5)


def test_the_loops_significance_is_the_drifts_distance_from_none() -> None:
    D = make_T(so3_exp(np.radians([0.0, 0.0, 1.0])), np.array([0.1, 0.0, 0.0]))
    xi = se3_log(D)
    assert loop_significance(D, LOOSE) == pytest.approx(xi @ np.linalg.solve(LOOSE, xi))
    assert loop_significance(D, TIGHT_MATCH) > 100 * loop_significance(D, LOOSE)
    assert loop_significance(D, np.zeros((6, 6))) == float("inf")


def test_roll_and_pitch_that_gravity_fixes_are_not_corrected() -> None:
    """A stereo-inertial estimate: yaw and position uncertain (2 deg, 20 cm), roll and pitch
    to 0.05 deg. A loop drift of 1.5 deg in yaw passes; the same 1.5 deg in roll does not."""
    imu_like = _cov((0.05, 0.05, 2.0), 0.2)
    yaw_fix, _ = _corrections(PlacesConfig(), cov_query=imu_like)
    roll = make_T(so3_exp(np.radians([1.5, 0.0, 0.0])), np.array([0.12, 0.0, 0.0]))
    roll_fix, events = _corrections(PlacesConfig(), cov_query=imu_like, drift=roll)
    assert yaw_fix[1] is not None and roll_fix == [None, None]
    assert events[0].refused


def test_the_gate_is_the_drifts_mahalanobis_distance() -> None:
    rng = np.random.default_rng(3)
    xi = np.concatenate([np.radians(rng.normal(size=3)), 0.1 * rng.normal(size=3)])
    D = Pose3.Expmap(xi).matrix()  # a drift whose twist is exactly xi
    np.testing.assert_allclose(se3_log(D), xi, atol=1e-12)
    S = LOOSE + TIGHT_MATCH
    assert loop_gate(D, LOOSE, np.zeros((6, 6)), TIGHT_MATCH) == pytest.approx(
        float(xi @ np.linalg.solve(S, xi)), rel=1e-9
    )
    # what the recognised keyframe was already unsure of is no drift between the two
    assert loop_gate(D, LOOSE, LOOSE, TIGHT_MATCH) == pytest.approx(
        float(xi @ np.linalg.solve(TIGHT_MATCH, xi)), rel=1e-9
    )


def test_yaw_and_translation_keep_the_querys_corrected_position() -> None:
    D = make_T(so3_exp(np.radians([0.8, -0.5, 3.0])), np.array([0.1, -0.2, 0.05]))
    p = np.array([2.0, 1.0, 1.5])
    D4 = yaw_and_translation(D, p)
    np.testing.assert_allclose(D4[:3, :3] @ p + D4[:3, 3], D[:3, :3] @ p + D[:3, 3])
    np.testing.assert_allclose(D4[:3, :3] @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-12)
    yaw = np.degrees(np.arctan2(D4[1, 0], D4[0, 0]))
    assert yaw == pytest.approx(np.degrees(np.arctan2(D[1, 0], D[0, 0])))


def test_without_an_estimators_covariance_there_is_no_gate() -> None:
    fixes, events = _corrections(PlacesConfig(), cov_query=None)
    assert fixes[1] is not None and not events[0].refused


def test_without_online_correction_loops_are_only_reported() -> None:
    fixes, events = _corrections(PlacesConfig(correct_loops_online=False))
    assert fixes == [None, None] and [e.correction_m for e in events] == [0.0]


class ScoredViews(GivenMatches):
    """Keyframes with landmarks and fixed appearance scores against any query; records the
    least score `find` was asked for."""

    def __init__(self, scores: dict[int, float]) -> None:
        super().__init__()
        self.views: dict[int, PlaceView] = {}
        self.asked: list[float] = []
        scores_ = scores

        class Db:
            def score(self, key: int, bow: BowVector) -> float:
                return scores_[key]

        self.db = Db()

    def add(self, view: PlaceView) -> None:
        self.views[view.key] = view

    def get(self, key: int) -> PlaceView:
        return self.views[key]

    def find(
        self, view: PlaceView, accept: Callable[[int], bool], points: object, min_score: float
    ) -> PlaceMatch | None:
        self.asked.append(min_score)
        return None


def _with_landmarks(v: PlaceView, ids: range) -> PlaceView:
    return dataclasses.replace(v, landmark_ids=np.array(list(ids), np.int64))


def test_a_loop_candidate_must_look_like_the_query_as_much_as_its_covisible_neighbours() -> None:
    """DBoW2's normalisation: the least score of the query against the recent keyframes that
    share at least 15 landmarks with it is the floor a candidate must reach to be verified;
    keyframes sharing fewer are not its neighbours."""
    views = ScoredViews({0: 0.5, 1: 0.3, 2: 0.1})
    frames = WorldFrames()
    frames.new_segment()
    stage = PlaceStage(views, PlacesConfig(), frames, lambda s, ids: np.full((ids.size, 3), np.nan))  # type: ignore[arg-type]
    stage.file(_with_landmarks(_view(0, 0.0), range(0, 100)), 0, 0, np.eye(4))
    stage.file(_with_landmarks(_view(1, 0.1), range(80, 200)), 0, 1, np.eye(4))
    stage.file(_with_landmarks(_view(2, 0.2), range(300, 400)), 0, 2, np.eye(4))
    query = _with_landmarks(_view(3, 0.3), range(70, 310))  # shares 30, 120 and 10 landmarks
    stage.loop(query, 0, np.eye(4), index=3)
    stage.loop(_with_landmarks(_view(4, 0.4), range(1000, 1100)), 0, np.eye(4), index=4)
    assert views.asked == [pytest.approx(0.3), 0.0]


@pytest.mark.parametrize("inertial", [False, True])
def test_with_an_imu_the_significance_is_that_of_the_correction_applied(inertial: bool) -> None:
    """`places.loop_significance_4dof`: a drift of 1.3 deg of roll and 2 mm, measured by a match
    that knows tilt to 0.3 deg, is significant on 6 DoF (the tilt alone: (1.3 / 0.3)^2 = 18.8).
    An IMU run applies only yaw and the move of the query's position (here ~2 mm: the query
    sits on the roll axis), which the match cannot tell from none: kept, not applied. Without an
    IMU the whole drift is applied, as before; 1.5 deg of yaw and 12 cm stay applied either
    way."""
    cfg = PlacesConfig(loop_significance_4dof=True)
    match = _cov((0.3, 0.3, 0.3), 0.01)
    tilt = make_T(so3_exp(np.radians([1.3, 0.0, 0.0])), np.array([0.002, 0.0, 0.0]))
    fixes, events = _corrections(cfg, drift=tilt, cov_match=match, inertial=inertial)
    assert (fixes[1] is None) == inertial
    (e,) = events
    assert not e.refused
    fixes, _ = _corrections(cfg, cov_match=match, inertial=inertial)  # yaw and 12 cm
    assert fixes[1] is not None
    # off (the default): the 6-DoF test, with or without an IMU
    fixes, _ = _corrections(PlacesConfig(), drift=tilt, cov_match=match, inertial=inertial)
    assert fixes[1] is not None


def test_applied_significance_carries_the_matchs_covariance_to_the_applied_correction() -> None:
    """`applied_significance` against a Monte Carlo of the match's error: the chi-square of the
    applied correction (yaw, move of p) under the sampled covariance of what is applied."""
    from eurocslam.geometry import se3_exp, yaw_of
    from eurocslam.places.loop_gate import applied_significance

    rng = np.random.default_rng(3)
    D = make_T(so3_exp(np.radians([0.4, -0.9, 0.5])), np.array([0.01, -0.02, 0.04]))
    p = np.array([1.5, -0.5, 0.9])
    A = rng.normal(size=(6, 6)) * np.r_[[np.radians(0.3)] * 3, [0.03] * 3][:, None]
    cov = A @ A.T + np.diag([1e-6] * 3 + [1e-5] * 3)

    def applied(T: np.ndarray) -> np.ndarray:
        return np.r_[yaw_of(T[:3, :3]), T[:3, :3] @ p + T[:3, 3] - p]

    xi = se3_log(D)
    ys = np.array([applied(se3_exp(x)) for x in rng.multivariate_normal(xi, cov, 20000)])
    y = applied(D)
    expected = y @ np.linalg.solve(np.cov(ys.T), y)
    assert applied_significance(D, p, cov) == pytest.approx(expected, rel=0.05)
