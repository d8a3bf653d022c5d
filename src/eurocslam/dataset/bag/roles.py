"""Which topic of a bag plays which role: the user's `--topic`, else the first default name the
bag has (EuRoC's, `topics.TopicMap`), else found by message type (`discovery`: the cameras,
the IMU as one stream or as accelerometer + gyroscope, the CameraInfo beside each camera)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from eurocslam.dataset.bag.discovery import camera_info_topic, discover_imu, discover_stereo
from eurocslam.dataset.bag.topics import IMU_ROLES, INFO_ROLES, ROLES, TopicMap
from eurocslam.errors import DatasetError


@dataclass
class RoleChoice:
    topics: dict[str, str]  # role -> topic
    unordered: bool = False  # cam0/cam1 found by type; left and right still to be decided
    notes: list[str] = field(default_factory=list)


def choose_roles(
    bag_topics: Mapping[str, tuple[str, int]], topic_map: TopicMap, where: str
) -> RoleChoice:
    """Each role's topic (`bag_topics`: topic -> (message type, count)). Errors name `where`
    and list what the bag has."""
    types = {n: t for n, (t, _) in bag_topics.items()}
    listing = ", ".join(f"{n} ({t}, {c})" for n, (t, c) in sorted(bag_topics.items()))
    out = RoleChoice({})
    chosen = out.topics
    for role in ROLES:
        cands = topic_map.candidates(role)
        found = next((t for t in cands if t in types), None)
        if found is not None:
            chosen[role] = found
        elif role in topic_map.explicit:
            raise DatasetError(
                f"{where}: no topic for {role} (looked for {', '.join(cands)}; map "
                f"one with --topic {role}=TOPIC). The bag has: {listing or 'no topics'}"
            )
    if "cam0" not in chosen or "cam1" not in chosen:
        missing = "cam0" if "cam0" not in chosen else "cam1"
        try:
            pair = discover_stereo(types, chosen.get("cam0"), chosen.get("cam1"), where)
        except DatasetError as e:
            reason = str(e).removeprefix(f"{where}: ")
            raise DatasetError(
                f"{where}: no topic for {missing} (looked for "
                f"{', '.join(topic_map.candidates(missing))}, then by message type: {reason}; "
                f"or --topic {missing}=TOPIC). The bag has: {listing or 'no topics'}"
            ) from None
        chosen["cam0"], chosen["cam1"] = pair.left, pair.right
        out.unordered = not pair.ordered
        if pair.ordered:
            out.notes.append(
                f"stereo pair found by {pair.how}: left {pair.left}, right {pair.right}"
            )
    if not any(r in chosen for r in IMU_ROLES):
        found_imu = discover_imu(types, where)
        for role in IMU_ROLES:
            t = getattr(found_imu, role)
            if t is not None:
                chosen[role] = t
        if found_imu.how:
            picked = ", ".join(f"{r} {chosen[r]}" for r in IMU_ROLES if r in chosen)
            out.notes.append(f"IMU found by message type ({found_imu.how}): {picked}")
    if "imu" in chosen and ("accel" in chosen or "gyro" in chosen):
        raise DatasetError(
            f"{where}: an IMU topic ({chosen['imu']}) and separate accel/gyro topics were both "
            "given; use one or the other"
        )
    if ("accel" in chosen) != ("gyro" in chosen):
        have, need = ("accel", "gyro") if "accel" in chosen else ("gyro", "accel")
        raise DatasetError(
            f"{where}: {have} topic {chosen[have]} without a {need} topic (add "
            f"--topic {need}=TOPIC)"
        )
    for cam, info_role in INFO_ROLES.items():
        if info_role not in chosen:
            t = camera_info_topic(chosen[cam], types)
            if t is not None:
                chosen[info_role] = t
    if chosen["cam0"] == chosen["cam1"]:
        raise DatasetError(f"{where}: cam0 and cam1 both map to {chosen['cam0']}")
    return out
