"""The Asctec Firefly hexacopter (the EuRoC MAV) as a `visualization_msgs/MarkerArray`.

Made from primitives, so nothing is fetched from the network and no mesh is shipped: a body,
six arms (the two front ones red), six motors with translucent rotor discs and two-bladed
propellers that spin, and the VI-Sensor box at the front: seven markers (body, canopy and sensor
box as primitives; arms, motors, rotor discs and propellers as one LINE_LIST, SPHERE_LIST,
TRIANGLE_LIST and LINE_LIST each), so one message is small (~8 KB) and quick to build (~0.3 ms:
the static markers' encoding is cached).
Dimensions follow the Firefly model of rotors_simulator (arm length 0.215 m, rotor radius
0.10 m, rotors at 30 + 60k degrees).

Every marker is in the body frame (`frame_id`) with `frame_locked = True`, so Foxglove moves the
drone with the tf of that frame; publish it once per frame (or per pose) and it follows the
estimate. Publishing the same call with the ground truth's body frame and another colour gives a
second drone, so drift shows as two drones drifting apart.

Frames: EuRoC's body frame is the IMU frame of the VI-Sensor, with x pointing UP, y to the right
and z forward (along the cameras' optical axes; see cam0's `T_BS`), pitched down by about 22
degrees. The model is built in a level forward-left-up frame (`drone`) and placed by
`T_BODY_DRONE`: centre 0.10 m behind and 0.07 m above the IMU, because the VI-Sensor hangs at the
front of the Firefly, below the arms.

The rotors spin like the tutorial's joint-state publisher: each propeller's angle about its motor
axis is `direction * 2 pi * spin_hz * t`, alternating direction from rotor to rotor. `spin_hz`
defaults to 2.5 revolutions/s (45 degrees per 20 Hz camera frame), slow enough not to alias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from eurocslam.dataset.calib import StereoRig, default_rig
from eurocslam.geometry import F64, make_T
from eurocslam.io import cdr, ros2
from eurocslam.timebase import NS_PER_S

CUBE = ros2.MarkerType.CUBE
SPHERE = ros2.MarkerType.SPHERE
CYLINDER = ros2.MarkerType.CYLINDER
LINE_LIST = ros2.MarkerType.LINE_LIST
SPHERE_LIST = ros2.MarkerType.SPHERE_LIST
TRIANGLE_LIST = ros2.MarkerType.TRIANGLE_LIST
ADD = 0  # visualization_msgs/Marker action

MSGTYPE = ros2.MARKER_ARRAY

ARM_LENGTH = 0.215  # m, motor axis to body centre
ROTOR_RADIUS = 0.10  # m
ROTOR_ANGLES_DEG = (30.0, 90.0, 150.0, 210.0, 270.0, 330.0)  # yaw of each arm, from forward
ROTOR_DIRECTIONS = (1, -1, 1, -1, 1, -1)  # +1 counter-clockwise seen from above
ROTOR_HEIGHT = 0.04  # m, propeller plane above the arm plane
DEFAULT_SPIN_HZ = 2.5

# The VI-Sensor is pitched down on the Firefly: at rest on the floor (V1_01, first second) the
# accelerometer reads (9.09, 0.13, -3.69) m/s^2 in the IMU frame, i.e. "up" is 22 degrees from +x
# towards -z. The drone frame is levelled accordingly, so a drone at rest is drawn level.
MOUNT_PITCH_DEG = 22.0
_c, _s = math.cos(math.radians(MOUNT_PITCH_DEG)), math.sin(math.radians(MOUNT_PITCH_DEG))
_FORWARD, _LEFT, _UP = np.array([_s, 0.0, _c]), np.array([0.0, -1.0, 0.0]), np.array([_c, 0.0, -_s])
# drone (forward, left, up) -> EuRoC body/IMU (x up, y right, z forward); columns = drone axes
R_BODY_DRONE: F64 = np.column_stack([_FORWARD, _LEFT, _UP])
T_BODY_DRONE: F64 = make_T(R_BODY_DRONE, -0.10 * _FORWARD + 0.07 * _UP)

Rgba = tuple[float, float, float, float]

# colours of the estimate's drone and the ground truth's drone
ESTIMATE_COLOR: Rgba = (1.0, 0.45, 0.05, 1.0)  # orange
GROUNDTRUTH_COLOR: Rgba = (0.15, 0.85, 0.35, 0.75)  # green, slightly see-through
_DARK: Rgba = (0.12, 0.12, 0.14, 1.0)
_FRONT: Rgba = (0.9, 0.1, 0.1, 1.0)  # the two front arms, so heading reads at a glance
_SENSOR: Rgba = (0.55, 0.55, 0.6, 1.0)


@dataclass(frozen=True)
class Part:
    """One marker of the model, posed in the `drone` frame (forward-left-up). List markers
    (LINE_LIST, SPHERE_LIST, TRIANGLE_LIST) carry their `points` (N, 3) in the part frame and
    optionally per-point `colors` (N, 4)."""

    name: str
    type: int
    T_drone_part: F64  # 4x4
    scale: tuple[float, float, float]
    color: Rgba
    points: F64 | None = None
    colors: F64 | None = None


def _shade(color: Rgba, alpha: float) -> Rgba:
    r, g, b, a = color
    return (r, g, b, alpha * a)


def rotor_angle(t_ns: int, index: int, spin_hz: float = DEFAULT_SPIN_HZ) -> float:
    """Propeller yaw [rad] about its motor axis at time `t_ns`, in [0, 2 pi)."""
    # whole seconds and nanoseconds apart, so epoch timestamps (~1.4e18 ns) keep full precision
    turns = (int(t_ns) % NS_PER_S) * spin_hz / NS_PER_S + (int(t_ns) // NS_PER_S) * spin_hz
    return (ROTOR_DIRECTIONS[index] * 2.0 * math.pi * (turns % 1.0)) % (2.0 * math.pi)


def hub(i: int) -> F64:
    """Centre of rotor `i`'s propeller in the drone frame."""
    yaw = math.radians(ROTOR_ANGLES_DEG[i])
    return np.array([ARM_LENGTH * math.cos(yaw), ARM_LENGTH * math.sin(yaw), ROTOR_HEIGHT])


