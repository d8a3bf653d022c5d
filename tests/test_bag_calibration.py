"""A robot's bag as its own calibration source (issue #37): CameraInfo messages, the static tf
tree, the rig built from both, topics found by message type, IMU noise from outside the bag.
Units on hand-made messages, then small bags written with rosbags for every bad-calibration
case (each a one-line error naming the topic or /tf_static, and `doctor` exit 2)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from eurocslam.camera import is_rectified, rectify_stereo
from eurocslam.config import config_from_dict
from eurocslam.dataset.bag.bag_rig import BagCamera, rig_from_camera_infos
from eurocslam.dataset.bag.camera_info import (
    camera_info_from_msg,
    check_camera_info,
    is_rectified_topic,
)
from eurocslam.dataset.bag.discovery import camera_info_topic, discover_imu, discover_stereo
from eurocslam.dataset.bag.reader import BagSequence
from eurocslam.dataset.bag.tf_tree import TfEdge, TfTree
from eurocslam.dataset.calib import default_rig
from eurocslam.dataset.doctor.bag_checks import check_bag
from eurocslam.dataset.doctor.report import exit_code
from eurocslam.dataset.imu_noise import NoiseFigures, load_imu_noise, noise_from_config
from eurocslam.errors import CalibrationError, ConfigError, DatasetError
from eurocslam.geometry import inv_T, make_T, so3_exp
from eurocslam.io.ros2_calib import stereo_camera_infos
from robot_bag_helpers import R_OPT, pinhole_info, realsense_tree, write_robot_bag

TOPIC = "/camera/infra1/camera_info"


def _msg(ros1: bool = False, **fields: Any) -> SimpleNamespace:
    """A decoded CameraInfo as rosbags gives it (ROS 1 spells D K R P in capitals)."""
    f = pinhole_info(**fields)
    arrays = {k: np.asarray(f[k], dtype=np.float64) for k in "dkrp"}
    if ros1:
        arrays = {k.upper(): v for k, v in arrays.items()}
    roi = SimpleNamespace(x_offset=0, y_offset=0, width=0, height=0)
    return SimpleNamespace(
        header=SimpleNamespace(frame_id=f["frame_id"] or "/camera_infra1_optical_frame"),
        width=f["width"], height=f["height"], distortion_model=f["distortion_model"],
        binning_x=f.get("binning_x", 0), binning_y=0, roi=f.get("roi", roi), **arrays,
    )  # fmt: skip


# ---- CameraInfo --------------------------------------------------------------------------------


def test_camera_info_reads_ros1_and_ros2_spellings() -> None:
    d = [-0.1, 0.01, 0.001, -0.002, 0.0005]
    a = check_camera_info(camera_info_from_msg(_msg(d=d), TOPIC))
    b = check_camera_info(camera_info_from_msg(_msg(ros1=True, d=d), TOPIC))
    assert a.frame_id == b.frame_id == "camera_infra1_optical_frame"  # leading slash dropped
    assert a.D == b.D == tuple(d) and a.model == "plumb_bob"
    np.testing.assert_array_equal(a.K, b.K)
    np.testing.assert_array_equal(a.P, b.P)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"k": np.zeros(9)}, "K is all zeros"),
        ({"k": [-50.0, 0, 32, 0, 50, 24, 0, 0, 1]}, "focal lengths -50, 50"),
        ({"d": [0.1, 0.01, 0.0, 0.0]}, "'plumb_bob' needs 5 coefficients, has 4"),
        ({"distortion_model": "rational_polynomial", "d": [0.1] * 5},
         "'rational_polynomial' needs 8 coefficients, has 5"),
        ({"distortion_model": "equidistant", "d": [0.1] * 5},
         "'equidistant' needs 4 coefficients, has 5"),
        ({"distortion_model": "fov", "d": [0.9]}, "distortion model 'fov' is not supported"),
        ({"r": [1, 0, 0, 0, 1, 0, 0, 0, -1]}, "R is not a rotation"),
        ({"width": 0}, "size is 0x48"),
        ({"binning_x": 2}, "binning 2x0 is not supported"),
        ({"roi": SimpleNamespace(x_offset=8, y_offset=0, width=32, height=48)},
         "roi 32x48\\+8\\+0 is not supported"),
    ],
)  # fmt: skip
def test_bad_camera_info_is_a_one_line_error_naming_the_topic(fields: dict, message: str) -> None:
    with pytest.raises(CalibrationError, match=message) as e:
        check_camera_info(camera_info_from_msg(_msg(**fields), TOPIC))
    assert str(e.value).startswith(TOPIC + ": ") and "\n" not in str(e.value)


def test_camera_info_models() -> None:
    def model(**f: Any) -> tuple[str, tuple[float, ...]]:
        info = check_camera_info(camera_info_from_msg(_msg(**f), TOPIC))
        return info.model, info.D

    assert model() == ("none", ())  # plumb_bob with D = 0: no distortion
    assert model(d=[]) == ("none", ())  # an empty D
    rat = [0.5, 0.1, 0.001, 0.002, 0.01, 0.9, 0.2, 0.03]
    assert model(distortion_model="rational_polynomial", d=rat) == ("rational_polynomial",
                                                                    tuple(rat))  # fmt: skip
    # depthai's 14 coefficients with the thin-prism and tilt terms zero
    assert model(distortion_model="rational_polynomial", d=rat + [0.0] * 6)[1] == tuple(rat)
    # a fisheye stays a fisheye with zero coefficients
    assert model(distortion_model="equidistant", d=[0.0] * 4) == ("equidistant", (0.0,) * 4)
    assert is_rectified_topic("/camera/infra1/image_rect_raw")
    assert is_rectified_topic("/stereo/left/image_rect/compressed")
    assert not is_rectified_topic("/camera/infra1/image_raw")


# ---- tf tree -----------------------------------------------------------------------------------


def _tree() -> TfTree:
    return TfTree(TfEdge(p, c, T) for p, c, T in realsense_tree())


def test_tf_chains_compose_in_both_directions() -> None:
    tree = _tree()
    T = tree.lookup("/camera_imu_optical_frame", "camera_infra2_optical_frame")
    edges = {c: T for _, c, T in realsense_tree()}
    expected = (
        inv_T(edges["camera_imu_optical_frame"]) @ inv_T(edges["camera_gyro_frame"])
        @ edges["camera_infra2_frame"] @ edges["camera_infra2_optical_frame"]
    )  # fmt: skip
    np.testing.assert_allclose(T, expected, atol=1e-15)
    np.testing.assert_allclose(
        tree.lookup("camera_infra2_optical_frame", "camera_imu_optical_frame"), inv_T(T),
        atol=1e-15,
    )  # fmt: skip
    assert tree.path("camera_infra1_optical_frame", "camera_imu_optical_frame") == [
        "camera_infra1_optical_frame", "camera_infra1_frame", "camera_link",
        "camera_gyro_frame", "camera_imu_optical_frame",
    ]  # fmt: skip


def test_tf_errors_name_the_topic_and_frames() -> None:
    tree = _tree()
    with pytest.raises(
        CalibrationError,
        match=r"/tf_static: no transform chain from 'camera_link' to 'camera_color_frame'.*"
        r"not in the tree",
    ):
        tree.lookup("camera_link", "camera_color_frame")
    tree.add(TfEdge("base_link", "lidar", np.eye(4)))
    with pytest.raises(CalibrationError, match="two unconnected trees"):
        tree.lookup("camera_link", "lidar")
    with pytest.raises(CalibrationError, match="no static transforms in the bag"):
        TfTree().lookup("a", "b")
    with pytest.raises(CalibrationError, match="'camera_link' has two parents"):
        tree.add(TfEdge("base_link", "camera_link", np.eye(4))) or tree.add(
            TfEdge("odom", "camera_link", np.eye(4))
        )


# ---- the rig -----------------------------------------------------------------------------------


def _bag_camera(role: str, info: Any, frame: str, topic: str | None = None) -> BagCamera:
    t = topic or f"/camera/infra{1 if role == 'cam0' else 2}/image_raw"
    return BagCamera(role, t, frame, (info.width, info.height), 20.0, info)


def _info_of(data: Any, topic: str, frame: str) -> Any:
    """A checked `CameraInfo` from io/ros2_calib's CameraInfoData (K, D, R, P of a rig)."""
    msg = SimpleNamespace(
        header=SimpleNamespace(frame_id=frame), width=data.width, height=data.height,
        distortion_model=data.distortion_model, d=data.D, k=data.K.ravel(), r=data.R.ravel(),
        p=data.P.ravel(), binning_x=0, binning_y=0, roi=None,
    )  # fmt: skip
    return camera_info_from_msg(msg, topic)


