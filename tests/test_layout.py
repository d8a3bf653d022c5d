"""The shipped Foxglove layouts: they parse, the 1.48 copy is the translation of the main one,
and every topic, message field and frame they reference exists in what `eurocslam run` writes."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from eurocslam.io.layout import (
    dumps,
    framed,
    framing,
    live_layout,
    run_layout,
    shipped_layouts,
    template,
    translate_to_studio_148,
    visual_only,
)

REPO = Path(__file__).resolve().parents[1]
LAYOUT = REPO / "layouts" / "eurocslam.json"
LAYOUT_148 = REPO / "layouts" / "eurocslam-1.48.json"
VISUAL = REPO / "layouts" / "eurocslam-visual.json"
VISUAL_148 = REPO / "layouts" / "eurocslam-visual-1.48.json"

# Topics `eurocslam run` writes (io/sensor_streams.py + io/slam_topics.py), their types, and the
# frames of its tf tree. The slow test below checks this list against a real run.mcap.
RUN_TOPICS = {
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/imu0": "sensor_msgs/msg/Imu",
    "/cam0/image_raw": "sensor_msgs/msg/Image",
    "/cam1/image_raw": "sensor_msgs/msg/Image",
    "/cam0/camera_info": "sensor_msgs/msg/CameraInfo",
    "/cam1/camera_info": "sensor_msgs/msg/CameraInfo",
    "/groundtruth/pose": "geometry_msgs/msg/PoseStamped",
    "/groundtruth/path": "nav_msgs/msg/Path",
    "/groundtruth/drone": "visualization_msgs/msg/MarkerArray",
    "/slam/pose": "geometry_msgs/msg/PoseStamped",
    "/slam/path": "nav_msgs/msg/Path",
    "/slam/path_final": "nav_msgs/msg/Path",
    "/slam/landmarks": "sensor_msgs/msg/PointCloud2",
    "/slam/drone": "visualization_msgs/msg/MarkerArray",
    "/slam/features": "visualization_msgs/msg/ImageMarker",
    "/slam/state": "std_msgs/msg/String",
    "/slam/stats": "std_msgs/msg/Float64MultiArray",
    "/slam/imu_bias": "std_msgs/msg/Float64MultiArray",
    "/slam/velocity": "std_msgs/msg/Float64MultiArray",
    "/slam/position_error": "std_msgs/msg/Float64MultiArray",
    "/slam/places": "visualization_msgs/msg/MarkerArray",
}
RUN_FRAMES = {"world", "body", "imu0", "cam0", "cam1", "gt_world", "gt_body"}


def _leaves(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert node["direction"] in ("row", "column")
    assert 0 < node["splitPercentage"] < 100
    return _leaves(node["first"]) + _leaves(node["second"])


def _load(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


def referenced(layout: dict[str, Any]) -> tuple[dict[str, set[str]], set[str]]:
    """({topic: {message paths after the topic}}, {frames}) that a layout refers to."""
    topics: dict[str, set[str]] = {}
    frames: set[str] = set()

    def add(path: str) -> None:
        m = re.fullmatch(r"(/[\w/]+?)((?:\.\w+(?:\[\d+\])?)*)", path)
        assert m, f"unparsable message path {path!r}"
        topics.setdefault(m.group(1), set()).add(m.group(2))

    for pid, cfg in layout["configById"].items():
        kind = pid.split("!")[0]
        if kind == "3D":
            frames.add(cfg["followTf"])
            for key in cfg.get("transforms", {}):
                assert key.startswith("frame:"), key
                frames.add(key.removeprefix("frame:"))
            for layer in cfg.get("layers", {}).values():
                if layer.get("frameId"):
                    frames.add(layer["frameId"])
            for t in cfg["topics"]:
                add(t)
        elif kind == "Image":
            add(cfg["imageMode"]["imageTopic"])
            for t in cfg["imageMode"].get("annotations", {}):
                add(t)
        elif kind == "ImageViewPanel":
            add(cfg["cameraTopic"])
            for t in cfg["enabledMarkerTopics"]:
                add(t)
        elif kind in ("Plot", "StateTransitions"):
            for p in cfg["paths"]:
                add(p["value"])
        else:
            raise AssertionError(f"panel kind {kind} not checked by this test")
    return topics, frames


def _field_exists(msgtype: str, path: str) -> bool:
    """Whether `.a.b[2]` exists in `msgtype` (rosbags' humble definitions)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    cur = msgtype
    for name, _idx in re.findall(r"\.(\w+)(\[\d+\])?", path):
        fields = dict(store.fielddefs[cur][1])
        if name not in fields:
            return False
        kind, spec = fields[name]
        # nodetype: 1 base, 2 name (message), 3 array, 4 sequence
        if kind in (3, 4):
            kind, spec = spec[0]
        cur = spec if kind == 2 else ""
    return True


def test_layouts_parse_and_are_consistent() -> None:
    main, old = _load(LAYOUT), _load(LAYOUT_148)
    for lay in (main, old):
        assert set(lay) >= {"configById", "layout", "globalVariables", "userNodes"}
        leaves = _leaves(lay["layout"])
        assert sorted(leaves) == sorted(lay["configById"])  # every panel placed exactly once
    assert translate_to_studio_148(main) == old, (
        "layouts/eurocslam-1.48.json is out of date: regenerate it with translate_to_studio_148"
    )
    kinds = {pid.split("!")[0] for pid in main["configById"]}
    assert kinds == {"3D", "Image", "Plot", "StateTransitions"}
    assert not any(k.startswith("Image!") for k in old["configById"])  # 1.48 has no Image panel


def test_layout_shows_what_the_issue_asks_for() -> None:
    main = _load(LAYOUT)
    topics, frames = referenced(main)
    three_d = main["configById"]["3D!map"]
    # the scene is drawn in `world` (the root of run's tf tree: world -> body, world -> gt_world);
    # the camera follows the drone's position and keeps the world's orientation
    assert (three_d["followTf"], three_d["followMode"]) == ("body", "follow-position")
    shown = {t for t, s in three_d["topics"].items() if s.get("visible")}
    # estimated path, ground-truth path, landmarks, both drones, camera frustums
    assert {
        "/slam/path",
        "/groundtruth/path",
        "/slam/landmarks",
        "/slam/drone",
        "/groundtruth/drone",
        "/slam/places",
        "/cam0/camera_info",
        "/cam1/camera_info",
    } <= shown
    images = {
        c["imageMode"]["imageTopic"]: c["imageMode"]
        for p, c in main["configById"].items()
        if p.startswith("Image!")
    }
    assert set(images) == {"/cam0/image_raw", "/cam1/image_raw"}
    assert images["/cam0/image_raw"]["annotations"]["/slam/features"]["visible"]
    plotted = {
        t
        for p, c in main["configById"].items()
        if p.startswith(("Plot!", "State"))
        for t in referenced({"configById": {p: c}})[0]
    }
    assert {
        "/imu0",
        "/slam/stats",
        "/slam/imu_bias",
        "/slam/position_error",
        "/slam/state",
    } <= plotted
    assert {"world", "body"} <= frames
    assert set(topics) <= set(RUN_TOPICS)


@pytest.mark.parametrize("path", [LAYOUT, LAYOUT_148, VISUAL, VISUAL_148])
def test_every_referenced_topic_field_and_frame_exists_in_run_output(path: Path) -> None:
    topics, frames = referenced(_load(path))
    missing = sorted(set(topics) - set(RUN_TOPICS))
    assert not missing, f"{path.name} refers to topics run does not write: {missing}"
    for topic, fields in topics.items():
        for f in fields:
            assert _field_exists(RUN_TOPICS[topic], f), f"{path.name}: {topic}{f} does not exist"
    assert frames <= RUN_FRAMES


def test_field_check_catches_typos() -> None:
    assert _field_exists("sensor_msgs/msg/Imu", ".angular_velocity.x")
    assert _field_exists("std_msgs/msg/Float64MultiArray", ".data[3]")
    assert not _field_exists("sensor_msgs/msg/Imu", ".angular_velocity.w")
    assert not _field_exists("std_msgs/msg/String", ".text")


# ---- the shipped files come from the template; the layout a run writes ------------------------


def test_shipped_layouts_are_the_templates_and_its_derivatives() -> None:
    assert template() == _load(LAYOUT)  # the package's template is the repository's layout
    for name, layout in shipped_layouts().items():
        assert (REPO / "layouts" / name).read_text() == dumps(layout), (
            f"layouts/{name} is out of date: python -m eurocslam.io.layout layouts"
        )


@pytest.mark.parametrize("layout", [visual_only(template()), run_layout(inertial=False)])
def test_visual_only_layout_has_no_empty_imu_panels(layout: dict[str, Any]) -> None:
    topics, _ = referenced(layout)
    assert not {"/imu0", "/slam/imu_bias"} & set(topics)  # nothing that a run without IMU lacks
    assert sorted(_leaves(layout["layout"])) == sorted(layout["configById"])
    plots = {p: c for p, c in layout["configById"].items() if p.startswith("Plot!")}
    assert set(plots) == {"Plot!position", "Plot!features", "Plot!error"}
    assert [q["value"] for q in plots["Plot!position"]["paths"]] == [
        "/slam/pose.pose.position.x",
        "/slam/pose.pose.position.y",
        "/slam/pose.pose.position.z",
    ]
    # the 3D panel and both cameras as in the stereo-inertial layout
    assert layout["configById"]["3D!map"]["topics"] == template()["configById"]["3D!map"]["topics"]
    assert {p for p in layout["configById"] if p.startswith("Image!")} == {
        "Image!cam0",
        "Image!cam1",
    }


def test_run_layout_follows_the_image_mode() -> None:
    def image_topics(layout: dict[str, Any]) -> set[str]:
        return {
            c["imageMode"]["imageTopic"]
            for p, c in layout["configById"].items()
            if p.startswith("Image!")
        }

    assert image_topics(run_layout(inertial=True)) == {"/cam0/image_raw", "/cam1/image_raw"}
    assert image_topics(run_layout(inertial=True, images="png")) == {
        "/cam0/image_raw/compressed",
        "/cam1/image_raw/compressed",
    }
    assert run_layout(inertial=True) == template()  # without an extent: the shipped layout


def _project(cam: dict[str, Any], p: np.ndarray, aspect: float) -> np.ndarray:
    """Normalised image coordinates (-1..1 inside the panel) of world points `p` seen by the 3D
    panel's orbit camera (Foxglove: distance, phi from +z, thetaOffset, looking at
    targetOffset)."""
    phi, theta = np.radians(cam["phi"]), -np.radians(cam["thetaOffset"])
    # camera position on the sphere around the target (three.js spherical, rotated z-up)
    back = np.array([np.sin(phi) * np.sin(theta), -np.sin(phi) * np.cos(theta), np.cos(phi)])
    eye = np.asarray(cam["targetOffset"]) + cam["distance"] * back
    fwd = -back
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    d = p - eye
    z = d @ fwd
    t = np.tan(np.radians(cam["fovy"]) / 2)
    return np.stack([(d @ right) / z / (t * aspect), (d @ up) / z / t], axis=1)


def test_the_3d_panel_frames_a_60_m_drive() -> None:
    # a KITTI-like drive: 60 m along a curve, the ground truth 5 % longer beside it
    s = np.linspace(0, 1, 51)[:, None]
    est = np.hstack([40 * np.sin(s), -40 * (1 - np.cos(s)) - 10 * s, 0.5 * s])
    gt = est * 1.05
    lay = framed(run_layout(inertial=False), np.vstack([est, gt]))
    three_d = lay["configById"]["3D!map"]
    cam = three_d["cameraState"]
    assert (three_d["followMode"], three_d["followTf"]) == ("follow-none", "world")
    centre, radius, distance = framing(np.vstack([est, gt]))
    assert cam["targetOffset"] == pytest.approx(list(centre), abs=1e-3)
    assert radius > 20 and cam["distance"] == pytest.approx(distance, abs=0.01)
    assert cam["distance"] > 60  # not the drone's 9 m
    # every estimated and true position inside the panel, from any heading of the camera
    for heading in (0, 40, 90, 180, 270):
        uv = _project({**cam, "thetaOffset": heading}, np.vstack([est, gt]), aspect=0.8)
        assert np.all(np.abs(uv) < 1.0), heading
    # drawn at its scale: a grid that covers it, paths and frustums larger than a room's
    grid = three_d["layers"]["grid"]
    assert grid["size"] >= 2 * radius and grid["size"] in (50, 100, 200)
    room = template()["configById"]["3D!map"]["topics"]
    for topic in ("/slam/path", "/groundtruth/path"):
        assert three_d["topics"][topic]["lineWidth"] > room[topic]["lineWidth"]
    assert three_d["topics"]["/cam0/camera_info"]["distance"] > 1.0


def test_the_live_layout_frames_every_heading_the_run_can_take() -> None:
    """Before the run the world's heading is unknown: the live view's 3D panel is framed on the
    disk the ground truth's reach spans about the origin (where the run starts), so the drive
    is in view whichever way it turns; without ground truth, the template's framing."""
    lay = live_layout(inertial=False, reach_m=60.0)
    three_d = lay["configById"]["3D!map"]
    assert three_d["cameraState"]["targetOffset"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-3)
    assert "/imu0" not in json.dumps(lay)  # visual-only panels
    for heading in (0.0, 45.0, 135.0, 250.0):  # a 60 m straight drive, in any direction
        a = np.radians(heading)
        drive = np.outer(np.linspace(0.0, 60.0, 31), [np.cos(a), np.sin(a), 0.0])
        uv = _project({**three_d["cameraState"], "thetaOffset": 30.0}, drive, aspect=0.8)
        assert np.all(np.abs(uv) < 1.0), heading
    assert live_layout(inertial=True, reach_m=None) == run_layout(inertial=True)
    assert live_layout(inertial=True, reach_m=float("nan")) == run_layout(inertial=True)


def test_a_room_keeps_the_drone_scale() -> None:
    p = np.random.default_rng(0).uniform(-2, 2, (200, 3))
    lay = framed(template(), p)["configById"]["3D!map"]
    assert 5 < lay["cameraState"]["distance"] < 15  # the template's 9 m, about
    room = template()["configById"]["3D!map"]
    for topic, settings in lay["topics"].items():  # nothing scaled down, hardly up
        for key in ("lineWidth", "distance", "width"):
            if key in settings:
                assert 1.0 <= settings[key] / room["topics"][topic][key] < 1.5
    assert lay["layers"]["grid"]["size"] == room["layers"]["grid"]["size"]
    # no positions (or only non-finite ones): framed like a room at the origin
    c, r, _ = framing(np.full((3, 3), np.nan))
    assert list(c) == [0, 0, 0] and r == 3.0


def test_play_names_the_runs_own_layout_else_the_shipped_one(tmp_path: Path) -> None:
    from types import SimpleNamespace

    from eurocslam.commands.play import _layout_for

    def info(topics: list[str]) -> Any:
        chans = {i: SimpleNamespace(topic=t) for i, t in enumerate(topics)}
        return SimpleNamespace(path=tmp_path / "run.mcap", channels=chans)

    assert _layout_for(info(["/imu0", "/cam0/image_raw"])) == "layouts/eurocslam.json"
    assert _layout_for(info(["/cam0/image_raw"])) == "layouts/eurocslam-visual.json"
    (tmp_path / "layout.json").write_text("{}")
    assert _layout_for(info(["/cam0/image_raw"])) == str(tmp_path / "layout.json")