def _disc_triangles(n_seg: int = 12) -> F64:
    """Triangle fans (6 * n_seg triangles, points (6 * n_seg * 3, 3)) of the rotor discs."""
    a = np.linspace(0.0, 2.0 * math.pi, n_seg + 1)
    rim = ROTOR_RADIUS * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    tris = []
    for i in range(len(ROTOR_ANGLES_DEG)):
        c = hub(i)
        for k in range(n_seg):
            tris += [c, c + rim[k], c + rim[k + 1]]
    return np.array(tris)


def _static_parts(color: Rgba) -> list[Part]:
    eye = np.eye(3)
    ident = np.eye(4)
    arm_pts, arm_cols = [], []
    for i, deg in enumerate(ROTOR_ANGLES_DEG):
        tip = hub(i) * np.array([1.0, 1.0, 0.0])
        arm_pts += [np.zeros(3), tip]
        arm_cols += [_FRONT if deg in (30.0, 330.0) else _DARK] * 2
    motors = np.array([hub(i) - [0.0, 0.0, ROTOR_HEIGHT / 2.0] for i in range(6)])
    return [
        Part("body", CYLINDER, ident, (0.17, 0.17, 0.055), color),
        Part("canopy", SPHERE, make_T(eye, np.array([0.0, 0.0, 0.03])), (0.11, 0.11, 0.06), _DARK),
        Part(
            "vi_sensor",
            CUBE,
            make_T(eye, np.array([0.10, 0.0, -0.07])),
            (0.05, 0.13, 0.05),
            _SENSOR,
        ),
        # LINE_LIST: scale.x is the line width
        Part(
            "arms",
            LINE_LIST,
            ident,
            (0.022, 0.0, 0.0),
            (1.0, 1.0, 1.0, 1.0),
            points=np.array(arm_pts),
            colors=np.array(arm_cols),
        ),
        Part("motors", SPHERE_LIST, ident, (0.04, 0.04, 0.05), _DARK, points=motors),
        Part(
            "discs",
            TRIANGLE_LIST,
            ident,
            (1.0, 1.0, 1.0),
            _shade(color, 0.3),
            points=_disc_triangles(),
        ),
    ]


def propeller_points(t_ns: int, spin_hz: float = DEFAULT_SPIN_HZ) -> F64:
    """(12, 3) LINE_LIST end points of the six propellers at `t_ns`, in the drone frame."""
    half = 0.95 * ROTOR_RADIUS
    pts = np.empty((2 * len(ROTOR_ANGLES_DEG), 3))
    for i in range(len(ROTOR_ANGLES_DEG)):
        a = rotor_angle(t_ns, i, spin_hz)
        d = half * np.array([math.cos(a), math.sin(a), 0.0])
        pts[2 * i], pts[2 * i + 1] = hub(i) - d, hub(i) + d
    return pts


def firefly_parts(t_ns: int, color: Rgba, spin_hz: float = DEFAULT_SPIN_HZ) -> list[Part]:
    """The model's markers at time `t_ns` (only the propellers depend on it)."""
    return [*_static_in_body(color)[0], _props(t_ns, spin_hz)]


def _props(t_ns: int, spin_hz: float) -> Part:
    return Part(
        "props",
        LINE_LIST,
        np.eye(4),
        (0.018, 0.0, 0.0),
        _DARK,
        points=propeller_points(t_ns, spin_hz),
    )