def _euroc_tree() -> TfTree:
    """EuRoC's rig as a tf tree: imu0 -> cam0, imu0 -> cam1."""
    rig = default_rig()
    return TfTree([TfEdge("imu0", "cam0", rig.cam0.T_body_cam),
                   TfEdge("imu0", "cam1", rig.cam1.T_body_cam)])  # fmt: skip


def test_raw_pair_placed_by_tf_or_by_the_R_P_pair() -> None:
    rig = default_rig()
    i0, i1 = stereo_camera_infos(rig)
    c0 = _bag_camera("cam0", _info_of(i0, "/cam0/camera_info", "cam0"), "cam0")
    c1 = _bag_camera("cam1", _info_of(i1, "/cam1/camera_info", "cam1"), "cam1")
    notes: list[str] = []
    got = rig_from_camera_infos(c0, c1, _euroc_tree(), "imu0", rig.imu, notes)
    for cam in ("cam0", "cam1"):
        a, b = getattr(rig, cam), getattr(got, cam)
        np.testing.assert_allclose(b.T_body_cam, a.T_body_cam, atol=1e-15)
        assert (b.fx, b.fy, b.cx, b.cy) == (a.fx, a.fy, a.cx, a.cy)
        assert b.distortion[:4] == a.distortion and b.distortion_model == "radial-tangential"
    assert "cam1 placed relative to cam0 by /tf_static" in notes
    # cam1's frame not in the tree: its place comes from the CameraInfo R/P pair
    tree = TfTree([TfEdge("imu0", "cam0", rig.cam0.T_body_cam)])
    notes = []
    got = rig_from_camera_infos(c0, c1, tree, "imu0", rig.imu, notes)
    np.testing.assert_allclose(got.T_cam1_cam0, rig.T_cam1_cam0, atol=1e-9)
    assert "cam1 placed relative to cam0 by the CameraInfo R/P pair" in notes


