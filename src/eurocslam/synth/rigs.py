"""The RealSense-like rig `eurocslam synth --rig realsense` renders with, shipped in the package
(`data/realsense_calib/`): an 848x480 infrared pair at 30 Hz with a ~5 cm baseline, slight
distortion and misalignment, and a 400 Hz IMU (BMI055 datasheet noise); not a real device's
calibration. (EuRoC's rig is `dataset.calib.default_rig`, TUM-VI's
`dataset.calib_sources.tumvi_rig`.)"""

from __future__ import annotations

import functools
from importlib import resources

from eurocslam.dataset.calib import StereoRig, rig_from_texts


@functools.cache
def realsense_rig() -> StereoRig:
    base = resources.files("eurocslam") / "data" / "realsense_calib"
    texts = {s: (base / s / "sensor.yaml").read_text() for s in ("cam0", "cam1", "imu0")}
    return rig_from_texts(texts, "<built-in RealSense-like calibration>")
