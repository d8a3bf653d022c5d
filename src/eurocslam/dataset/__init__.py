"""Dataset access: EuRoC ASL reader, calibration, validation (doctor) and synthetic generator."""

from eurocslam.dataset.asl import AslSequence, open_sequence
from eurocslam.dataset.calib import CameraCalib, ImuCalib, StereoRig, default_rig, load_rig
from eurocslam.dataset.types import (
    GroundTruth,
    ImuData,
    PositionData,
    SequenceSource,
    SkipReport,
    StereoFrame,
)

__all__ = [
    "AslSequence",
    "CameraCalib",
    "GroundTruth",
    "ImuCalib",
    "ImuData",
    "PositionData",
    "SequenceSource",
    "SkipReport",
    "StereoFrame",
    "StereoRig",
    "default_rig",
    "load_rig",
    "open_sequence",
]