def _rect_pair(tx1: float, tf_baseline: float | None) -> tuple[Any, list[str]]:
    infos = [pinhole_info(), pinhole_info(tx=tx1)]
    cams = [
        _bag_camera(r, check_camera_info(camera_info_from_msg(_msg(**f), f"/{r}/camera_info")),
                    f"camera_infra{k + 1}_optical_frame", f"/camera/infra{k + 1}/image_rect_raw")
        for k, (r, f) in enumerate(zip(("cam0", "cam1"), infos, strict=True))
    ]  # fmt: skip
    tree = TfTree(TfEdge(p, c, T) for p, c, T in realsense_tree(tf_baseline or 0.05))
    if tf_baseline is None:  # infra2 not in the tree
        tree = TfTree(TfEdge(p, c, T) for p, c, T in realsense_tree() if "infra2" not in c)
    notes: list[str] = []
    rig = rig_from_camera_infos(cams[0], cams[1], tree, "camera_imu_optical_frame", None, notes)
    return rig, notes


def test_rectified_pair_takes_the_baseline_from_P() -> None:
    rig, notes = _rect_pair(-50.0 * 0.05, 0.05)
    assert is_rectified(rig) and rig.cam0.distortion_model == "none"
    geom = rectify_stereo(rig).geometry
    assert geom.baseline == pytest.approx(0.05, abs=1e-15) and geom.fx == 50.0
    assert not any("disagree" in n or "P is used" in n for n in notes)
    # cam0 sits where the tree says: imu optical <- gyro <- link -> infra1 -> optical
    np.testing.assert_allclose(rig.cam0.T_body_cam[:3, 3], [-0.005, 0.004, 0.01], atol=1e-15)


