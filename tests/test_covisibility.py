"""The covisibility floor's set arithmetic (places/covisibility.py)."""

from __future__ import annotations

import numpy as np

from eurocslam.places.covisibility import n_shared


def test_shared_landmarks_count_as_intersect1d() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        a = np.unique(rng.integers(0, 60, rng.integers(0, 40)))
        b = np.unique(rng.integers(0, 60, rng.integers(0, 40)))
        assert n_shared(a, b) == np.intersect1d(a, b).size
    empty = np.zeros(0, np.int64)
    assert n_shared(empty, np.arange(5)) == n_shared(np.arange(5), empty) == 0
    assert n_shared(np.array([9]), np.array([1, 2, 3])) == 0  # beyond b's last value
