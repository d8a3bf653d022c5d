"""Dataset access: the EuRoC ASL reader, the KITTI odometry reader, ROS bags and MCAP as input
(`bag`), calibration, and the checks on a sequence before it is trusted (`doctor`)."""

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
