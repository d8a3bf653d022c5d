"""Which bag topic plays which role (cam0, cam1, imu or accel + gyro, groundtruth, leica, and the
cameras' CameraInfo), and the message types a role accepts. Defaults cover EuRoC's ROS 1 bags
and the MCAPs `eurocslam convert` writes; other bags' topics are found by message type
(`discovery`) or named with `--topic ROLE=TOPIC`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

from eurocslam.errors import DatasetError

ROLES = ("cam0", "cam1", "imu", "accel", "gyro", "groundtruth", "leica", "cam0_info", "cam1_info")
REQUIRED_ROLES = ("cam0", "cam1")  # without an IMU topic the input is stereo-only
IMU_ROLES = ("imu", "accel", "gyro")  # one united stream, or accelerometer and gyro apart
INFO_ROLES = {"cam0": "cam0_info", "cam1": "cam1_info"}
ROLE_ALIASES = {
    "cam0": "cam0", "left": "cam0",
    "cam1": "cam1", "right": "cam1",
    "imu": "imu", "imu0": "imu",
    "accel": "accel", "accelerometer": "accel",
    "gyro": "gyro", "gyroscope": "gyro",
    "groundtruth": "groundtruth", "gt": "groundtruth", "vicon": "groundtruth",
    "leica": "leica", "leica0": "leica",
    "cam0_info": "cam0_info", "left_info": "cam0_info",
    "cam1_info": "cam1_info", "right_info": "cam1_info",
}  # fmt: skip

EUROC_VICON_TOPIC = "/vicon/firefly_sbx/firefly_sbx"


@dataclass(frozen=True)
class TopicMap:
    """Which topic plays which role. Each role lists candidates; the first present one is used.

    Defaults cover EuRoC's ROS 1 bags and the MCAPs `eurocslam convert` writes; roles without
    a default (accel, gyro, the CameraInfo topics) and cameras or IMU not under a default name
    are found by message type (`discovery`). A user-given topic (`--topic cam0=/my/left`)
    replaces the candidates and must then be present.
    """

    cam0: tuple[str, ...] = ("/cam0/image_raw", "/cam0/image_raw/compressed")
    cam1: tuple[str, ...] = ("/cam1/image_raw", "/cam1/image_raw/compressed")
    imu: tuple[str, ...] = ("/imu0",)
    accel: tuple[str, ...] = ()
    gyro: tuple[str, ...] = ()
    groundtruth: tuple[str, ...] = ("/groundtruth/pose", EUROC_VICON_TOPIC)
    leica: tuple[str, ...] = ("/leica0", "/leica/position")
    cam0_info: tuple[str, ...] = ()
    cam1_info: tuple[str, ...] = ()
    # roles the user set explicitly (then the topic must exist)
    explicit: frozenset[str] = frozenset()

    def candidates(self, role: str) -> tuple[str, ...]:
        return tuple(getattr(self, role))

    def with_topics(self, mapping: Mapping[str, str]) -> TopicMap:
        """Override roles: `{"cam0": "/my/left"}`. Role names accept aliases (left, imu0, gt)."""
        changes: dict[str, Any] = {}
        for key, topic in mapping.items():
            role = ROLE_ALIASES.get(key.strip().lower())
            if role is None:
                raise DatasetError(
                    f"--topic {key}={topic}: unknown role '{key}' (roles: {', '.join(ROLES)})"
                )
            topic = topic.strip()
            if not topic:
                raise DatasetError(f"--topic {key}=: empty topic name")
            changes[role] = (topic if topic.startswith("/") else "/" + topic,)
        return replace(self, **changes, explicit=self.explicit | frozenset(changes))

    @classmethod
    def from_specs(cls, specs: Sequence[str] | None) -> TopicMap:
        """Parse `ROLE=TOPIC` strings (the CLI's repeated `--topic`)."""
        mapping: dict[str, str] = {}
        for spec in specs or ():
            if "=" not in spec:
                raise DatasetError(
                    f"--topic '{spec}': expected ROLE=TOPIC, e.g. cam0=/my/left (--topic maps "
                    "input bag topics; convert's --topics selects output topics)"
                )
            key, topic = spec.split("=", 1)
            mapping[key] = topic
        return cls().with_topics(mapping)

    def describe(self) -> str:
        return ", ".join(f"{r}={'|'.join(self.candidates(r))}" for r in ROLES if self.candidates(r))


IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
ROLE_TYPES: dict[str, tuple[str, ...]] = {
    "cam0": IMAGE_TYPES,
    "cam1": IMAGE_TYPES,
    "imu": ("sensor_msgs/msg/Imu",),
    "accel": ("sensor_msgs/msg/Imu",),
    "gyro": ("sensor_msgs/msg/Imu",),
    "groundtruth": (
        "geometry_msgs/msg/PoseStamped",
        "geometry_msgs/msg/TransformStamped",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        "nav_msgs/msg/Odometry",
    ),
    "leica": ("geometry_msgs/msg/PointStamped",),
    "cam0_info": ("sensor_msgs/msg/CameraInfo",),
    "cam1_info": ("sensor_msgs/msg/CameraInfo",),
}


ROLE_FIELDS = tuple(f.name for f in fields(TopicMap) if f.name != "explicit")
assert ROLE_FIELDS == ROLES
