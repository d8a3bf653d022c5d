"""Foxglove layouts for `run.mcap`: the shipped ones (`layouts/`) and the one `run` writes for its
own run (`OUT/layout.json`, `OUT/layout-1.48.json`).

The template is `eurocslam/data/layouts/eurocslam.json` (today's Foxglove), framed for EuRoC's
drone: the 3D panel follows the body at 9 m, and four plots show the IMU and its biases. Everything
else is derived from it:

* `translate_to_studio_148`: the same layout for Foxglove Studio 1.48 (its image panel is
  `ImageViewPanel`);
* `visual_only`: a run without an IMU (`--no-imu`, KITTI, a camera-only bag) has no `/imu0` and
  no biases: the four IMU panels give way to the estimated position;
* `framed`: the 3D panel framed on the run's own extent (the estimate and the ground truth in
  `world`): fixed frame `world`, the camera on the middle of the run at the distance that shows
  all of it, the grid, paths and camera frustums scaled to it (a 60 m drive is not a room);
* `run_layout`: what `run` writes, all of the above chosen from the run (IMU or not, image topics
  of `--images`, extent).

`python -m eurocslam.io.layout DIR` writes the shipped layouts (`shipped_layouts`) into DIR; a test
keeps the repository's `layouts/` equal to them.
"""

from __future__ import annotations

import copy
import json
import math
import sys
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.errors import OutputError

Layout = dict[str, Any]

PANEL_3D = "3D!map"
IMU_PANELS = ("Plot!gyro", "Plot!accel", "Plot!gyro_bias", "Plot!accel_bias")
POSITION_PANEL = "Plot!position"
# the run's layouts, written beside run.mcap
RUN_LAYOUT = "layout.json"
RUN_LAYOUT_148 = "layout-1.48.json"

# framing: Foxglove's default vertical field of view (the template's fovy) and the 3D panel's
# width / height in the shipped arrangement (about 510 x 630 px in a 1600 x 1000 window): the
# narrower, horizontal field of view decides the distance
FOVY_DEG = 45.0
PANEL_ASPECT = 0.8
MARGIN = 1.15  # the run's bounding sphere fills 1 / MARGIN of the narrower field of view
MIN_RADIUS_M = 3.0  # a run that hardly moves is still framed like a room


def template() -> Layout:
    """The shipped layout for today's Foxglove (a fresh copy)."""
    text = (resources.files("eurocslam") / "data" / "layouts" / "eurocslam.json").read_text()
    out: Layout = json.loads(text)
    return out


def translate_to_studio_148(layout: Layout) -> Layout:
    """Today's Foxglove layout -> Foxglove Studio 1.48 (the open-source build the headless
    viewer runs): the `Image` panel (3D-style `imageMode` config) is `ImageViewPanel` there
    (`cameraTopic`, `enabledMarkerTopics`). Everything else is the same."""
    out = copy.deepcopy(layout)
    renamed: dict[str, str] = {}
    configs: dict[str, Any] = {}
    for pid, cfg in out["configById"].items():
        kind, _, suffix = pid.partition("!")
        if kind == "Image":
            mode = cfg["imageMode"]
            new_id = f"ImageViewPanel!{suffix}"
            renamed[pid] = new_id
            configs[new_id] = {
                "cameraTopic": mode["imageTopic"],
                "enabledMarkerTopics": [
                    t for t, s in mode.get("annotations", {}).items() if s.get("visible")
                ],
                "synchronize": bool(mode.get("synchronize", False)),
                "transformMarkers": False,
                "mode": "fit",
            }
        else:
            configs[pid] = cfg
    out["configById"] = configs
    out["layout"] = _map_leaves(out["layout"], lambda leaf: renamed.get(leaf, leaf))
    return out


def _map_leaves(node: Any, fn: Any) -> Any:
    """The split tree with each leaf (panel id) replaced by fn(leaf); a leaf mapped to None is
    removed and its split collapses into the other side."""
    if isinstance(node, str):
        return fn(node)
    first, second = _map_leaves(node["first"], fn), _map_leaves(node["second"], fn)
    if first is None or second is None:
        return second if first is None else first
    return {**node, "first": first, "second": second}