def test_rectified_pair_quirks_of_realsense_ros() -> None:
    # P[0, 3] = 0 (realsense-ros before 2.2.16): the baseline from /tf_static
    rig, notes = _rect_pair(0.0, 0.05)
    assert rig.baseline == pytest.approx(0.05, abs=1e-12)
    assert any("P[0, 3] is 0; stereo baseline 0.0500 m from /tf_static" in n for n in notes)
    # P[0, 3] with a left camera's sign while the tree puts infra2 on the right
    rig, notes = _rect_pair(+50.0 * 0.05, 0.05)
    assert rig.baseline == pytest.approx(0.05, abs=1e-12) and is_rectified(rig)
    assert any("realsense-ros quirk" in n for n in notes)
    # P and the tree disagree (P: 5 cm, tree: 6 cm): P wins, a note says so
    rig, notes = _rect_pair(-50.0 * 0.05, 0.06)
    assert rig.baseline == pytest.approx(0.05, abs=1e-12)
    assert any("so P is used" in n for n in notes)
    # a positive P[0, 3] with no tree to say otherwise: the "right" camera is on the left
    with pytest.raises(
        CalibrationError, match=r"stereo baseline -0\.0500 m: this camera is not to the right"
    ):
        _rect_pair(+50.0 * 0.05, None)
    with pytest.raises(
        CalibrationError, match=r"P\[0, 3\] is 0 \(no baseline\) and /tf_static does not relate"
    ):
        _rect_pair(0.0, None)


# ---- whole bags with bad calibration -----------------------------------------------------------

GOOD = (pinhole_info(), pinhole_info(tx=-2.5))


@pytest.mark.parametrize(
    ("infos", "tree", "kw", "message"),
    [
        ((pinhole_info(k=np.zeros(9)), GOOD[1]), realsense_tree(), {},
         "/camera/infra1/camera_info: CameraInfo K is all zeros"),
        ((GOOD[0], pinhole_info(tx=-2.5, d=[0.1, 0.0, 0.0, 0.0])), realsense_tree(), {},
         "/camera/infra2/camera_info: distortion model 'plumb_bob' needs 5 coefficients, has 4"),
        ((pinhole_info(width=640, height=480), GOOD[1]), realsense_tree(), {},
         "/camera/infra1/camera_info: CameraInfo says 640x480 but the images on "
         "/camera/infra1/image_rect_raw are 64x48"),
        (GOOD, [e for e in realsense_tree() if e[1] != "camera_imu_optical_frame"], {},
         "/tf_static: no transform chain from 'camera_imu_optical_frame' to "
         "'camera_infra1_optical_frame' \\(body = IMU frame to cam0\\): frame "
         "'camera_imu_optical_frame' is not in the tree"),
        (GOOD, [e for e in realsense_tree() if "infra1" not in e[1]], {},
         "/tf_static: no transform chain from 'camera_imu_optical_frame' to "
         "'camera_infra1_optical_frame'"),
        (GOOD, [], {}, "/tf_static: no static transforms in the bag"),
        (GOOD, realsense_tree(), {"imu_frame": None},
         "/camera/imu: the IMU messages have no header.frame_id"),
    ],
)  # fmt: skip
def test_bad_calibration_in_a_bag(
    infos: tuple, tree: list, kw: dict, message: str, tmp_path: Path
) -> None:
    bag = write_robot_bag(tmp_path / "bad", infos, tree, **kw)
    with pytest.raises(CalibrationError, match=message) as e:
        BagSequence(bag)
    assert "\n" not in str(e.value)
    findings = check_bag(bag)  # the doctor reports the same one line
    assert exit_code(findings) == 2
    assert any(f.severity == "error" and e.value.args[0] in f.message for f in findings)


