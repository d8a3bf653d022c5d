"""Test helpers for place recognition: rendered views, and a world whose every surface carries
the same periodic texture (two different places that look alike: a false-loop trap).

    scene = repetitive_scene(seed=0)                 # a built-in flight in a tiled room
    a, b = far_apart_frames(scene, min_distance_m=2.0)
    left_a, _ = scene.image(a, 0)                    # raw (distorted) cam0 images, as synth writes
    left_b, _ = scene.image(b, 0)

Appearance alone proposes `b` for `a` (the same tiles everywhere); only a geometric check (the
matches' 3D points do not agree with one rigid motion, or agree with the wrong one) can reject
it, which is what a loop-closure test on this scene must show.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.features import OrbExtractor
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.synth import Scene, SynthSpec
from eurocslam.synth.world import GUTTER, MIP_LEVELS, World, make_texture


def repetitive_world(world: World, seed: int = 0, tile_texels: int = 128) -> World:
    """The same world geometry with every face covered by one periodic tile (`tile_texels`
    texels: 64 cm at the default 5 mm texels), mip levels included."""
    rng = np.random.default_rng([seed, 0x7E7])
    tile = make_texture(tile_texels, tile_texels, rng, mean=150.0, spread=60.0)
    atlas = [np.zeros_like(a) for a in world.atlas]
    for i in range(world.n_faces):
        w, h = int(world.tex_w[i]), int(world.tex_h[i])
        reps = (-(-h // tile_texels), -(-w // tile_texels))
        level = np.ascontiguousarray(np.tile(tile, reps)[:h, :w])
        for lv in range(MIP_LEVELS):
            g = GUTTER >> lv
            y0 = (int(world.off_y[i]) - GUTTER) >> lv
            x0 = (int(world.off_x[i]) - GUTTER) >> lv
            padded = cv2.copyMakeBorder(level, g, g, g, g, cv2.BORDER_REPLICATE)
            atlas[lv][y0 : y0 + padded.shape[0], x0 : x0 + padded.shape[1]] = padded
            if lv + 1 < MIP_LEVELS:
                level = cv2.resize(
                    level, (level.shape[1] // 2, level.shape[0] // 2), interpolation=cv2.INTER_AREA
                )
    return replace(world, atlas=atlas)


def repetitive_scene(seed: int = 0, duration_s: float = 30.0) -> Scene:
    """A built-in flight whose room, boxes and pillars all carry the same periodic texture."""
    scene = Scene.build(SynthSpec(duration_s=duration_s, seed=seed))
    scene.world = repetitive_world(scene.world, seed)
    return scene


def camera_positions(scene: Scene) -> np.ndarray:
    """(n, 3) body positions of every frame."""
    return np.asarray(scene.motion.spline.positions(scene.t_s(scene.cam_t_ns)))


def far_apart_frames(
    scene: Scene, min_distance_m: float = 2.0, start: int = 100
) -> tuple[int, int]:
    """Two frames whose cameras are at least `min_distance_m` apart and look in directions
    more than 60 deg apart (different places by any standard), both in flight."""
    p = camera_positions(scene)
    n = p.shape[0]
    dirs = np.array(
        [scene.T_world_body(float(scene.t_s(scene.cam_t_ns[k])))[:3, 2] for k in range(n)]
    )
    far = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2) >= min_distance_m
    turned = dirs @ dirs.T < 0.5
    for a in range(start, n):
        partners = np.flatnonzero(far[a] & turned[a])
        if partners.size:
            return a, int(partners[-1])
    raise AssertionError("no frame pair far enough apart in this flight")


def left_descriptors(scene: Scene, frames: list[int]) -> list[np.ndarray]:
    """ORB descriptors of the rectified left images of `frames`, as the frontend extracts."""
    cfg = FrontendConfig()
    rect = StereoRectifier.for_config(scene.rig, cfg)
    g = rect.geometry
    orb = OrbExtractor(cfg, g.width, g.height)
    return [orb.extract(rect.rectify_left(scene.image(k, 0)[0])).desc for k in frames]
