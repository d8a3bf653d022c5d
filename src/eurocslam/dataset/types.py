"""Typed data at the dataset boundary. Timestamps are int64 nanoseconds."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.calib import StereoRig
from eurocslam.geometry import F64, make_T, quat_wxyz_to_rot

I64 = NDArray[np.int64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class StereoFrame:
    """One stereo pair. `left`/`right` are 8-bit mono images, or None when that camera's image
    is missing or unreadable (only yielded when incomplete frames are asked for)."""

    t_ns: int
    left: U8 | None
    right: U8 | None
    left_path: Path | None = None
    right_path: Path | None = None

    @property
    def complete(self) -> bool:
        return self.left is not None and self.right is not None


@dataclass(frozen=True)
class ImuData:
    """IMU samples in the IMU frame: gyro [rad/s], accel [m/s^2]."""

    t_ns: I64
    gyro: F64
    accel: F64

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def slice(self, t0_ns: int, t1_ns: int) -> ImuData:
        """Samples with t0 <= t <= t1."""
        i0 = int(np.searchsorted(self.t_ns, t0_ns, side="left"))
        i1 = int(np.searchsorted(self.t_ns, t1_ns, side="right"))
        return ImuData(self.t_ns[i0:i1], self.gyro[i0:i1], self.accel[i0:i1])


def empty_imu() -> ImuData:
    """No IMU samples (a stereo-only sequence)."""
    return ImuData(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))


@dataclass(frozen=True)
class GroundTruth:
    """Pose of the body (IMU) frame in the ground-truth world frame (`T_gtworld_body`), with
    velocity and biases when the source has them (ASL 17-column format)."""

    t_ns: I64
    p: F64  # (N, 3)
    q_wxyz: F64  # (N, 4), normalised
    v: F64 | None = None  # (N, 3)
    bg: F64 | None = None  # gyro bias (N, 3)
    ba: F64 | None = None  # accel bias (N, 3)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def T_world_body(self) -> F64:
        """(N, 4, 4) poses."""
        return make_T(quat_wxyz_to_rot(self.q_wxyz), self.p)


@dataclass(frozen=True)
class PositionData:
    """Position-only measurements (leica0), in the ground-truth world frame."""

    t_ns: I64
    p: F64


@dataclass
class SkipReport:
    """Counted, reported-once problems that do not stop reading (missing images, etc.)."""

    counts: dict[str, int] = field(default_factory=dict)
    examples: dict[str, list[str]] = field(default_factory=dict)

    def add(self, kind: str, example: str) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        ex = self.examples.setdefault(kind, [])
        if len(ex) < 3:
            ex.append(example)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def lines(self) -> list[str]:
        out = []
        for kind, n in sorted(self.counts.items()):
            ex = ", ".join(self.examples.get(kind, []))
            out.append(f"{n} x {kind} (e.g. {ex})")
        return out


class SequenceSource(Protocol):
    """What the pipeline needs from any input (ASL folder, KITTI sequence, ROS bag, MCAP). A
    stereo-only source has no IMU rows (`imu` empty) and `rig.imu` None."""

    name: str
    rig: StereoRig
    imu: ImuData
    groundtruth: GroundTruth | None
    leica: PositionData | None
    skips: SkipReport

    @property
    def frame_times(self) -> I64:
        """Timestamps of every stereo frame the source knows (complete or not)."""
        ...

    def frames(
        self,
        *,
        include_incomplete: bool = False,
        t_start_ns: int | None = None,
        t_end_ns: int | None = None,
    ) -> Iterator[StereoFrame]: ...


def has_imu(source: SequenceSource) -> bool:
    """The source can run stereo-inertial: it has IMU rows and an IMU calibration."""
    return len(source.imu) > 0 and source.rig.imu is not None
