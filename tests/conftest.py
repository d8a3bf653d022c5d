"""Shared fixtures. Real EuRoC data lives in ../shared/data/euroc beside the checkout; tests that
need it skip cleanly where it is absent (a user's machine)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_EUROC = Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"real EuRoC data not available ({path})")
    return path


@pytest.fixture(scope="session")
def euroc_dir() -> Path:
    """../shared/data/euroc (skip if absent)."""
    return _need(SHARED_EUROC)


@pytest.fixture(scope="session")
def v101_micro() -> Path:
    """95 real stereo frames of V1_01 (drone still), full real IMU."""
    return _need(SHARED_EUROC / "V1_01_easy_micro")


@pytest.fixture(scope="session")
def mh01_first5() -> Path:
    """First 5 real stereo frames of MH_01 with every sensor.yaml."""
    return _need(SHARED_EUROC / "MH_01_easy_first5")
