"""Tracking does not need a motion prior: with `frontend.motion_prior: false` every frame is
tracked from the last pose alone, and where the motion is too fast for the projection search
the descriptor path (matching without a prior, PnP RANSAC) finds the pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eurocslam.config import RunConfig
from eurocslam.dataset import open_sequence
from eurocslam.eval.align import align
from eurocslam.frontend.config import FrontendConfig
from eurocslam.pipeline.outputs import RunResult
from eurocslam.pipeline.slam import SlamPipeline
from eurocslam.synth import SynthSpec, synthesize


@pytest.fixture(scope="module")
def fast_flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 s of a fast flight: up to 3 m/s and 3 rad/s (up to ~60 px of image motion a frame)."""
    spec = SynthSpec.tiny(seed=3, duration_s=3.0, max_speed=3.0, max_yaw_rate=3.0)
    return synthesize(spec, tmp_path_factory.mktemp("synth") / "fast")


def _ate(seq_path: Path, res: RunResult) -> float:
    gt = open_sequence(seq_path).groundtruth
    assert gt is not None
    p_ref = gt.p[np.searchsorted(gt.t_ns, res.final.t_ns)]
    p_est = res.final.p
    a = align("se3", p_ref, p_est)
    return float(np.sqrt(np.mean(np.sum((p_ref - (p_est @ a.R.T + a.t)) ** 2, axis=1))))


@pytest.mark.parametrize("mode", ["visual-only", "stereo-inertial"])
def test_every_frame_is_tracked_without_a_motion_prior(fast_flight: Path, mode: str) -> None:
    no_prior = RunConfig(mode=mode, frontend=FrontendConfig(motion_prior=False))
    res = SlamPipeline(open_sequence(fast_flight), no_prior).run()
    s = res.summary
    assert s.coverage == 1.0 and s.segments == 1, s.lines()
    assert s.state_frames.get("LOST", 0) == 0
    paths = s.track_paths
    assert paths.get("lost", 0) == 0
    assert paths.get("descriptor", 0) >= 5, paths  # the projection from the last pose fails there
    assert sum(paths.values()) == s.frames - 1  # every frame after the first was tracked
    assert _ate(fast_flight, res) < 0.02


def test_the_prior_keeps_the_projection_path(fast_flight: Path) -> None:
    res = SlamPipeline(open_sequence(fast_flight), RunConfig(mode="visual-only")).run()
    paths = res.summary.track_paths
    assert paths.get("projection", 0) >= res.summary.frames - 5, paths
    assert "tracked by: projection" in "\n".join(res.summary.lines())
    assert res.summary.to_dict()["track_paths"] == paths
