"""Shared fixtures. Real EuRoC data lives in ../shared/data/euroc beside the checkout, the real
KITTI excerpt in ../shared/data/kitti_excerpt; tests that need them skip cleanly where they are
absent (a user's machine)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_EUROC = Path(os.environ.get("EUROCSLAM_SHARED_EUROC", REPO.parent / "shared/data/euroc"))
SHARED_KITTI = Path(
    os.environ.get("EUROCSLAM_SHARED_KITTI", REPO.parent / "shared/data/kitti_excerpt")
)


def pytest_configure(config: pytest.Config) -> None:
    """Handle SIGINT as a Python started normally does (KeyboardInterrupt), also when pytest
    was started with SIGINT ignored: the background job of a non-interactive shell (`.ci/run &`
    from a script) inherits an ignored SIGINT, and so would every process a test starts (a
    disposition that survives exec). Python then installs no SIGINT handler: the Ctrl-C tests'
    SIGINT would be ignored by `eurocslam bench` (and by `ray start`'s workers and the runs),
    which never exits. A handled SIGINT here is a default one in every child."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def _need(path: Path, what: str = "real EuRoC data") -> Path:
    if not path.exists():
        pytest.skip(f"{what} not available ({path})")
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


@pytest.fixture(scope="session")
def kitti_excerpt() -> Path:
    """The real KITTI odometry excerpt's root: sequences/k2 (51 stereo frames, 1241x376, no IMU)
    and poses/k2.txt."""
    return _need(SHARED_KITTI / "sequences" / "k2", "the real KITTI excerpt").parent.parent