def test_good_robot_bag_and_the_calibration_precedence(tmp_path: Path) -> None:
    bag = write_robot_bag(tmp_path / "good", GOOD, realsense_tree())
    seq = BagSequence(bag)
    assert seq.calib_source == "CameraInfo + /tf_static of good"
    assert is_rectified(seq.rig) and seq.rig.baseline == pytest.approx(0.05, abs=1e-12)
    assert seq.rig.imu is not None and seq.rig.imu.rate_hz == 200.0
    default = "the bag carries no figures (none given): using eurocslam/data/imu_noise_defaults"
    assert any(default in n for n in seq.notes)
    # --calib beats the bag (EuRoC's sizes then do not fit these images: an error saying so)
    calib = tmp_path / "calib"
    for name, text in default_rig().yaml_texts:
        (calib / name).mkdir(parents=True)
        (calib / name / "sensor.yaml").write_text(text)
    with pytest.raises(CalibrationError, match=r"images are 64x48 but the calibration \("):
        BagSequence(bag, calib=calib)
    findings = check_bag(bag)
    assert exit_code(findings) == 1  # the default IMU noise is a warning
    text = " ".join(f.message for f in findings)
    assert "rectified: P's pinhole" in text and "stereo baseline 0.0500 m" in text


# ---- discovery ---------------------------------------------------------------------------------

REALSENSE_TOPICS = {
    "/camera/infra1/image_rect_raw": "sensor_msgs/msg/Image",
    "/camera/infra2/image_rect_raw": "sensor_msgs/msg/Image",
    "/camera/infra1/image_rect_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/camera/infra2/image_rect_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/camera/infra1/camera_info": "sensor_msgs/msg/CameraInfo",
    "/camera/infra2/camera_info": "sensor_msgs/msg/CameraInfo",
    "/camera/depth/image_rect_raw": "sensor_msgs/msg/Image",
    "/camera/color/image_raw": "sensor_msgs/msg/Image",
    "/camera/accel/sample": "sensor_msgs/msg/Imu",
    "/camera/gyro/sample": "sensor_msgs/msg/Imu",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}


def test_discovery_on_realsense_topics() -> None:
    pair = discover_stereo(REALSENSE_TOPICS)
    assert (pair.left, pair.right, pair.ordered) == (
        "/camera/infra1/image_rect_raw",
        "/camera/infra2/image_rect_raw",
        True,
    )  # uncompressed before compressed; depth and colour never
    imu = discover_imu(REALSENSE_TOPICS)
    assert (imu.imu, imu.accel, imu.gyro) == (None, "/camera/accel/sample", "/camera/gyro/sample")
    united = {**REALSENSE_TOPICS, "/camera/imu": "sensor_msgs/msg/Imu"}
    assert discover_imu(united).imu == "/camera/imu"
    assert camera_info_topic(pair.left, REALSENSE_TOPICS) == "/camera/infra1/camera_info"
    assert camera_info_topic("/camera/infra2/image_rect_raw/compressed",
                             REALSENSE_TOPICS) == "/camera/infra2/camera_info"  # fmt: skip
    both = {**united, "/mavros/imu/data": "sensor_msgs/msg/Imu"}
    with pytest.raises(DatasetError, match=r"several IMU topics.*--topic imu=TOPIC"):
        discover_imu(both, "x.bag")
    # two image topics the names do not pair: left and right decided later (by tf)
    two = {"/front/image": "sensor_msgs/msg/Image", "/rear/image": "sensor_msgs/msg/Image"}
    assert not discover_stereo(two).ordered
    stereo = {"/zed/left/image_rect_color": "sensor_msgs/msg/Image",
              "/zed/right/image_rect_color": "sensor_msgs/msg/Image",
              "/zed/left/image_raw": "sensor_msgs/msg/Image",
              "/zed/right/image_raw": "sensor_msgs/msg/Image"}  # fmt: skip
    assert discover_stereo(stereo).left == "/zed/left/image_raw"  # raw before rectified


