"""Views rendered by the project's own generator: ORB descriptors and ground-truth camera poses.

The vocabulary's training data and the retrieval benchmark's sequences. A view is the left
image of a `eurocslam.synth` scene at one instant, rectified and run through the frontend's ORB
extractor exactly as a SLAM run would (`FrontendConfig` defaults), with the rectified camera's
true pose. Nothing is written to disk.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.features import OrbExtractor
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.geometry import F64
from eurocslam.synth import Scene, SynthSpec
from eurocslam.timebase import ns_to_s


@dataclass(frozen=True)
class View:
    """One rendered left image's ORB features and its true rectified-camera pose."""

    t_ns: int
    T_world_rect0: F64  # 4x4
    uv: F64  # (n, 2) rectified pixels
    desc: NDArray[np.uint8]  # (n, 32)


def views(spec: SynthSpec, step_s: float, config: FrontendConfig | None = None) -> Iterator[View]:
    """Every `step_s` seconds of the sequence `spec` describes (rounded to whole frames)."""
    cfg = config or FrontendConfig()
    scene = Scene.build(spec)
    rect = StereoRectifier.for_config(scene.rig, cfg)
    g = rect.geometry
    orb = OrbExtractor(cfg, g.width, g.height)
    t = scene.cam_t_ns
    stride = max(1, round(step_s / max(float(ns_to_s(t[1] - t[0])), 1e-9)))
    for k in range(0, t.size, stride):
        img, _ = scene.image(k, 0)
        feats = orb.extract(rect.rectify_left(img))
        T_world_rect0 = scene.T_world_body(float(scene.t_s(t[k]))) @ g.T_body_rect0
        yield View(int(t[k]), T_world_rect0, feats.uv, feats.desc)


def replica_spec(groundtruth: Path, seed: int, duration_s: float | None = None) -> SynthSpec:
    """A rendered replica of a recorded motion (EuRoC ground truth) in world `seed`."""
    return SynthSpec(trajectory=groundtruth, seed=seed, duration_s=duration_s)
