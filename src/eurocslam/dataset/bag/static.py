"""What a bag says about its calibration, read before the index pass: every `/tf_static`
message (`tf_tree`), the first CameraInfo of each camera (`camera_info`), and the
`header.frame_id` of the first camera and IMU messages (which name their frames in the tree).
`left_is_first` decides left and right of a pair found by message type alone."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from eurocslam.dataset.bag.camera_info import CameraInfo, camera_info_from_msg
from eurocslam.dataset.bag.tf_tree import TF_STATIC_TOPIC, TF_TYPE, TfTree, edges_from_tf_message
from eurocslam.dataset.bag.topics import IMU_ROLES, INFO_ROLES
from eurocslam.errors import DatasetError


@dataclass
class BagStatic:
    tf: TfTree = field(default_factory=TfTree)
    camera_infos: dict[str, CameraInfo] = field(default_factory=dict)  # cam0 / cam1 -> info
    frame_ids: dict[str, str] = field(default_factory=dict)  # cam0, cam1, imu, ... -> frame_id

    def swap_cameras(self) -> None:
        for d in (self.camera_infos, self.frame_ids):
            swap(d, "cam0", "cam1")


def swap(d: dict[str, Any], k0: str, k1: str) -> None:
    """Exchange two keys' values (either may be absent)."""
    v0, v1 = d.pop(k0, None), d.pop(k1, None)
    if v1 is not None:
        d[k0] = v1
    if v0 is not None:
        d[k1] = v0


def read_static(
    reader: Any,
    role_conns: dict[str, list[Any]],
    topics: dict[str, str],
    decode: Callable[[bytes, Any, int], Any],
) -> BagStatic:
    """The static part of an open bag (`decode(raw, connection, log_ns)` decodes a message,
    its errors naming the topic; `topics`: role -> topic)."""
    out = BagStatic()

    def first(conns: list[Any]) -> Any | None:
        for conn, log_ns, raw in reader.messages(connections=conns):
            return decode(raw, conn, log_ns)
        return None

    tf_conns = [c for c in reader.connections if c.topic == TF_STATIC_TOPIC]
    tf_conns = [c for c in tf_conns if c.msgtype == TF_TYPE]
    if tf_conns:
        for conn, log_ns, raw in reader.messages(connections=tf_conns):
            for edge in edges_from_tf_message(decode(raw, conn, log_ns), TF_STATIC_TOPIC):
                out.tf.add(edge)
    for cam, info_role in INFO_ROLES.items():
        msg = first(role_conns[info_role]) if info_role in role_conns else None
        if msg is not None:
            out.camera_infos[cam] = camera_info_from_msg(msg, topics[info_role])
    for role in ("cam0", "cam1", *IMU_ROLES):
        msg = first(role_conns[role]) if role in role_conns else None
        if msg is not None:
            out.frame_ids[role] = str(msg.header.frame_id).strip().lstrip("/")
    return out


def left_is_first(static: BagStatic, first: str, second: str, where: str) -> tuple[bool, str]:
    """Whether the first camera of an unordered pair is the left one, and what said so: the tf
    tree (the other camera at +x in its optical frame), else the CameraInfo P (the right
    camera's P[0, 3] is negative)."""
    fa, fb = static.frame_ids.get("cam0", ""), static.frame_ids.get("cam1", "")
    infos = static.camera_infos
    x = 0.0
    how = ""
    if fa and fb and fa != fb and static.tf.connected(fa, fb):
        x = float(static.tf.lookup(fa, fb)[0, 3])  # the second camera's origin in the first's
        how = "the /tf_static baseline"
    elif "cam0" in infos and "cam1" in infos:
        x = infos["cam0"].Tx - infos["cam1"].Tx
        how = "the CameraInfo P[0, 3]"
    if not x:
        raise DatasetError(
            f"{where}: cannot tell the left camera from the right between {first} and {second} "
            "(no tf baseline, no P[0, 3]); name them with --topic left=TOPIC --topic right=TOPIC"
        )
    return x > 0, how
