"""Opening any input sequence: an EuRoC ASL folder, a KITTI odometry sequence or a ROS bag / MCAP,
by what the path is."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

from eurocslam.dataset.asl import AslSequence
from eurocslam.dataset.bag.files import is_bag_path
from eurocslam.dataset.bag.reader import BagSequence
from eurocslam.dataset.bag.topics import TopicMap
from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.imu_noise import NoiseFigures, with_imu_noise
from eurocslam.dataset.kitti import KittiSequence
from eurocslam.dataset.kitti_files import is_kitti_root, is_kitti_sequence
from eurocslam.errors import DatasetError

logger = logging.getLogger(__name__)


def open_sequence(
    path: Path | str,
    rig: StereoRig | None = None,
    *,
    calib: Path | str | None = None,
    topics: TopicMap | Mapping[str, str] | None = None,
    imu_noise: NoiseFigures | None = None,
    quiet: bool = False,
) -> AslSequence | BagSequence | KittiSequence:
    """Open an input sequence: an EuRoC ASL folder (or its `mav0/`), a KITTI odometry sequence
    folder (`sequences/NN`), a ROS 1 `.bag`, a ROS 2 bag folder (`metadata.yaml`), a `.db3` or an
    `.mcap` (including `eurocslam convert` output).

    `rig` wins over `calib` (a folder of cam0/cam1/imu0 `sensor.yaml` files; for an ASL folder
    also a Kalibr camchain.yaml or a folder holding one); `topics` maps bag topics to roles
    (`{"cam0": "/my/left"}`, bags only). `imu_noise`: IMU noise figures that replace the
    calibration's (`--imu-calib`, the config's `imu:`; a bag calibrated by its CameraInfo takes
    the packaged defaults where none are given). Notes (calibration source and fallbacks, stamp
    source) are logged (INFO) unless `quiet`; they stay in the source's `notes`.
    """
    p = Path(path)
    if is_bag_path(p):
        seq = BagSequence(p, rig, calib=calib, topics=topics, imu_noise=imu_noise)
        if not quiet:
            for note in seq.notes:
                logger.info("note: %s", note)
        return seq
    if topics:
        raise DatasetError(f"{p}: --topic applies to ROS bags and MCAP inputs, not folders")
    if p.is_file():
        raise DatasetError(
            f"{p}: not a recognised input (expected an EuRoC ASL folder, a KITTI sequence "
            "folder, a .bag, .db3 or .mcap file, or a ROS 2 bag folder)"
        )
    if is_kitti_sequence(p) or is_kitti_root(p):
        if rig is not None or calib is not None:
            raise DatasetError(f"{p}: a KITTI sequence carries its calibration (calib.txt)")
        return KittiSequence(p)
    asl = AslSequence(path, rig, calib=calib)
    if imu_noise is not None and not imu_noise.empty and asl.rig.imu is not None:
        asl.rig = with_imu_noise(asl.rig, imu_noise, imu_noise.source)
        asl.notes.append(f"IMU noise figures from {imu_noise.source}")
    if not quiet:
        for note in asl.notes:
            logger.info("note: %s", note)
    return asl