def _leaves(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    return _leaves(node["first"]) + _leaves(node["second"])


def _plot(title: str, paths: list[tuple[str, str]], like: dict[str, Any]) -> dict[str, Any]:
    """A Plot panel's config with the template's look (`like`: one of its plots)."""
    return {
        **like,
        "title": title,
        "paths": [
            {"value": v, "enabled": True, "timestampMethod": "receiveTime", "label": label}
            for v, label in paths
        ],
    }


def visual_only(layout: Layout) -> Layout:
    """The layout for a run without an IMU: no IMU or bias plots (their topics are not written,
    or hold nothing); the estimated position over time where the IMU plots were."""
    out = copy.deepcopy(layout)
    configs = out["configById"]
    like = configs["Plot!features"]
    for pid in IMU_PANELS:
        configs.pop(pid, None)
    configs[POSITION_PANEL] = _plot(
        "position [m] (estimate in world)",
        [(f"/slam/pose.pose.position.{a}", a) for a in "xyz"],
        like,
    )

    def swap(leaf: str) -> str | None:
        if leaf == "Plot!gyro":
            return POSITION_PANEL
        return None if leaf in IMU_PANELS else leaf

    out["layout"] = _map_leaves(out["layout"], swap)
    assert sorted(_leaves(out["layout"])) == sorted(configs)
    return out


def with_image_topics(layout: Layout, images: str) -> Layout:
    """The image panels on the topics `--images` writes: `/camN/image_raw` (raw) or
    `/camN/image_raw/compressed` (png, jpeg)."""
    from eurocslam.io.sensor_streams import image_topic

    out = copy.deepcopy(layout)
    for pid, cfg in out["configById"].items():
        if pid.startswith("Image!"):
            mode = cfg["imageMode"]
            cam = mode["imageTopic"].strip("/").split("/")[0]
            mode["imageTopic"] = image_topic(cam, images)
    return out


def _nice_at_least(x: float) -> float:
    """The smallest 1, 2 or 5 x 10^k that is >= x."""
    k = math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0**k >= x * (1 - 1e-12):
            return m * 10.0**k
    return 10.0 ** (k + 1)  # pragma: no cover


def framing(points: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(centre, radius, distance): the bounding box centre of `points` (N x 3, world, non-finite
    rows ignored), the radius of its bounding sphere (at least MIN_RADIUS_M), and the camera
    distance at which that sphere fills 1 / MARGIN of the 3D panel's narrower field of view."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) == 0:
        return np.zeros(3), MIN_RADIUS_M, _distance(MIN_RADIUS_M)
    lo, hi = p.min(axis=0), p.max(axis=0)
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, MIN_RADIUS_M)
    return (lo + hi) / 2.0, radius, _distance(radius)


def _distance(radius: float) -> float:
    half_v = math.radians(FOVY_DEG) / 2.0
    half = min(half_v, math.atan(math.tan(half_v) * PANEL_ASPECT))
    return MARGIN * radius / math.sin(half)


def framed(layout: Layout, points: np.ndarray) -> Layout:
    """The 3D panel framed on `points` (the run's positions in `world`): fixed frame `world`, the
    camera looking at their centre from the distance that shows them all (same tilt and heading
    as the template), the grid around them, and paths and camera frustums scaled with that
    distance (never down), so that they look on screen as they do in the template."""
    out = copy.deepcopy(layout)
    cfg = out["configById"][PANEL_3D]
    centre, radius, distance = framing(points)
    cam = cfg["cameraState"]
    # the camera looks at targetOffset, in the display frame (`target` is a legacy field the
    # 3D panel does not read)
    cam["targetOffset"] = [round(float(c), 3) for c in centre]
    cam["distance"] = round(distance, 2)
    cam["far"] = max(float(cam.get("far", 5000)), 20.0 * distance)
    cfg["followMode"] = "follow-none"
    cfg["followTf"] = "world"
    # lines and frustums keep their size on screen: scaled with the camera's distance
    scale = max(1.0, distance / float(layout["configById"][PANEL_3D]["cameraState"]["distance"]))
    for settings in cfg["topics"].values():
        for key in ("lineWidth", "distance", "width"):  # paths; camera frustums
            if key in settings:
                settings[key] = round(float(settings[key]) * scale, 4)
    grid = cfg.get("layers", {}).get("grid")
    if grid is not None:
        size = max(float(grid["size"]), _nice_at_least(2.0 * radius))
        step = size / int(grid["divisions"])
        grid["size"] = size
        # on the run, snapped to the grid's own step (z stays the world's ground)
        grid["position"] = [round(float(c) / step) * step for c in centre[:2]] + [0]
    return out


def run_layout(*, inertial: bool, images: str = "raw", points: np.ndarray | None = None) -> Layout:
    """The layout `run` writes beside its run.mcap: visual-only panels without an IMU, the image
    topics of `--images`, the 3D panel framed on `points` (when given)."""
    out = template() if inertial else visual_only(template())
    out = with_image_topics(out, images)
    if points is not None:
        out = framed(out, points)
    return out


def live_layout(*, inertial: bool, images: str = "raw", reach_m: float | None = None) -> Layout:
    """The layout of a live view, written before the run: `run_layout`'s panels, and the 3D panel
    framed on a disk of radius `reach_m` about the world's origin, where the run starts (the
    farthest its ground truth goes from its first position: the heading the run will give the
    world is not known yet, so the disk every heading fits in). None: the template's framing."""
    if reach_m is None or not math.isfinite(reach_m):
        return run_layout(inertial=inertial, images=images)
    r = max(float(reach_m), MIN_RADIUS_M)
    disk = np.array([[r, 0.0, 0.0], [-r, 0.0, 0.0], [0.0, r, 0.0], [0.0, -r, 0.0]])
    return run_layout(inertial=inertial, images=images, points=disk)


def dumps(layout: Layout) -> str:
    return json.dumps(layout, indent=2) + "\n"


def write_run_layouts(folder: Path, layout: Layout) -> None:
    """`layout.json` (today's Foxglove) and `layout-1.48.json` (Foxglove Studio 1.48)."""
    try:
        (folder / RUN_LAYOUT).write_text(dumps(layout))
        (folder / RUN_LAYOUT_148).write_text(dumps(translate_to_studio_148(layout)))
    except OSError as e:
        raise OutputError(f"{folder}: cannot write the layout: {e}") from None


def shipped_layouts() -> dict[str, Layout]:
    """The files of the repository's `layouts/` that come from the template (not convert's)."""
    main = template()
    visual = visual_only(main)
    return {
        "eurocslam.json": main,
        "eurocslam-1.48.json": translate_to_studio_148(main),
        "eurocslam-visual.json": visual,
        "eurocslam-visual-1.48.json": translate_to_studio_148(visual),
    }


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m eurocslam.io.layout DIR  (writes the shipped layouts)")
        return 2
    folder = Path(args[0])
    for name, layout in shipped_layouts().items():
        (folder / name).write_text(dumps(layout))
        print(folder / name)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