@lru_cache(maxsize=16)
def _static_in_body(color: Rgba) -> tuple[list[Part], list[F64]]:
    parts = _static_parts(color)
    return parts, [T_BODY_DRONE @ p.T_drone_part for p in parts]


def _rgba(frame_id: str, color: Rgba) -> Rgba:
    if not frame_id:
        raise ValueError("drone_markers: frame_id must not be empty")
    if len(color) != 4 or not all(0.0 <= c <= 1.0 for c in color):
        raise ValueError(f"drone_markers: color must be 4 values in 0..1, got {color!r}")
    return (float(color[0]), float(color[1]), float(color[2]), float(color[3]))


def _marker(frame_id: str, t_ns: int, ns: str, i: int, part: Part, T_body_part: F64) -> ros2.Marker:
    return ros2.Marker(
        t_ns=int(t_ns),
        frame_id=frame_id,
        ns=ns,
        id=i,
        type=part.type,
        pose=T_body_part,
        scale=part.scale,
        color=part.color,
        action=ADD,
        frame_locked=True,
        points=part.points,
        colors=part.colors,
    )


def drone_marker_list(
    frame_id: str,
    t_ns: int,
    color: Rgba = ESTIMATE_COLOR,
    ns: str = "drone",
    spin_hz: float = DEFAULT_SPIN_HZ,
) -> list[ros2.Marker]:
    """The Firefly's markers (ids 0..N-1 in `ns`), posed in the body frame `frame_id`."""
    rgba = _rgba(frame_id, color)
    parts = firefly_parts(t_ns, rgba, spin_hz)
    poses = [*_static_in_body(rgba)[1], T_BODY_DRONE]  # the propellers' points are in `drone`
    return [
        _marker(frame_id, t_ns, ns, i, part, T_body_part)
        for i, (part, T_body_part) in enumerate(zip(parts, poses, strict=True))
    ]


@lru_cache(maxsize=16)
def _static_cdr(frame_id: str, color: Rgba, ns: str) -> tuple[bytes, tuple[int, ...]]:
    """The MarkerArray's CDR up to the propellers (marker count and the static markers), and
    the offsets of their stamps: only those and the propellers change from call to call."""
    parts, poses = _static_in_body(color)
    out = cdr.CdrWriter()
    out.u32(len(parts) + 1)
    stamps = []
    for i, (part, T_body_part) in enumerate(zip(parts, poses, strict=True)):
        out.align(4)
        stamps.append(len(out.buf))
        ros2.write_marker(out, _marker(frame_id, 0, ns, i, part, T_body_part))
    return bytes(out.buf), tuple(stamps)


def drone_markers(
    frame_id: str,
    t_ns: int,
    color: Rgba = ESTIMATE_COLOR,
    ns: str = "drone",
    spin_hz: float = DEFAULT_SPIN_HZ,
) -> bytes:
    """The Firefly as a CDR-encoded `visualization_msgs/msg/MarkerArray` (`MSGTYPE`), ready
    for any sink: `sink.write(topic, drone.MSGTYPE, t_ns, drone_markers("body", t_ns))`.

    `frame_id`: the body frame the drone rides on (e.g. `body` for the estimate, the ground
    truth's body frame for the ground truth). `color`: RGBA in 0..1 of the body and rotor discs
    (`ESTIMATE_COLOR`, `GROUNDTRUTH_COLOR`). `ns`: marker namespace; use different ones for the
    estimate and the ground truth so both drones exist side by side. Marker ids are stable, so
    each message replaces the previous one; `frame_locked` makes it follow the tf of `frame_id`.
    The same bytes as `ros2.marker_array(drone_marker_list(...))`, built from a cached encoding
    of the static markers (a call per frame and drone is on the tracking thread's path).
    """
    rgba = _rgba(frame_id, color)
    static, stamps = _static_cdr(frame_id, rgba, ns)
    out = cdr.CdrWriter()
    out.buf = bytearray(static)
    stamp = cdr.stamp_bytes(t_ns)
    for off in stamps:
        out.buf[off : off + len(stamp)] = stamp
    props = _props(t_ns, spin_hz)
    ros2.write_marker(out, _marker(frame_id, t_ns, ns, len(stamps), props, T_BODY_DRONE))
    return out.getvalue()


def flies_on(rig: StereoRig) -> bool:
    """The rig is the Firefly's VI-Sensor: EuRoC's camera placement on the IMU (cam0 within 1
    cm and 1 deg of EuRoC's `T_BS`), which `output.drone_model: auto` draws the Firefly for."""
    T_euroc = default_rig().cam0.T_body_cam
    T = rig.cam0.T_body_cam
    dR = T_euroc[:3, :3].T @ T[:3, :3]
    angle = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0))))
    return (
        rig.imu is not None
        and angle < 1.0
        and float(np.linalg.norm(T[:3, 3] - T_euroc[:3, 3])) < 0.01
    )
