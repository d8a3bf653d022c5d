"""The covisibility floor of a loop query: the least appearance score a candidate needs.

Among the segment's last `COVISIBLE_LOOKBACK` keyframes, those that share at least
`COVISIBLE_MIN_SHARED` landmarks with the query are its covisible neighbours (ORB-SLAM's
covisibility graph edge). A loop candidate that looks less like the query than those neighbours
do is no evidence of a revisit; DBoW2 / ORB-SLAM normalise loop scores this way, and most
queries then verify no candidate.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from eurocslam.places.recognizer import PlaceRecognizer, PlaceView

COVISIBLE_LOOKBACK = 10
COVISIBLE_MIN_SHARED = 15
# landmark sets kept: a query's neighbours and the query (older ones are made again if asked)
_KEPT = 2 * COVISIBLE_LOOKBACK


def n_shared(a: NDArray[np.int64], b: NDArray[np.int64]) -> int:
    """How many values two sorted unique arrays share (`np.intersect1d(a, b).size`)."""
    if a.size == 0 or b.size == 0:
        return 0
    pos = np.minimum(np.searchsorted(b, a), b.size - 1)
    return int(np.count_nonzero(b[pos] == a))


class Covisibility:
    """Covisibility floors over the keyframes of one `PlaceRecognizer`."""

    def __init__(self, recognizer: PlaceRecognizer) -> None:
        self._recognizer = recognizer
        self._sets: dict[int, NDArray[np.int64]] = {}  # key -> `landmark_set`

    def floor(self, view: PlaceView, recent: Iterable[int | None]) -> float:
        """The least appearance score of `view` against those of the `recent` keyframes (keys;
        None: not filed) that are covisible with it (0 where none is)."""
        ids = self.landmark_set(view)
        floor = float("inf")
        for key in recent:
            if key is None:
                continue
            other = self.landmark_set(self._recognizer.get(key))
            if n_shared(ids, other) >= COVISIBLE_MIN_SHARED:
                floor = min(floor, self._recognizer.db.score(key, view.bow))
        return floor if floor != float("inf") else 0.0

    def landmark_set(self, view: PlaceView) -> NDArray[np.int64]:
        """The landmarks a view observes, sorted and unique (kept for the latest `_KEPT`
        keyframes: each is one of the next `COVISIBLE_LOOKBACK` queries' neighbours)."""
        s = self._sets.get(view.key)
        if s is None:
            s = np.unique(view.landmark_ids[view.landmark_ids >= 0])
            if view.key >= 0:
                self._sets[view.key] = s
                if len(self._sets) > _KEPT:  # the oldest filed: no longer anyone's neighbour
                    del self._sets[next(iter(self._sets))]
        return s
