"""`Trajectory`: timestamped poses of the body frame in some world frame (`T_world_body`).

* `t_ns`: int64 nanoseconds, non-decreasing within each segment (repeats are kept, as evo does);
* `p`: (N, 3) positions in metres;
* `q_wxyz`: (N, 4) unit quaternions, w first (converted to/from x-first only via `geometry`);
* `segment`: optional (N,) int64 segment id per pose. A SLAM run that resets starts a new
  segment; each segment lives in its own world frame and is aligned on its own by `eval`.

A core type: it imports no I/O. Files (TUM, EuRoC CSV) are read and written by
`eurocslam.trajectory_io`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64, make_T, quat_wxyz_to_rot, rot_to_quat_wxyz
from eurocslam.timebase import I64, NS_PER_S


@dataclass(frozen=True)
class Trajectory:
    """Timestamped poses `T_world_body`. See the module docstring for the fields."""

    t_ns: I64
    p: F64
    q_wxyz: F64
    segment: I64 | None = None
    name: str = ""

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns)
        if t.ndim != 1 or t.dtype != np.int64:
            raise ValueError(f"Trajectory.t_ns must be int64[N], got {t.dtype}{list(t.shape)}")
        n = t.shape[0]
        if np.shape(self.p) != (n, 3):
            raise ValueError(f"Trajectory.p must be ({n}, 3), got {np.shape(self.p)}")
        if np.shape(self.q_wxyz) != (n, 4):
            raise ValueError(f"Trajectory.q_wxyz must be ({n}, 4), got {np.shape(self.q_wxyz)}")
        if self.segment is not None and np.shape(self.segment) != (n,):
            raise ValueError(f"Trajectory.segment must be ({n},), got {np.shape(self.segment)}")

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @classmethod
    def from_poses(
        cls, t_ns: I64, T_world_body: F64, segment: I64 | None = None, name: str = ""
    ) -> Trajectory:
        """Build from (N, 4, 4) rigid transforms."""
        T = np.asarray(T_world_body, dtype=np.float64)
        return cls(
            np.asarray(t_ns, dtype=np.int64),
            np.ascontiguousarray(T[:, :3, 3]),
            rot_to_quat_wxyz(T[:, :3, :3]),
            segment,
            name,
        )

    def rotations(self) -> F64:
        """(N, 3, 3) rotation matrices R_world_body."""
        return quat_wxyz_to_rot(self.q_wxyz)

    def T_world_body(self) -> F64:
        """(N, 4, 4) poses."""
        return make_T(self.rotations(), self.p)

    @property
    def has_segments(self) -> bool:
        return self.segment is not None and np.unique(self.segment).size > 1

    def take(self, idx: NDArray[np.integer] | slice) -> Trajectory:
        """A new trajectory with the poses at `idx` (index array or slice)."""
        seg = None if self.segment is None else self.segment[idx]
        return Trajectory(self.t_ns[idx], self.p[idx], self.q_wxyz[idx], seg, self.name)

    def segments(self) -> list[tuple[int, Trajectory]]:
        """(segment id, poses) in order of first appearance; one entry (0) without segments."""
        if self.segment is None:
            return [(0, self)]
        out = []
        ids, first = np.unique(self.segment, return_index=True)
        for sid in ids[np.argsort(first)]:
            out.append((int(sid), self.take(np.flatnonzero(self.segment == sid))))
        return out

    def with_name(self, name: str) -> Trajectory:
        return Trajectory(self.t_ns, self.p, self.q_wxyz, self.segment, name)

    def duration_s(self) -> float:
        return float(self.t_ns[-1] - self.t_ns[0]) / NS_PER_S if len(self) else 0.0

    def path_length(self) -> float:
        """Travelled distance in metres (sum of position steps within segments)."""
        total = 0.0
        for _, seg in self.segments():
            if len(seg) > 1:
                total += float(np.linalg.norm(np.diff(seg.p, axis=0), axis=1).sum())
        return total
