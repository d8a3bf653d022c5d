"""What Foxglove does with our files, in Node: @mcap/core with CRC validation, @foxglove/rosmsg
schema parsing and @foxglove/rosmsg2-serialization decoding, no trailing bytes, byte-identical
re-encoding. Skips without node/npm."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from eurocslam.convert import ConvertOptions, convert
from eurocslam.dataset import open_sequence
from eurocslam.dataset.calib import default_rig
from eurocslam.geometry import make_T, so3_exp
from eurocslam.io import ros2, ros2_calib
from eurocslam.io.mcap_writer import McapSink

sys.path.insert(0, str(Path(__file__).with_name("node")))
import node_helper


def test_node_decodes_converted_v101_and_mh01(
    v101_micro: Path, mh01_first5: Path, tmp_path: Path
) -> None:
    out = tmp_path / "v101.mcap"
    convert(open_sequence(v101_micro), out, ConvertOptions(end=1.5, progress=False))
    rc, res, err = node_helper.decode(out)
    assert rc == 0, err
    assert res["topics"]["/cam0/image_raw"] == res["topics"]["/cam1/image_raw"] > 0
    assert res["topics"]["/tf_static"] == 1 and "/imu0" in res["topics"]
    out = tmp_path / "mh01.mcap"
    convert(
        open_sequence(mh01_first5),
        out,
        ConvertOptions(images="png", compression="lz4", progress=False),
    )
    rc, res, err = node_helper.decode(out)
    assert rc == 0, err
    assert res["topics"]["/leica0"] == 5 and res["topics"]["/cam1/image_raw/compressed"] == 5


def test_node_decodes_every_builder(tmp_path: Path) -> None:
    """The types `run` and the live view write (markers, clouds, annotations, numbers)."""
    t = 1_403_715_273_262_142_976
    T = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([1.0, 2.0, 3.0]))
    img = np.arange(48 * 64, dtype=np.uint8).reshape(48, 64)
    i0, _ = ros2_calib.stereo_camera_infos(default_rig())
    gc, ac = ros2_calib.imu_covariances(default_rig().imu)
    msgs = [
        ("/tf_static", ros2.TF_MESSAGE, ros2.tf_message([ros2.Transform(t, "body", "cam0", T)])),
        ("/img", ros2.IMAGE, ros2.image(t, "cam0", img)),
        ("/img_rgb", ros2.IMAGE, ros2.image(t, "cam0", np.stack([img] * 3, axis=2))),
        ("/img/compressed", ros2.COMPRESSED_IMAGE, ros2.compressed_image(t, "cam0", "png", b"x")),
        ("/info", ros2.CAMERA_INFO, ros2_calib.camera_info(t, "cam0", i0)),
        ("/imu", ros2.IMU, ros2.imu(t, "imu0", [1, 2, 3], [4, 5, 6], gc, ac)),
        ("/pose", ros2.POSE_STAMPED, ros2.pose_stamped(t, "world", T)),
        ("/path", ros2.PATH, ros2.path(t, "world", [t, t + 1, t + 2], np.stack([T] * 3))),
        ("/pt", ros2.POINT_STAMPED, ros2.point_stamped(t, "world", [1, 2, 3])),
        (
            "/cloud",
            ros2.POINT_CLOUD2,
            ros2.point_cloud2(
                t, "world", np.ones((5, 3)), np.full((5, 3), 200, np.uint8), np.arange(5.0)
            ),
        ),
        (
            "/marker",
            ros2.MARKER,
            ros2.marker(ros2.Marker(t, "world", "a", 1, 8, points=np.ones((3, 3)))),
        ),
        (
            "/markers",
            ros2.MARKER_ARRAY,
            ros2.marker_array(
                [
                    ros2.Marker(t, "body", "drone", i, 10, pose=T, mesh_resource="x", text="t")
                    for i in range(3)
                ]
            ),
        ),
        (
            "/img/markers",
            ros2.IMAGE_MARKER,
            ros2.image_marker(t, "cam0", [[1, 2], [3, 4]], outline_colors=np.ones((2, 4))),
        ),
        ("/bias", ros2.FLOAT64_MULTI_ARRAY, ros2.float64_multi_array([1, 2], ["a", "b"])),
        ("/x", ros2.FLOAT64, ros2.float64(1.5)),
        ("/state", ros2.STRING, ros2.string("OK")),
    ]
    out = tmp_path / "all.mcap"
    with McapSink(out, compression="zstd") as sink:
        for k, (topic, mt, data) in enumerate(msgs):
            sink.write(topic, mt, t + k, data)
    rc, res, err = node_helper.decode(out)
    assert rc == 0, err
    assert res["messages"] == len(msgs) and len(res["schemas"]) == len({m for _, m, _ in msgs})


def test_node_check_rejects_mixed_schema_spelling(tmp_path: Path) -> None:
    """Negative control: a schema with 'MSG: std_msgs/msg/Header' (fields say std_msgs/Header)
    is what Foxglove rejects; the Node check must fail on it too."""
    from mcap.writer import Writer

    bad = ros2.schema_text(ros2.POSE_STAMPED).replace(
        "MSG: std_msgs/Header", "MSG: std_msgs/msg/Header"
    )
    out = tmp_path / "bad.mcap"
    with out.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        sid = w.register_schema(ros2.POSE_STAMPED, "ros2msg", bad.encode())
        cid = w.register_channel("/pose", "cdr", sid, {"offered_qos_profiles": ""})
        w.add_message(cid, 1, ros2.pose_stamped(1, "w", np.eye(4)), 1)
        w.finish()
    rc, _, err = node_helper.decode(out)
    assert rc != 0 and "Header" in err
