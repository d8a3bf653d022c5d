"""The issue's bad-calibration cases through the command line, in every source they apply to:
`doctor` reports an error (exit 2) and `run` stops with one line naming the topic or file
(exit 2), before writing anything.

Cases (sources): K all zeros (a bag's CameraInfo in each storage, EuRoC sensor.yaml
`intrinsics`, TUM-VI camchain `cam0.intrinsics`); a tf tree not reaching the IMU (/tf_static);
an equidistant model with five coefficients (CameraInfo D, sensor.yaml, camchain); cameras that
disagree with the images' size (CameraInfo width/height, sensor.yaml `resolution`, camchain
`cam1.resolution`, a Kalibr camchain given with --calib).
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from eurocslam.cli import main
from robot_bag_helpers import pinhole_info, realsense_tree, write_robot_bag
from test_calib_sources import make_tumvi_folder

GOOD = (pinhole_info(), pinhole_info(tx=-2.5))
EQUI5 = {"distortion_model": "equidistant", "d": [0.01, 0.001, 0.0, 0.0, 0.0]}
RAW_TOPICS = ("/camera/infra1/image_raw", "/camera/infra2/image_raw")

BAG_CASES: dict[str, tuple[Any, Any, dict[str, Any], str]] = {
    "K all zeros": (
        (pinhole_info(k=np.zeros(9)), GOOD[1]), realsense_tree(), {},
        "/camera/infra1/camera_info: CameraInfo K is all zeros",
    ),
    "tf tree not reaching the IMU": (
        GOOD, [e for e in realsense_tree() if e[1] != "camera_gyro_frame"], {},
        "/tf_static: no transform chain from 'camera_imu_optical_frame' to "
        "'camera_infra1_optical_frame' (body = IMU frame to cam0): the frames are in two "
        "unconnected trees",
    ),
    "equidistant with five coefficients": (
        (pinhole_info(**EQUI5), pinhole_info(tx=-2.5, **EQUI5)), realsense_tree(),
        {"topics": RAW_TOPICS},
        "/camera/infra1/camera_info: distortion model 'equidistant' needs 4 coefficients, has 5",
    ),
    "cameras disagree with the images' size": (
        (pinhole_info(width=640, height=480), GOOD[1]), realsense_tree(), {},
        "/camera/infra1/camera_info: CameraInfo says 640x480 but the images on "
        "/camera/infra1/image_rect_raw are 64x48",
    ),
}  # fmt: skip


def _cli_error(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one line a failing command prints (exit 2)."""
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def _check(target: Path, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
           extra: tuple[str, ...] = ()) -> None:  # fmt: skip
    out = tmp_path / "out"
    err = _cli_error(["run", str(target), "-o", str(out), "--no-progress", *extra], capsys)
    assert err.startswith("eurocslam run: error: ") and message in err, err
    assert not out.exists()  # stopped before touching OUT
    assert main(["doctor", str(target), *extra]) == 2
    errors = [ln for ln in capsys.readouterr().out.splitlines() if ln.lstrip().startswith("ERROR")]
    assert any(message in ln for ln in errors), errors


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
@pytest.mark.parametrize("case", sorted(BAG_CASES))
def test_bad_calibration_in_a_bag(
    case: str, storage: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    infos, tree, kw, message = BAG_CASES[case]
    bag = write_robot_bag(tmp_path / "bag", infos, tree, storage=storage, **kw)
    _check(bag, message, tmp_path, capsys)


def test_a_good_bag_in_each_storage_opens(tmp_path: Path) -> None:
    # the cases above fail for their calibration, not for the storage
    from eurocslam.dataset import open_sequence

    for storage in ("mcap", "sqlite3", "ros1"):
        bag = write_robot_bag(tmp_path / storage, GOOD, realsense_tree(), storage=storage)
        seq = open_sequence(bag, quiet=True)
        assert seq.rig.baseline == pytest.approx(0.05, abs=1e-12), storage


# ---- calibration files -------------------------------------------------------------------------


def _edit_sensor_yaml(path: Path, key: str, value: str) -> None:
    text = path.read_text()
    new, n = re.subn(rf"^{key}: .*$", f"{key}: {value}", text, flags=re.M)
    assert n == 1, key
    path.write_text(new)


SENSOR_CASES: dict[str, tuple[str, list[tuple[str, str]], str]] = {
    "K all zeros": (
        "cam0", [("intrinsics", "[0.0, 0.0, 0.0, 0.0]")],
        "mav0/cam0/sensor.yaml: key 'intrinsics': focal lengths must be positive, are 0, 0",
    ),
    "equidistant with five coefficients": (
        "cam0",
        [("distortion_model", "equidistant"),
         ("distortion_coefficients", "[0.01, 0.001, 0.0, 0.0, 0.0]")],
        "mav0/cam0/sensor.yaml: key 'distortion_coefficients' must have 4 values for distortion "
        "model 'equidistant', has 5",
    ),
    "cameras disagree with the images' size": (
        "cam1", [("resolution", "[640, 480]")],
        "mav0/cam1/sensor.yaml: key 'resolution' is [640, 480] but the cam1 images are 752x480",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(SENSOR_CASES))
def test_bad_calibration_in_sensor_yaml(
    case: str, v101_micro: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cam, edits, message = SENSOR_CASES[case]
    seq = tmp_path / "V1_01"
    shutil.copytree(v101_micro, seq)
    for key, value in edits:
        _edit_sensor_yaml(seq / "mav0" / cam / "sensor.yaml", key, value)
    _check(seq, message, tmp_path, capsys)


def _zero_k(c: dict[str, Any]) -> None:
    c["cam0"]["intrinsics"] = [0.0, 0.0, 0.0, 0.0]


def _five(c: dict[str, Any]) -> None:
    c["cam0"]["distortion_coeffs"] = [*c["cam0"]["distortion_coeffs"], 0.0]


def _size(c: dict[str, Any]) -> None:
    c["cam1"]["resolution"] = [1024, 1024]


CAMCHAIN_CASES: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    "K all zeros": (
        _zero_k, "dso/camchain.yaml: key 'cam0.intrinsics': focal lengths must be positive"
    ),
    "equidistant with five coefficients": (
        _five,
        "dso/camchain.yaml: key 'cam0.distortion_coeffs' must have 4 values for distortion model "
        "'equidistant', has 5",
    ),
    "cameras disagree with the images' size": (
        _size, "dso/camchain.yaml: key 'cam1.resolution' is [1024, 1024] but the cam1 images are "
        "512x512",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CAMCHAIN_CASES))
def test_bad_calibration_in_a_tumvi_camchain(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    edit, message = CAMCHAIN_CASES[case]
    seq = make_tumvi_folder(tmp_path / "dataset-room1_512_16")
    path = seq / "dso" / "camchain.yaml"
    chain = yaml.safe_load(path.read_text())
    edit(chain)
    path.write_text(yaml.safe_dump(chain, sort_keys=False))
    _check(seq, message, tmp_path, capsys)


def test_a_kalibr_camchain_given_with_calib_for_other_images(
    v101_micro: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # TUM-VI's 512x512 fisheye camchain given for EuRoC's 752x480 images
    tumvi = make_tumvi_folder(tmp_path / "tumvi", frames=2)
    calib = tmp_path / "calib" / "camchain.yaml"
    calib.parent.mkdir()
    shutil.copy(tumvi / "dso" / "camchain.yaml", calib)
    message = f"{calib}: key 'cam0.resolution' is [512, 512] but the cam0 images are 752x480"
    _check(v101_micro, message, tmp_path, capsys, ("--calib", str(calib)))


# ---- what a good rig's calibration becomes in the MCAP ----------------------------------------

RATIONAL = [0.5, 0.1, 0.001, 0.002, 0.01, 0.9, 0.2, 0.03]
EQUI4 = [0.01, 0.001, -0.002, 0.0002]


@pytest.mark.parametrize(
    ("model", "d"),
    [("plumb_bob", [-0.1, 0.01, 0.001, -0.002, 0.0005]), ("equidistant", EQUI4),
     ("rational_polynomial", RATIONAL)],
)  # fmt: skip
def test_the_mcap_carries_the_bags_camera_model_and_tf(
    model: str, d: list[float], tmp_path: Path
) -> None:
    """A robot bag's raw cameras (CameraInfo of each model, /tf_static) as `run.mcap` writes
    them (`convert` and `run` share the sensor streams): the same distortion model and
    coefficients, K, and /tf_static body (the IMU frame) -> cam0/cam1 of the rig."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from eurocslam.dataset import open_sequence
    from eurocslam.geometry import make_T, quat_wxyz_to_rot

    over = {"distortion_model": model, "d": d}
    infos = (pinhole_info(**over), pinhole_info(tx=-2.5, **over))
    bag = write_robot_bag(tmp_path / "bag", infos, realsense_tree(), topics=RAW_TOPICS)
    rig = open_sequence(bag, quiet=True).rig
    out = tmp_path / "out.mcap"
    assert main(["convert", str(bag), "-o", str(out), "--no-progress"]) == 0
    got: dict[str, Any] = {}
    with open(out, "rb") as f:
        for _s, ch, _m, msg in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages(topics=["/cam0/camera_info", "/cam1/camera_info", "/tf_static"]):
            if ch.topic == "/tf_static":
                for tr in msg.transforms:
                    q, p = tr.transform.rotation, tr.transform.translation
                    got[tr.child_frame_id] = make_T(
                        quat_wxyz_to_rot(np.array([q.w, q.x, q.y, q.z])), np.array([p.x, p.y, p.z])
                    )
            else:
                got.setdefault(ch.topic, msg)
    for cam, calib, k in (("cam0", rig.cam0, 0), ("cam1", rig.cam1, 1)):
        info = got[f"/{cam}/camera_info"]
        assert info.distortion_model == model
        np.testing.assert_allclose(info.d, d, atol=1e-12)
        np.testing.assert_allclose(np.reshape(info.k, (3, 3)), np.reshape(infos[k]["k"], (3, 3)))
        np.testing.assert_allclose(got[cam], calib.T_body_cam, atol=1e-9)
    assert rig.imu is not None
    np.testing.assert_allclose(got["imu0"], rig.imu.T_body_imu, atol=1e-9)
