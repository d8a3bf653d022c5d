"""Latched topics: which topics keep their newest message for late subscribers (ROS 2
transient-local durability, like `/tf_static`), and how an MCAP channel says so.

One definition for every sink: the MCAP writer marks these channels transient-local in their
`offered_qos_profiles` metadata (so `ros2 bag play` latches them), the live view re-sends their
newest message to each new viewer, and playing a recorded MCAP treats a channel as latched when
it is one of these topics or its metadata says transient-local.
"""

from __future__ import annotations

from collections.abc import Mapping

import yaml

LATCHED_TOPICS = frozenset({"/tf_static"})

# rmw enum values as rosbag2 (humble) serialises them: history 3 = UNKNOWN (as recorded),
# reliability 1 = RELIABLE, durability 1 = TRANSIENT_LOCAL / 2 = VOLATILE, liveliness 1 =
# AUTOMATIC; durations {0, 0} = "unspecified" (the rmw default: infinite).
_DURATION0 = {"sec": 0, "nsec": 0}


def qos_profile_yaml(*, transient_local: bool = False) -> str:
    """The `offered_qos_profiles` string of one publisher, in rosbag2's (humble) YAML form."""
    prof = [
        {
            "history": 3,
            "depth": 0,
            "reliability": 1,
            "durability": 1 if transient_local else 2,
            "deadline": dict(_DURATION0),
            "lifespan": dict(_DURATION0),
            "liveliness": 1,
            "liveliness_lease_duration": dict(_DURATION0),
            "avoid_ros_namespace_conventions": False,
        }
    ]
    return yaml.safe_dump(prof, default_flow_style=False, sort_keys=False).strip()


def is_transient_local(metadata: Mapping[str, str]) -> bool:
    """Whether an MCAP channel's metadata offers transient-local durability (latched)."""
    qos = metadata.get("offered_qos_profiles", "")
    return "durability: 1" in qos or "transient_local" in qos.lower()
