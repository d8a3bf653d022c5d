"""Which bag topic plays which role (cam0, cam1, imu, groundtruth, leica), and the message types a
role accepts. Defaults cover EuRoC's ROS 1 bags and the MCAPs `eurocslam convert` writes. What
the scan learns of a role's topic: its stamps (`TopicStats`), a camera's images (`ImageInfo`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.types import I64
from eurocslam.errors import DatasetError

ROLES = ("cam0", "cam1", "imu", "groundtruth", "leica")
REQUIRED_ROLES = ("cam0", "cam1")  # without an IMU topic the input is stereo-only
ROLE_ALIASES = {
    "cam0": "cam0", "left": "cam0",
    "cam1": "cam1", "right": "cam1",
    "imu": "imu", "imu0": "imu",
    "groundtruth": "groundtruth", "gt": "groundtruth", "vicon": "groundtruth",
    "leica": "leica", "leica0": "leica",
}  # fmt: skip

EUROC_VICON_TOPIC = "/vicon/firefly_sbx/firefly_sbx"


@dataclass(frozen=True)
class TopicMap:
    """Which topic plays which role. Each role lists candidates; the first present one is used.

    Defaults cover EuRoC's ROS 1 bags and the MCAPs `eurocslam convert` writes. A user-given
    topic (`--topic cam0=/my/left`) replaces the candidates and must then be present.
    """

    cam0: tuple[str, ...] = ("/cam0/image_raw", "/cam0/image_raw/compressed")
    cam1: tuple[str, ...] = ("/cam1/image_raw", "/cam1/image_raw/compressed")
    imu: tuple[str, ...] = ("/imu0",)
    groundtruth: tuple[str, ...] = ("/groundtruth/pose", EUROC_VICON_TOPIC)
    leica: tuple[str, ...] = ("/leica0", "/leica/position")
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
        return ", ".join(f"{r}={'|'.join(self.candidates(r))}" for r in ROLES)


IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
ROLE_TYPES: dict[str, tuple[str, ...]] = {
    "cam0": IMAGE_TYPES,
    "cam1": IMAGE_TYPES,
    "imu": ("sensor_msgs/msg/Imu",),
    "groundtruth": (
        "geometry_msgs/msg/PoseStamped",
        "geometry_msgs/msg/TransformStamped",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        "nav_msgs/msg/Odometry",
    ),
    "leica": ("geometry_msgs/msg/PointStamped",),
}


ROLE_FIELDS = tuple(f.name for f in fields(TopicMap) if f.name != "explicit")
assert ROLE_FIELDS == ROLES


@dataclass
class TopicStats:
    """Stamps of one role's topic in the order the bag stores them (log-time order)."""

    role: str
    topic: str
    msgtype: str
    header_ns: list[int] | I64 = field(default_factory=list)  # lists while scanning,
    log_ns: list[int] | I64 = field(default_factory=list)  # int64 arrays after `freeze`

    def freeze(self) -> None:
        """Turn the stamp lists into int64 arrays (a quarter of the memory)."""
        self.header_ns = np.asarray(self.header_ns, dtype=np.int64)
        self.log_ns = np.asarray(self.log_ns, dtype=np.int64)

    @property
    def count(self) -> int:
        return len(self.log_ns)

    def header_array(self) -> I64:
        return np.asarray(self.header_ns, dtype=np.int64)

    def log_array(self) -> I64:
        return np.asarray(self.log_ns, dtype=np.int64)

    def unset_stamps(self) -> NDArray[np.bool_]:
        """Messages whose header stamp is zero though they were logged later: the stamp was never
        set (a stamp and log time both 0, as a sequence whose times start at 0 has, is real)."""
        unset: NDArray[np.bool_] = (self.header_array() == 0) & (self.log_array() != 0)
        return unset

    @property
    def zero_stamps(self) -> int:
        return int(np.count_nonzero(self.unset_stamps()))


@dataclass(frozen=True)
class ImageInfo:
    """What the first message of a camera topic says about its images."""

    topic: str
    msgtype: str
    encoding: str  # Image encoding, or CompressedImage format
    width: int
    height: int
