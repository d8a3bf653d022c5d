"""The Asctec Firefly hexacopter (the EuRoC MAV) as a `visualization_msgs/MarkerArray`.

Made from primitives, so nothing is fetched from the network and no mesh is shipped: a body,
six arms, six motors with translucent rotor discs and two-bladed propellers that spin, and the
VI-Sensor box at the front. Dimensions follow the Firefly model of rotors_simulator
(arm length 0.215 m, rotor radius 0.10 m, rotors at 30 + 60k degrees).

Every marker is in the body frame (`frame_id`) with `frame_locked = True`, so Foxglove moves the
drone with the tf of that frame; publish it once per frame (or per pose) and it follows the
estimate. Publishing the same call with the ground truth's body frame and another colour gives a
second drone, so drift shows as two drones drifting apart.

Frames: EuRoC's body frame is the IMU frame of the VI-Sensor, with x pointing UP, y to the right
and z forward (along the cameras' optical axes; see cam0's `T_BS`), pitched down by about 22
degrees. The model is built in a level forward-left-up frame (`drone`) and placed by
`T_BODY_DRONE`: centre 0.10 m behind and 0.07 m above the IMU, because the VI-Sensor hangs at the
front of the Firefly, below the arms.

The rotors spin like the tutorial's joint-state publisher: each propeller's yaw about its motor
axis is `direction * 2 pi * spin_hz * t`, alternating direction from rotor to rotor. `spin_hz`
defaults to 2.5 revolutions/s (45 degrees per 20 Hz camera frame), slow enough not to alias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from eurocslam.geometry import F64, make_T, rot_to_quat_wxyz, rot_z, wxyz_to_xyzw

# visualization_msgs/Marker constants
CUBE = 1
SPHERE = 2
CYLINDER = 3
ADD = 0

MSGTYPE = "visualization_msgs/msg/MarkerArray"

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
    """One primitive of the model, posed in the `drone` frame (forward-left-up)."""

    name: str
    type: int  # CUBE / SPHERE / CYLINDER
    T_drone_part: F64  # 4x4
    scale: tuple[float, float, float]
    color: Rgba


def _shade(color: Rgba, alpha: float | None = None) -> Rgba:
    r, g, b, a = color
    return (r, g, b, a if alpha is None else alpha * a)


def rotor_angle(t_ns: int, index: int, spin_hz: float = DEFAULT_SPIN_HZ) -> float:
    """Propeller yaw [rad] about its motor axis at time `t_ns`, in [0, 2 pi)."""
    # integer-exact phase: (t_ns * spin_hz) mod 1e9, so huge epoch timestamps keep full precision
    turns = (int(t_ns) % 10**9) * spin_hz / 1e9 + (int(t_ns) // 10**9) * spin_hz
    return (ROTOR_DIRECTIONS[index] * 2.0 * math.pi * (turns % 1.0)) % (2.0 * math.pi)


def _static_parts(color: Rgba) -> list[Part]:
    eye = np.eye(3)
    parts = [
        Part("body", CYLINDER, make_T(eye, np.zeros(3)), (0.17, 0.17, 0.055), color),
        Part("canopy", SPHERE, make_T(eye, np.array([0.0, 0.0, 0.03])), (0.11, 0.11, 0.06), _DARK),
        Part(
            "vi_sensor",
            CUBE,
            make_T(eye, np.array([0.10, 0.0, -0.07])),
            (0.05, 0.13, 0.05),
            _SENSOR,
        ),
    ]
    for i, deg in enumerate(ROTOR_ANGLES_DEG):
        r_arm = rot_z(math.radians(deg))
        axis = r_arm @ np.array([1.0, 0.0, 0.0])
        front = deg in (30.0, 330.0)
        parts.append(
            Part(
                f"arm{i}",
                CUBE,
                make_T(r_arm, axis * ARM_LENGTH / 2.0),
                (ARM_LENGTH, 0.022, 0.016),
                _FRONT if front else _DARK,
            )
        )
        motor = axis * ARM_LENGTH
        parts.append(
            Part(
                f"motor{i}",
                CYLINDER,
                make_T(eye, motor + np.array([0.0, 0.0, ROTOR_HEIGHT / 2.0])),
                (0.03, 0.03, ROTOR_HEIGHT),
                _DARK,
            )
        )
        parts.append(
            Part(
                f"disc{i}",
                CYLINDER,
                make_T(eye, _hub(i)),
                (2 * ROTOR_RADIUS, 2 * ROTOR_RADIUS, 0.003),
                _shade(color, 0.3),
            )
        )
    return parts


def _hub(i: int) -> F64:
    """Centre of rotor `i`'s propeller in the drone frame."""
    yaw = math.radians(ROTOR_ANGLES_DEG[i])
    return np.array([ARM_LENGTH * math.cos(yaw), ARM_LENGTH * math.sin(yaw), ROTOR_HEIGHT])


