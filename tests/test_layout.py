"""The shipped Foxglove layouts: they parse, the 1.48 copy is the translation of the main one,
and every topic, message field and frame they reference exists in what `eurocslam run` writes."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[1]
LAYOUT = REPO / "layouts" / "eurocslam.json"
LAYOUT_148 = REPO / "layouts" / "eurocslam-1.48.json"

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


def translate_to_studio_148(layout: dict[str, Any]) -> dict[str, Any]:
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

    def walk(node: Any) -> Any:
        if isinstance(node, str):
            return renamed.get(node, node)
        return {**node, "first": walk(node["first"]), "second": walk(node["second"])}

    out["layout"] = walk(out["layout"])
    return out


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


@pytest.mark.parametrize("path", [LAYOUT, LAYOUT_148])
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