def test_unnamed_pair_ordered_by_the_tf_baseline(tmp_path: Path) -> None:
    # image topics named /a and /b, /b's camera is the left one (cam1 at -x of it)
    bag = write_robot_bag(
        tmp_path / "ab", (GOOD[1], GOOD[0]), realsense_tree(),
        frames=("camera_infra2_optical_frame", "camera_infra1_optical_frame"),
        topics=("/a/image_rect_raw", "/b/image_rect_raw"),
    )  # fmt: skip
    seq = BagSequence(bag)
    assert (seq.stats["cam0"].topic, seq.stats["cam1"].topic) == ("/b/image_rect_raw",
                                                                  "/a/image_rect_raw")  # fmt: skip
    assert any("decided by the /tf_static baseline" in n for n in seq.notes)
    assert seq.rig.baseline == pytest.approx(0.05, abs=1e-12)


# ---- IMU noise ---------------------------------------------------------------------------------


def test_imu_noise_files_and_config(tmp_path: Path) -> None:
    kalibr = tmp_path / "imu.yaml"
    kalibr.write_text(
        "accelerometer_noise_density: 1.86e-03\naccelerometer_random_walk: 4.33e-04\n"
        "gyroscope_noise_density: 1.87e-04\ngyroscope_random_walk: 2.66e-05\n"
        "rostopic: /camera/imu\nupdate_rate: 200.0\n"
    )
    n = load_imu_noise(kalibr)
    assert n.complete and n.accelerometer_random_walk == 4.33e-04 and n.source == str(kalibr)
    nested = tmp_path / "results-imu.yaml"
    nested.write_text("imu0:\n" + "".join(f"  {ln}\n" for ln in kalibr.read_text().splitlines()))
    assert load_imu_noise(nested).gyroscope_random_walk == 2.66e-05
    euroc = Path(__file__).parents[1] / "src/eurocslam/data/euroc_calib/imu0/sensor.yaml"
    assert load_imu_noise(euroc).gyroscope_noise_density == 1.6968e-04
    bad = tmp_path / "bad.yaml"
    bad.write_text("gyroscope_noise_density: 1e-4\n")
    with pytest.raises(CalibrationError, match=r"bad\.yaml: missing key 'gyroscope_random_walk'"):
        load_imu_noise(bad)
    bad.write_text(kalibr.read_text().replace("1.87e-04", "-1"))
    with pytest.raises(CalibrationError, match="'gyroscope_noise_density' must be a positive"):
        load_imu_noise(bad)
    cfg = config_from_dict({"imu": {"gyroscope_noise_density": 2e-4}})
    part = noise_from_config(cfg.imu)
    assert part.gyroscope_noise_density == 2e-4 and not part.complete and not part.empty
    assert noise_from_config(config_from_dict({}).imu).empty
    with pytest.raises(
        ConfigError,
        match=r"imu\.accelerometer_random_walk' value -1.0 out of range \(must be > 0\)",
    ):
        config_from_dict({"imu": {"accelerometer_random_walk": -1.0}})
    with pytest.raises(ConfigError, match=r"imu\.gyroscope_random_walk' must be a number"):
        config_from_dict({"imu": {"gyroscope_random_walk": "x"}})
    # the figures given win; the rest from the default
    merged = NoiseFigures(gyroscope_noise_density=1.0, source="mine").over(n)
    assert merged.gyroscope_noise_density == 1.0 and merged.gyroscope_random_walk == 2.66e-05


