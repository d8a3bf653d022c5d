#!/usr/bin/env python
"""What rectifying a fisheye rig to a pinhole of a given field of view keeps, and costs.

For each `frontend.rectify_fov_deg` (`--fov`, degrees) on TUM-VI's stereo fisheye (the rig of
`synth --rig tumvi`: 512x512, equidistant, 0.101 m baseline), from the geometry alone:

- the share of the fisheye's image (its pixels with a ray) that lands inside the rectified
  image, and the solid angle the rectified image covers against the raw image's;
- pixels per degree at the rectified image's centre and at its left/right edge, against the raw
  fisheye's at the same angles (3.3 px/deg at its centre): a pinhole samples its centre more
  coarsely the wider it is and stretches its edges (interpolated, not new detail);
- the largest field of view whose every rectified pixel both cameras see (the cap);

and on frames of a rendered TUM-VI replica (`--replica`, a folder written by `synth --rig tumvi`,
every `--step`th frame): milliseconds to rectify a stereo pair, ORB keypoints kept on the left
image, stereo matches per frame, and the median depth of the matched points. One process, one
thread of OpenCV per call as the frontend uses it; compare rows of one run (a shared machine).

usage: .venv/bin/python benchmarks/bench_fisheye.py [--replica DIR] [--fov 90,120,150]
       [--size image|focal]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from eurocslam.dataset import open_sequence
from eurocslam.dataset.calib_sources import tumvi_rig
from eurocslam.dataset.rig import CameraCalib, StereoRig
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor
from eurocslam.frontend.stereo import StereoRectifier


def solid_angle(bearings: np.ndarray, pixel_area_sr: np.ndarray) -> float:
    """Sum of the per-pixel solid angles (steradians) of the pixels given."""
    return float(pixel_area_sr[np.isfinite(bearings).all(axis=1)].sum())


def pixel_solid_angles(rays: np.ndarray, h: int, w: int) -> np.ndarray:
    """Approximate solid angle of each pixel from its unit ray's neighbours (H*W,)."""
    r = rays.reshape(h, w, 3)
    du = np.linalg.norm(np.gradient(r, axis=1), axis=2)
    dv = np.linalg.norm(np.gradient(r, axis=0), axis=2)
    return np.nan_to_num(du * dv, nan=0.0).ravel()


def raw_px_per_deg(cam: CameraCalib, theta: float) -> float:
    """The raw fisheye's radial pixels per degree at `theta` from its axis."""
    h = 1e-4
    a = cam.model.project(np.array([[np.sin(theta), 0.0, np.cos(theta)]]))[0, 0]
    b = cam.model.project(np.array([[np.sin(theta + h), 0.0, np.cos(theta + h)]]))[0, 0]
    return float((b - a) / np.degrees(h))


def geometry_row(rig: StereoRig, fov: float, size: str) -> dict[str, float]:
    cam = rig.cam0
    w, h = cam.width, cam.height
    r = StereoRectifier(rig, 0.0, fov, size)
    g = r.geometry
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    raw_uv = np.column_stack([u.ravel(), v.ravel()])
    raw_rays = cam.model.unproject(raw_uv)
    raw_sr = pixel_solid_angles(raw_rays, h, w)
    rect = r.raw_to_rect0(raw_uv)
    inside = (
        np.isfinite(rect).all(axis=1)
        & (rect[:, 0] >= 0)
        & (rect[:, 0] <= g.width - 1)
        & (rect[:, 1] >= 0)
        & (rect[:, 1] <= g.height - 1)
    )
    valid = np.isfinite(raw_rays).all(axis=1)
    deg = np.pi / 180.0
    # px/deg at the rectified edge (u = 0 on the centre row): a pinhole's u = f tan(theta)
    # stretches the periphery, du/dtheta = f (1 + x^2)
    x_edge = (0.0 - g.cx) / g.fx
    return {
        "fov": r.rectification.fov_deg or fov,
        "width": float(g.width),
        "cap": r.rectification.fov_limit_deg or float("nan"),
        "fx": g.fx,
        "pixels_kept": float(inside.sum() / valid.sum()),
        "solid_angle_kept": float(raw_sr[inside].sum() / raw_sr[valid].sum()),
        "centre_px_per_deg": g.fx * deg,
        "edge_px_per_deg": g.fx * deg * (1.0 + x_edge * x_edge),
        "raw_edge_px_per_deg": raw_px_per_deg(cam, float(np.arctan(abs(x_edge)))),
    }


def frame_rows(fov: float, size: str, replica: Path, step: int) -> dict[str, float]:
    seq = open_sequence(replica, quiet=True)
    ex = Extractor.for_rig(seq.rig, FrontendConfig(rectify_fov_deg=fov, rectify_size=size))
    rect_ms, kps, matches, depths = [], [], [], []
    for k, fr in enumerate(seq.frames()):
        if k % step or fr.left is None or fr.right is None:
            continue
        t = time.perf_counter()
        ex.rectifier.rectify_left(fr.left)
        ex.rectifier.rectify_right(fr.right)
        rect_ms.append((time.perf_counter() - t) * 1e3)
        ff = ex.extract(fr)
        kps.append(len(ff.left))
        ok = ff.stereo.valid
        matches.append(int(ok.sum()))
        if ok.any():
            depths.append(float(np.median(ff.stereo.depth[ok])))
    return {
        "frames": float(len(kps)),
        "rectify_ms": statistics.median(rect_ms),
        "keypoints": statistics.mean(kps),
        "stereo_matches": statistics.mean(matches),
        "median_depth_m": statistics.median(depths),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fov", default="90,105,120,135,150", help="fields of view [deg]")
    ap.add_argument("--replica", type=Path, help="a TUM-VI replica (synth --rig tumvi)")
    ap.add_argument("--step", type=int, default=20, help="every Nth frame of the replica")
    ap.add_argument(
        "--size", default="image", choices=("image", "focal"), help="frontend.rectify_size"
    )
    args = ap.parse_args()
    fovs = [float(x) for x in args.fov.split(",")]
    rig = tumvi_rig()
    print(
        f"# TUM-VI rig: {rig.cam0.width}x{rig.cam0.height}, fx {rig.cam0.fx:.2f}, "
        f"baseline {rig.baseline:.4f} m; raw centre {rig.cam0.fx * np.pi / 180:.2f} px/deg"
    )
    head = (
        f"| fov [deg] ({args.size}) | fx [px] | raw pixels kept | solid angle kept "
        "| px/deg centre (raw 3.33) | px/deg edge (raw there) |"
    )
    if args.replica:
        head += " rectify pair [ms] | ORB kept | stereo matches | median depth [m] |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for fov in fovs:
        g = geometry_row(rig, fov, args.size)
        row = (
            f"| {g['fov']:.1f} ({g['width']:.0f} px) | {g['fx']:.1f} | "
            f"{100 * g['pixels_kept']:.1f} % | "
            f"{100 * g['solid_angle_kept']:.1f} % | {g['centre_px_per_deg']:.2f} | "
            f"{g['edge_px_per_deg']:.2f} ({g['raw_edge_px_per_deg']:.2f}) |"
        )
        if args.replica:
            f = frame_rows(fov, args.size, args.replica, args.step)
            row += (
                f" {f['rectify_ms']:.2f} | {f['keypoints']:.0f} | {f['stereo_matches']:.0f} | "
                f"{f['median_depth_m']:.2f} |"
            )
        print(row, flush=True)
    print(f"(cap: the widest field of view both cameras see entirely: {g['cap']:.2f} deg)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
