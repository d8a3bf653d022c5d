"""The Firefly drone MarkerArray: structure, geometry, spinning rotors, colours, CDR encoding.

Messages are decoded with rosbags' own humble definitions (a reader we did not write)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from eurocslam.geometry import quat_wxyz_to_rot, transform_points, xyzw_to_wxyz
from eurocslam.io import drone
from eurocslam.io.drone import (
    ARM_LENGTH,
    DEFAULT_SPIN_HZ,
    ESTIMATE_COLOR,
    GROUNDTRUTH_COLOR,
    R_BODY_DRONE,
    T_BODY_DRONE,
    drone_markers,
)

T0 = 1_403_715_273_262_142_976  # a real V1_01 camera stamp


def _decode(data: bytes):  # type: ignore[no-untyped-def]
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE).deserialize_cdr(data, drone.MSGTYPE)


def _names() -> list[str]:
    return [p.name for p in drone.firefly_parts(T0, ESTIMATE_COLOR)]


def _by_name(msg, name: str):  # type: ignore[no-untyped-def]
    return msg.markers[_names().index(name)]


def _T(m) -> np.ndarray:  # type: ignore[no-untyped-def]
    """4x4 pose of a decoded marker in its frame."""
    o, p = m.pose.orientation, m.pose.position
    T = np.eye(4)
    T[:3, :3] = quat_wxyz_to_rot(xyzw_to_wxyz(np.array([o.x, o.y, o.z, o.w])))
    T[:3, 3] = [p.x, p.y, p.z]
    return T


def _points_in_body(m) -> np.ndarray:  # type: ignore[no-untyped-def]
    pts = np.array([[p.x, p.y, p.z] for p in m.points])
    return transform_points(_T(m), pts)


def test_structure_body_six_arms_six_rotors() -> None:
    msg = _decode(drone_markers("body", T0))
    assert len(msg.markers) == len(_names())
    assert [m.id for m in msg.markers] == list(range(len(msg.markers)))
    for m in msg.markers:
        assert m.header.frame_id == "body"
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == (T0 // 10**9, T0 % 10**9)
        assert m.frame_locked
        assert m.ns == "drone"
        assert m.action == 0
        assert m.scale.x > 0
        q = m.pose.orientation
        assert math.isclose(math.hypot(q.x, q.y, q.z, q.w), 1.0, abs_tol=1e-9)
    assert _by_name(msg, "body").type == drone.CYLINDER
    arms = _by_name(msg, "arms")
    assert arms.type == drone.LINE_LIST and len(arms.points) == 12  # six segments
    assert len(arms.colors) == 12
    assert _by_name(msg, "motors").type == drone.SPHERE_LIST
    assert len(_by_name(msg, "motors").points) == 6
    props = _by_name(msg, "props")
    assert props.type == drone.LINE_LIST and len(props.points) == 12
    discs = _by_name(msg, "discs")
    assert discs.type == drone.TRIANGLE_LIST and len(discs.points) % (3 * 6) == 0
    assert discs.color.a < 0.5  # see-through rotor discs


def test_rotors_sit_on_a_regular_hexagon_in_the_rotor_plane() -> None:
    msg = _decode(drone_markers("body", T0))
    props = _points_in_body(_by_name(msg, "props")).reshape(6, 2, 3)
    hubs = props.mean(axis=1)  # each propeller is centred on its motor axis
    up_body = R_BODY_DRONE[:, 2]
    centre = transform_points(T_BODY_DRONE, np.array([[0.0, 0.0, drone.ROTOR_HEIGHT]]))[0]
    assert np.allclose((hubs - centre) @ up_body, 0.0, atol=1e-9)
    assert np.allclose(np.linalg.norm(hubs - centre, axis=1), ARM_LENGTH, atol=1e-9)
    chords = np.linalg.norm(hubs - np.roll(hubs, 1, axis=0), axis=1)
    assert np.allclose(chords, ARM_LENGTH, atol=1e-9)  # regular hexagon: chord = radius
    # the arms end under the rotors
    arms = _points_in_body(_by_name(msg, "arms")).reshape(6, 2, 3)
    assert np.allclose(arms[:, 1] + drone.ROTOR_HEIGHT * up_body, hubs, atol=1e-9)


def _prop_directions(t_ns: int) -> np.ndarray:
    """Unit blade directions (6, 3) in the body frame."""
    pts = _points_in_body(_by_name(_decode(drone_markers("body", t_ns)), "props")).reshape(6, 2, 3)
    d = pts[:, 1] - pts[:, 0]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_rotors_spin_in_alternating_directions() -> None:
    dt_ns = 50_000_000  # one 20 Hz camera frame
    a, b = _prop_directions(T0), _prop_directions(T0 + dt_ns)
    expected = 2 * math.pi * DEFAULT_SPIN_HZ * dt_ns / 1e9  # 45 degrees
    up_body = R_BODY_DRONE[:, 2]
    signs = []
    for da, db in zip(a, b, strict=True):
        assert abs(float(da @ up_body)) < 1e-9  # blades lie in the rotor plane
        angle = math.atan2(float(np.cross(da, db) @ up_body), float(da @ db))
        assert math.isclose(abs(angle), expected, abs_tol=1e-6)
        signs.append(int(np.sign(angle)))
    assert signs == [1, -1, 1, -1, 1, -1]


def test_static_parts_do_not_move_with_time() -> None:
    a = _decode(drone_markers("body", T0)).markers
    b = _decode(drone_markers("body", T0 + 123_456_789)).markers
    for ma, mb, name in zip(a, b, _names(), strict=True):
        if name != "props":
            assert ma.pose == mb.pose
            assert ma.points == mb.points


def test_rotor_angle_keeps_precision_at_epoch_timestamps() -> None:
    period_ns = int(1e9 / DEFAULT_SPIN_HZ)  # one full turn later: the same angle
    assert math.isclose(
        drone.rotor_angle(T0, 0), drone.rotor_angle(T0 + period_ns, 0), abs_tol=1e-6
    )
    assert 0.0 <= drone.rotor_angle(T0, 1) < 2 * math.pi


def test_groundtruth_drone_other_colour_frame_and_namespace() -> None:
    est = _decode(drone_markers("body", T0))
    gt = _decode(drone_markers("gt_body", T0, color=GROUNDTRUTH_COLOR, ns="drone_gt"))
    assert _by_name(est, "body").color != _by_name(gt, "body").color
    assert _by_name(gt, "body").color.g == pytest.approx(GROUNDTRUTH_COLOR[1])
    assert _by_name(est, "body").color.r == pytest.approx(ESTIMATE_COLOR[0])
    assert {m.header.frame_id for m in gt.markers} == {"gt_body"}
    assert {m.ns for m in gt.markers} == {"drone_gt"}
    assert [m.pose for m in est.markers] == [m.pose for m in gt.markers]  # same geometry


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
    gt = seq.groundtruth
    assert gt is not None
    t_frames = seq.frame_times
    still = (gt.t_ns >= t_frames[0]) & (gt.t_ns <= t_frames[-1])  # the 4.7 s image window
    assert still.sum() > 50
    up_world = gt.T_world_body()[still, :3, :3] @ R_BODY_DRONE[:, 2]
    assert np.degrees(np.arccos(up_world[:, 2])).max() < 4.0
    # forward (the drone's x) is the cameras' viewing direction, body z, levelled
    assert R_BODY_DRONE[:, 0] @ np.array([0.0, 0.0, 1.0]) > 0.9


@pytest.mark.parametrize(
    ("frame_id", "color", "ns"),
    [("body", ESTIMATE_COLOR, "drone"), ("gt_body", GROUNDTRUTH_COLOR, "drone_gt")],
)
def test_cached_encoding_equals_a_fresh_one(frame_id: str, color: tuple, ns: str) -> None:
    from eurocslam.io import ros2

    for t in (0, 1, 999_999_999, 1_000_000_007, T0, T0 + 50_000_000):
        fresh = ros2.marker_array(drone.drone_marker_list(frame_id, t, color, ns))
        assert drone_markers(frame_id, t, color, ns) == fresh
    msg = _decode(drone_markers(frame_id, T0 + 7, color, ns))
    assert {m.header.stamp.nanosec for m in msg.markers} == {(T0 + 7) % 1_000_000_000}


def test_the_firefly_is_drawn_where_the_rig_is_its_vi_sensor() -> None:
    """`output.drone_model: auto`: EuRoC's rig carries the Firefly; the same cameras moved by
    5 cm on the body, or a rig without an IMU (a car's), do not."""
    from eurocslam.dataset.calib import default_rig
    from eurocslam.io.drone import flies_on

    rig = default_rig()
    assert flies_on(rig)
    T = rig.cam0.T_body_cam.copy()
    T[0, 3] += 0.05
    moved = dataclasses.replace(rig, cam0=dataclasses.replace(rig.cam0, T_body_cam=T))
    assert not flies_on(moved)
    assert not flies_on(dataclasses.replace(rig, imu=None))