def test_imu_noise_reaches_the_rig(tmp_path: Path) -> None:
    bag = write_robot_bag(tmp_path / "noise", GOOD, realsense_tree())
    kalibr = tmp_path / "imu.yaml"
    kalibr.write_text(
        "accelerometer_noise_density: 1.86e-03\naccelerometer_random_walk: 4.33e-04\n"
        "gyroscope_noise_density: 1.87e-04\ngyroscope_random_walk: 2.66e-05\n"
    )
    seq = BagSequence(bag, imu_noise=load_imu_noise(kalibr))
    imu = seq.rig.imu
    assert imu is not None
    assert (imu.gyro_noise_density, imu.accel_random_walk) == (1.87e-4, 4.33e-4)
    assert not any("carries no figures" in n for n in seq.notes)
    assert f"IMU noise figures from {kalibr}" in seq.notes
    # the imu0 sensor.yaml that convert and run attach carries them too
    assert "gyroscope_noise_density: 0.000187\n" in dict(seq.rig.yaml_texts)["imu0"]
    assert exit_code(check_bag(bag, imu_noise=load_imu_noise(kalibr))) == 0


def test_rotated_accelerometer_frame_is_turned_into_the_gyros() -> None:
    from eurocslam.dataset.bag.arrays import ArrayBuilder
    from eurocslam.dataset.bag.stats import TopicStats
    from eurocslam.dataset.types import SkipReport

    stats = {r: TopicStats(r, f"/{r}", "sensor_msgs/msg/Imu") for r in ("accel", "gyro")}
    t = [0, 10_000_000, 20_000_000]
    for st in stats.values():
        st.header_ns, st.log_ns = list(t), list(t)
        st.freeze()
    R = so3_exp(np.array([0.0, 0.0, np.pi / 2]))  # accel frame turned 90 deg about z
    tree = TfTree([TfEdge("gyro", "accel", make_T(R, np.zeros(3)))])
    rows = [(0.0, 0.0, 0.0, 1.0, 0.0, 9.81)] * 3
    imu = ArrayBuilder(Path("x"), stats, [], SkipReport()).united_imu(
        (t, rows), (t, rows), {"accel": "accel", "gyro": "gyro"}, tree
    )
    np.testing.assert_allclose(imu.accel, [[0.0, 1.0, 9.81]] * 3, atol=1e-15)
    assert R_OPT.shape == (3, 3)


def test_run_takes_imu_noise_from_the_flag_else_the_config(tmp_path: Path) -> None:
    import argparse

    from eurocslam.commands._args import source_options

    cfg = config_from_dict({"imu": {"gyroscope_noise_density": 3e-4}})
    args = argparse.Namespace(topic=[], calib=None, imu_calib=None)
    noise = source_options(args, cfg.imu)["imu_noise"]
    assert noise.gyroscope_noise_density == 3e-4 and noise.source == "the configuration (imu:)"
    assert source_options(args, config_from_dict({}).imu)["imu_noise"] is None
    kalibr = tmp_path / "imu.yaml"
    kalibr.write_text(
        "accelerometer_noise_density: 1.86e-03\naccelerometer_random_walk: 4.33e-04\n"
        "gyroscope_noise_density: 1.87e-04\ngyroscope_random_walk: 2.66e-05\n"
    )
    args.imu_calib = kalibr  # the flag beats the config
    assert source_options(args, cfg.imu)["imu_noise"].gyroscope_noise_density == 1.87e-4
    # a partial config on a CameraInfo bag: the figure given, the defaults for the rest
    bag = write_robot_bag(tmp_path / "partial", GOOD, realsense_tree())
    seq = BagSequence(bag, imu_noise=noise)
    assert seq.rig.imu is not None and seq.rig.imu.gyro_noise_density == 3e-4
    assert any("(some not given)" in n for n in seq.notes)