def firefly_parts(t_ns: int, color: Rgba, spin_hz: float = DEFAULT_SPIN_HZ) -> list[Part]:
    """The model's primitives at time `t_ns` (only the propellers' angles depend on it)."""
    props = [
        Part(
            f"prop{i}",
            CUBE,
            make_T(rot_z(rotor_angle(t_ns, i, spin_hz)), _hub(i)),
            (2 * ROTOR_RADIUS * 0.95, 0.018, 0.004),
            _DARK,
        )
        for i in range(len(ROTOR_ANGLES_DEG))
    ]
    return _static_parts(color) + props


Posed = tuple[Part, tuple[float, float, float], tuple[float, float, float, float]]


def _pose_in_body(parts: list[Part]) -> list[Posed]:
    """Each part with its position and quaternion (xyzw) in the body frame."""
    if not parts:
        return []
    T_body_part = T_BODY_DRONE @ np.stack([p.T_drone_part for p in parts])
    q = wxyz_to_xyzw(rot_to_quat_wxyz(T_body_part[:, :3, :3]))
    t = T_body_part[:, :3, 3]
    return [
        (
            part,
            (float(ti[0]), float(ti[1]), float(ti[2])),
            (float(qi[0]), float(qi[1]), float(qi[2]), float(qi[3])),
        )
        for part, ti, qi in zip(parts, t, q, strict=True)
    ]


@lru_cache(maxsize=16)
def _static_posed(color: Rgba) -> list[Posed]:
    return _pose_in_body(_static_parts(color))


def _stamp(t_ns: int) -> dict[str, int]:
    return {"sec": int(t_ns) // 10**9, "nanosec": int(t_ns) % 10**9}


def _marker(posed: Posed, mid: int, frame_id: str, t_ns: int, ns: str) -> dict[str, Any]:
    part, (px, py, pz), (qx, qy, qz, qw) = posed
    r, g, b, a = part.color
    header = {"stamp": _stamp(t_ns), "frame_id": frame_id}
    return {
        "header": header,
        "ns": ns,
        "id": mid,
        "type": part.type,
        "action": ADD,
        "pose": {
            "position": {"x": px, "y": py, "z": pz},
            "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
        },
        "scale": {"x": part.scale[0], "y": part.scale[1], "z": part.scale[2]},
        "color": {"r": r, "g": g, "b": b, "a": a},
        "lifetime": {"sec": 0, "nanosec": 0},
        "frame_locked": True,
        "points": [],
        "colors": [],
        "texture_resource": "",
        "texture": {"header": header, "format": "", "data": b""},
        "uv_coordinates": [],
        "text": "",
        "mesh_resource": "",
        "mesh_file": {"filename": "", "data": b""},
        "mesh_use_embedded_materials": False,
    }


def drone_markers(
    frame_id: str,
    t_ns: int,
    color: Rgba = ESTIMATE_COLOR,
    ns: str = "drone",
    spin_hz: float = DEFAULT_SPIN_HZ,
) -> dict[str, Any]:
    """A `visualization_msgs/msg/MarkerArray` (as a ROS-field dict) drawing the Firefly.

    `frame_id`: the body frame the drone rides on (e.g. `body` for the estimate, the ground
    truth's body frame for the ground truth). `color`: RGBA in 0..1 of the body and rotor discs.
    `ns`: marker namespace; use different ones for the estimate and the ground truth so both
    drones exist side by side. Marker ids are stable (0..N-1), so each call replaces the last.
    """
    if not frame_id:
        raise ValueError("drone_markers: frame_id must not be empty")
    if len(color) != 4 or not all(0.0 <= c <= 1.0 for c in color):
        raise ValueError(f"drone_markers: color must be 4 values in 0..1, got {color!r}")
    color = tuple(float(c) for c in color)  # type: ignore[assignment]
    n_static = len(_static_posed(color))
    posed = _static_posed(color) + _pose_in_body(firefly_parts(t_ns, color, spin_hz)[n_static:])
    return {"markers": [_marker(p, i, frame_id, t_ns, ns) for i, p in enumerate(posed)]}
