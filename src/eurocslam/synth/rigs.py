"""The rigs `eurocslam synth --rig NAME` renders with, shipped in the package: `euroc` (EuRoC's
VI-sensor, the default) and `realsense` (a RealSense-like 848x480 infrared pair at 30 Hz with a
~5 cm baseline and a 400 Hz IMU; not a real device's calibration)."""

from __future__ import annotations

import functools
from importlib import resources

from eurocslam.dataset.calib import StereoRig, default_rig, rig_from_texts
from eurocslam.errors import DatasetError

RIGS = ("euroc", "realsense")


@functools.cache
def realsense_rig() -> StereoRig:
    base = resources.files("eurocslam") / "data" / "realsense_calib"
    texts = {s: (base / s / "sensor.yaml").read_text() for s in ("cam0", "cam1", "imu0")}
    return rig_from_texts(texts, "<built-in RealSense-like calibration>")


def builtin_rig(name: str) -> StereoRig:
    """A built-in rig by name (`RIGS`)."""
    if name == "euroc":
        return default_rig()
    if name == "realsense":
        return realsense_rig()
    raise DatasetError(f"--rig {name}: unknown rig (built in: {', '.join(RIGS)})")
