"""The static transform tree of a bag (`/tf_static`, `tf2_msgs/TFMessage`) and lookups through it.

Each `geometry_msgs/TransformStamped` is an edge `header.frame_id` (parent) -> `child_frame_id`
holding `T_parent_child` (ROS: the child frame's pose in the parent frame, which maps child
points into the parent). A lookup composes a chain in either direction, e.g.
`camera_imu_optical_frame <- camera_gyro_frame <- camera_link -> camera_infra1_frame ->
camera_infra1_optical_frame`. Frame names lose a leading `/` (ROS 1 spelling). A child published
again replaces its earlier edge (tf keeps the latest); one published under two parents is an
error naming both.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from eurocslam.errors import CalibrationError
from eurocslam.geometry import F64, inv_T, make_T, normalize_quat, quat_wxyz_to_rot

TF_STATIC_TOPIC = "/tf_static"
TF_TYPE = "tf2_msgs/msg/TFMessage"


def frame_name(frame_id: str) -> str:
    """A tf frame name as tf2 spells it: no leading slash, no surrounding blanks."""
    return str(frame_id).strip().lstrip("/")


@dataclass(frozen=True)
class TfEdge:
    parent: str
    child: str
    T_parent_child: F64


def transform_matrix(translation: tuple[float, float, float], q_xyzw: tuple[float, ...]) -> F64:
    """4x4 `T_parent_child` from a ROS translation and x, y, z, w quaternion."""
    x, y, z, w = (float(v) for v in q_xyzw)
    try:
        q = normalize_quat(np.array([w, x, y, z]))
    except ValueError:
        raise ValueError("zero quaternion") from None
    return make_T(quat_wxyz_to_rot(q), np.asarray(translation, dtype=np.float64))


def edges_from_tf_message(msg: object, topic: str = TF_STATIC_TOPIC) -> list[TfEdge]:
    """The edges of one decoded `tf2_msgs/TFMessage` (ROS 1 or ROS 2)."""
    out = []
    for tr in getattr(msg, "transforms", ()):
        parent, child = frame_name(tr.header.frame_id), frame_name(tr.child_frame_id)
        if not parent or not child:
            raise CalibrationError(f"{topic}: a transform with an empty frame name")
        t, r = tr.transform.translation, tr.transform.rotation
        try:
            T = transform_matrix((t.x, t.y, t.z), (r.x, r.y, r.z, r.w))
        except ValueError:
            raise CalibrationError(
                f"{topic}: transform {parent} -> {child} has a zero quaternion"
            ) from None
        if not np.all(np.isfinite(T)):
            raise CalibrationError(f"{topic}: transform {parent} -> {child} is not finite")
        out.append(TfEdge(parent, child, T))
    return out


class TfTree:
    """Frames connected by static transforms; `lookup(target, source)` gives `T_target_source`."""

    def __init__(self, edges: Iterable[TfEdge] = (), topic: str = TF_STATIC_TOPIC) -> None:
        self.topic = topic
        self._parent: dict[str, TfEdge] = {}
        for e in edges:
            self.add(e)

    def add(self, edge: TfEdge) -> None:
        old = self._parent.get(edge.child)
        if old is not None and old.parent != edge.parent:
            raise CalibrationError(
                f"{self.topic}: frame '{edge.child}' has two parents, '{old.parent}' and "
                f"'{edge.parent}'"
            )
        self._parent[edge.child] = edge

    def __len__(self) -> int:
        return len(self._parent)

    @property
    def frames(self) -> set[str]:
        out = set(self._parent)
        out.update(e.parent for e in self._parent.values())
        return out

    def _neighbours(self) -> dict[str, list[tuple[str, F64]]]:
        """Each frame's neighbours with `T_frame_neighbour`."""
        nb: dict[str, list[tuple[str, F64]]] = {}
        for e in self._parent.values():
            nb.setdefault(e.parent, []).append((e.child, e.T_parent_child))
            nb.setdefault(e.child, []).append((e.parent, inv_T(e.T_parent_child)))
        return nb

    def path(self, target: str, source: str) -> list[str] | None:
        """The frames from `target` to `source` (both included), or None when not connected."""
        found = self._search(frame_name(target), frame_name(source))
        return None if found is None else found[0]

    def _search(self, target: str, source: str) -> tuple[list[str], F64] | None:
        if target == source:
            return [target], np.eye(4)
        nb = self._neighbours()
        if target not in nb or source not in nb:
            return None
        prev: dict[str, tuple[str, F64]] = {}
        queue = deque([target])
        seen = {target}
        while queue:
            f = queue.popleft()
            for n, T_f_n in nb[f]:
                if n in seen:
                    continue
                seen.add(n)
                prev[n] = (f, T_f_n)
                if n == source:
                    chain = [n]
                    T = np.eye(4)
                    while chain[-1] != target:
                        p, T_p_c = prev[chain[-1]]
                        T = T_p_c @ T
                        chain.append(p)
                    return chain[::-1], T
                queue.append(n)
        return None

    def connected(self, target: str, source: str) -> bool:
        return self._search(frame_name(target), frame_name(source)) is not None

    def lookup(self, target: str, source: str, what: str = "") -> F64:
        """`T_target_source` (maps `source` points into `target`); a one-line
        `CalibrationError` naming the topic and both frames when they are not connected."""
        t, s = frame_name(target), frame_name(source)
        found = self._search(t, s)
        if found is not None:
            return found[1]
        purpose = f" ({what})" if what else ""
        if not self._parent:
            raise CalibrationError(
                f"{self.topic}: no static transforms in the bag, so '{s}' cannot be placed "
                f"relative to '{t}'{purpose}"
            )
        missing = [f for f in (t, s) if f not in self.frames]
        known = ", ".join(sorted(self.frames)[:12]) + (" ..." if len(self.frames) > 12 else "")
        if missing:
            reason = f"frame '{missing[0]}' is not in the tree"
        else:
            reason = "the frames are in two unconnected trees"
        raise CalibrationError(
            f"{self.topic}: no transform chain from '{t}' to '{s}'{purpose}: {reason} "
            f"(frames: {known})"
        )
