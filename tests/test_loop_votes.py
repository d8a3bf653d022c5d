"""When a recognised loop moves the online estimate (pipeline/places.py `PlaceStage.loop`): the
verified matches are given (a stub recognizer), so that only the stage's rules are tested."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from eurocslam.config import PlacesConfig
from eurocslam.geometry import F64, make_T, so3_exp
from eurocslam.pipeline.places import FrameBook, PlaceEvent, PlaceStage
from eurocslam.places.recognizer import PlaceMatch, PlaceView
from eurocslam.places.vocabulary import BowVector


class StubRecognizer:
    """Answers every query with `match` (when the stage accepts its key)."""

    def __init__(self) -> None:
        self.match: PlaceMatch | None = None

    def add(self, view: PlaceView) -> None:
        pass

    def find(
        self, view: PlaceView, accept: Callable[[int], bool], points: object
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


def _corrections(
    inliers: list[int], cfg: PlacesConfig
) -> tuple[list[F64 | None], list[PlaceEvent]]:
    """Keyframes 20 s after a filed one each recognise it with `inliers`; the match puts them
    1.5 deg and 12 cm away from where the estimate has them. The D acted on, per keyframe, and
    the events reported."""
    stub = StubRecognizer()
    book = FrameBook()
    book.new_segment()
    stage = PlaceStage(stub, cfg, book, lambda seg, ids: np.full((ids.size, 3), np.nan))  # type: ignore[arg-type]
    stage.file(_view(0, 0.0), 0, 0, np.eye(4))
    drift = make_T(so3_exp(np.radians([0.0, 0.0, 1.5])), np.array([0.12, 0.0, 0.0]))
    out = []
    for i, n in enumerate(inliers):
        T_est = make_T(np.eye(3), np.array([0.5 * i, 0.0, 0.0]))
        stub.match = PlaceMatch(0, 0.5, drift @ T_est, n)
        fix = stage.loop(_view(i + 1, 20.0 + i), 0, T_est)
        out.append(None if fix is None else fix.D)
    return out, stage.events


def test_two_agreeing_loops_with_enough_inliers_correct_the_drift() -> None:
    cfg = PlacesConfig()
    fixes, events = _corrections([cfg.loop_correct_min_inliers, 200], cfg)
    assert fixes[0] is None  # one keyframe is not enough
    assert fixes[1] is not None
    np.testing.assert_allclose(np.degrees(np.arccos((np.trace(fixes[1][:3, :3]) - 1) / 2)), 1.5)
    assert [(e.kind, round(e.correction_deg, 6)) for e in events] == [("loop", 1.5)]


@pytest.mark.parametrize("weak", [0, 1])
def test_a_coarse_match_among_the_votes_corrects_nothing(weak: int) -> None:
    """Consecutive keyframes matched with few inliers can agree on the same wrong drift: the
    loop is reported, the estimate is not moved."""
    cfg = PlacesConfig()
    inliers = [200, 200]
    inliers[weak] = cfg.loop_correct_min_inliers - 1
    fixes, events = _corrections(inliers, cfg)
    assert fixes == [None, None]
    assert [(e.kind, e.correction_m, e.n_inliers) for e in events] == [("loop", 0.0, inliers[1])]


def test_without_online_correction_loops_are_only_reported() -> None:
    fixes, events = _corrections([200, 200], PlacesConfig(correct_loops_online=False))
    assert fixes == [None, None] and [e.correction_m for e in events] == [0.0]
