"""The Firefly drone MarkerArray: structure, geometry, spinning rotors, colours, CDR encoding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eurocslam.geometry import quat_wxyz_to_rot, rotation_angle, xyzw_to_wxyz
from eurocslam.io import drone
from eurocslam.io.drone import (
    ARM_LENGTH,
    DEFAULT_SPIN_HZ,
    ESTIMATE_COLOR,
    GROUNDTRUTH_COLOR,
    R_BODY_DRONE,
    drone_markers,
)

T0 = 1_403_715_273_262_142_976  # a real V1_01 camera stamp


def _by_prefix(msg: dict, t_ns: int, prefix: str) -> list[dict]:
    names = [p.name for p in drone.firefly_parts(t_ns, ESTIMATE_COLOR)]
    return [m for m, n in zip(msg["markers"], names, strict=True) if n.startswith(prefix)]


def _R(m: dict) -> np.ndarray:
    o = m["pose"]["orientation"]
    return quat_wxyz_to_rot(xyzw_to_wxyz(np.array([o["x"], o["y"], o["z"], o["w"]])))


def _p(m: dict) -> np.ndarray:
    p = m["pose"]["position"]
    return np.array([p["x"], p["y"], p["z"]])


def test_structure_body_six_arms_six_rotors() -> None:
    msg = drone_markers("body", T0)
    ms = msg["markers"]
    assert len(_by_prefix(msg, T0, "arm")) == 6
    assert len(_by_prefix(msg, T0, "prop")) == 6
    assert len(_by_prefix(msg, T0, "disc")) == 6
    assert len(_by_prefix(msg, T0, "body")) == 1
    assert [m["id"] for m in ms] == list(range(len(ms)))
    for m in ms:
        assert m["header"]["frame_id"] == "body"
        assert m["header"]["stamp"] == {"sec": T0 // 10**9, "nanosec": T0 % 10**9}
        assert m["frame_locked"] is True
        assert m["ns"] == "drone"
        assert m["action"] == 0
        assert m["type"] in (drone.CUBE, drone.SPHERE, drone.CYLINDER)
        assert all(v > 0 for v in m["scale"].values())
        q = m["pose"]["orientation"]
        assert math.isclose(math.hypot(q["x"], q["y"], q["z"], q["w"]), 1.0, abs_tol=1e-9)


def test_rotors_sit_on_a_hexagon_in_the_rotor_plane() -> None:
    msg = drone_markers("body", T0)
    hubs = np.array([_p(m) for m in _by_prefix(msg, T0, "disc")])
    up_body = R_BODY_DRONE[:, 2]
    centre = hubs.mean(axis=0)
    # all hubs in one plane perpendicular to the drone's up axis, at the arm length
    assert np.allclose((hubs - centre) @ up_body, 0.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(hubs - centre, axis=1), ARM_LENGTH, atol=1e-12)
    # neighbours 60 degrees apart: equal chord = arm length for a regular hexagon
    chords = np.linalg.norm(hubs - np.roll(hubs, 1, axis=0), axis=1)
    assert np.allclose(chords, ARM_LENGTH, atol=1e-12)


def test_rotors_spin_in_alternating_directions() -> None:
    dt_ns = 50_000_000  # one 20 Hz camera frame
    a = _by_prefix(drone_markers("body", T0), T0, "prop")
    b = _by_prefix(drone_markers("body", T0 + dt_ns), T0 + dt_ns, "prop")
    expected = 2 * math.pi * DEFAULT_SPIN_HZ * dt_ns / 1e9  # 45 degrees
    up_body = R_BODY_DRONE[:, 2]
    signs = []
    for ma, mb in zip(a, b, strict=True):
        R_rel = _R(mb) @ _R(ma).T  # rotation from a to b, in the body frame
        assert math.isclose(rotation_angle(R_rel), expected, abs_tol=1e-6)
        axis = np.array(
            [R_rel[2, 1] - R_rel[1, 2], R_rel[0, 2] - R_rel[2, 0], R_rel[1, 0] - R_rel[0, 1]]
        )
        cos = float(axis @ up_body) / np.linalg.norm(axis)
        assert abs(abs(cos) - 1.0) < 1e-9  # spins about the motor axis
        signs.append(np.sign(cos))
        assert np.allclose(_p(ma), _p(mb))  # spins in place
    assert signs == [1, -1, 1, -1, 1, -1]


def test_static_parts_do_not_move_with_time() -> None:
    a = drone_markers("body", T0)["markers"]
    b = drone_markers("body", T0 + 123_456_789)["markers"]
    names = [p.name for p in drone.firefly_parts(T0, ESTIMATE_COLOR)]
    for ma, mb, n in zip(a, b, names, strict=True):
        if not n.startswith("prop"):
            assert ma["pose"] == mb["pose"]


def test_rotor_angle_keeps_precision_at_epoch_timestamps() -> None:
    # one full period later the angle must be the same, even at t ~ 1.4e18 ns
    period_ns = int(1e9 / DEFAULT_SPIN_HZ)
    assert math.isclose(
        drone.rotor_angle(T0, 0), drone.rotor_angle(T0 + period_ns, 0), abs_tol=1e-6
    )
    assert 0.0 <= drone.rotor_angle(T0, 1) < 2 * math.pi


def test_groundtruth_drone_other_colour_frame_and_namespace() -> None:
    est = drone_markers("body", T0)
    gt = drone_markers("gt_body", T0, color=GROUNDTRUTH_COLOR, ns="drone_gt")
    assert est["markers"][0]["color"] != gt["markers"][0]["color"]
    assert gt["markers"][0]["color"]["g"] == pytest.approx(GROUNDTRUTH_COLOR[1])
    assert {m["header"]["frame_id"] for m in gt["markers"]} == {"gt_body"}
    assert {m["ns"] for m in gt["markers"]} == {"drone_gt"}
    # same geometry
    assert [m["pose"] for m in est["markers"]] == [m["pose"] for m in gt["markers"]]


@pytest.mark.parametrize("color", [(1.0, 0.0, 0.0), (2.0, 0.0, 0.0, 1.0), (0, 0, 0, -1)])
def test_bad_colour_is_rejected(color: tuple) -> None:
    with pytest.raises(ValueError, match="color"):
        drone_markers("body", T0, color=color)  # type: ignore[arg-type]


def test_empty_frame_is_rejected() -> None:
    with pytest.raises(ValueError, match="frame_id"):
        drone_markers("", T0)


def test_drone_is_level_when_the_real_drone_rests_on_the_floor(v101_micro) -> None:
    """On V1_01 the drone stands on the floor. The model's up axis must agree with 'up' measured
    by the accelerometer in the IMU frame (the VI-Sensor is pitched down ~22 deg) and with the
    ground truth's gravity-aligned world z."""
    from eurocslam.dataset import open_sequence

    seq = open_sequence(v101_micro)
    acc = seq.imu.accel[:400].mean(axis=0)
    up_measured = acc / np.linalg.norm(acc)
    assert math.degrees(math.acos(float(up_measured @ R_BODY_DRONE[:, 2]))) < 2.0
    assert seq.groundtruth is not None
    gt = seq.groundtruth
    t_frames = seq.frame_times
    still = (gt.t_ns >= t_frames[0]) & (gt.t_ns <= t_frames[-1])  # the 4.7 s image window
    assert still.sum() > 50
    up_world = gt.T_world_body()[still, :3, :3] @ R_BODY_DRONE[:, 2]
    assert np.degrees(np.arccos(up_world[:, 2])).max() < 4.0
    # and forward (the drone's x) is the cameras' viewing direction, body z, levelled
    assert R_BODY_DRONE[:, 0] @ np.array([0.0, 0.0, 1.0]) > 0.9


def test_encodes_as_ros2_markerarray_and_decodes_with_rosbags() -> None:
    from mcap_ros2._dynamic import serialize_dynamic
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    text = store.generate_msgdef(drone.MSGTYPE, ros_version=2)[0]
    encode = serialize_dynamic("visualization_msgs/MarkerArray", text)[
        "visualization_msgs/MarkerArray"
    ]
    msg = drone_markers("gt_body", T0, color=GROUNDTRUTH_COLOR, ns="drone_gt")
    decoded = store.deserialize_cdr(encode(msg), drone.MSGTYPE)
    assert len(decoded.markers) == len(msg["markers"])
    for d, m in zip(decoded.markers, msg["markers"], strict=True):
        assert d.header.frame_id == "gt_body"
        assert d.header.stamp.sec == T0 // 10**9
        assert d.frame_locked
        assert d.type == m["type"]
        assert d.pose.position.x == m["pose"]["position"]["x"]
        assert d.pose.orientation.w == m["pose"]["orientation"]["w"]
        assert d.color.a == pytest.approx(m["color"]["a"])
