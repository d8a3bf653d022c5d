"""Dataset access: the EuRoC ASL reader, the KITTI odometry reader, ROS bags and MCAP as input
(`bag`), calibration, and the checks on a sequence before it is trusted (`doctor`)."""

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from eurocslam.dataset.asl import AslSequence
    from eurocslam.dataset.calib import CameraCalib, ImuCalib, StereoRig, default_rig, load_rig
    from eurocslam.dataset.kitti import KittiSequence
    from eurocslam.dataset.source import open_sequence
    from eurocslam.dataset.types import (
        GroundTruth,
        ImuData,
        PositionData,
        SequenceSource,
        SkipReport,
        StereoFrame,
        has_imu,
    )

# the module each name is in: loaded on first use, so that a module of the package (the
# extraction workers need `types` and `calib`) does not bring the readers of every source
# (ASL, KITTI, bags and their MCAP reader) with it: 0.06 s of each worker's start
_WHERE = {
    "AslSequence": "asl",
    "CameraCalib": "calib",
    "ImuCalib": "calib",
    "StereoRig": "calib",
    "default_rig": "calib",
    "load_rig": "calib",
    "KittiSequence": "kitti",
    "open_sequence": "source",
    "GroundTruth": "types",
    "ImuData": "types",
    "PositionData": "types",
    "SequenceSource": "types",
    "SkipReport": "types",
    "StereoFrame": "types",
    "has_imu": "types",
}

__all__ = [
    "AslSequence",
    "CameraCalib",
    "GroundTruth",
    "ImuCalib",
    "ImuData",
    "KittiSequence",
    "PositionData",
    "SequenceSource",
    "SkipReport",
    "StereoFrame",
    "StereoRig",
    "default_rig",
    "has_imu",
    "load_rig",
    "open_sequence",
]

if not TYPE_CHECKING:  # (type checkers see the imports above)

    def __getattr__(name: str) -> Any:
        where = _WHERE.get(name)
        if where is None:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        value = getattr(import_module(f"{__name__}.{where}"), name)
        globals()[name] = value
        return value
