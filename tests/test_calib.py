"""Calibration: real sensor.yaml files, the built-in EuRoC rig, `%YAML` quirks, clear errors
naming file and key, and the sanity checks the doctor and the loaders share."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from eurocslam.dataset.calib import (
    CameraCalib,
    camera_from_yaml,
    default_rig,
    load_rig,
    load_sensor_yaml,
    load_sensor_yaml_text,
)
from eurocslam.dataset.doctor.calib_checks import (
    check_camera,
    check_imu,
    check_stereo,
    check_stereo_pair,
    check_transform,
    radial_fold_radius,
)
from eurocslam.errors import CalibrationError
from eurocslam.geometry import make_T, so3_exp

CAM0_K = (458.654, 457.296, 367.215, 248.375)
CAM1_K = (457.587, 456.134, 379.999, 255.238)


def _k(c: CameraCalib) -> tuple[float, float, float, float]:
    return (c.fx, c.fy, c.cx, c.cy)


def test_default_rig_is_euroc() -> None:
    rig = default_rig()
    assert rig.baseline == pytest.approx(0.110, abs=1e-3)
    assert _k(rig.cam0) == CAM0_K
    assert _k(rig.cam1) == CAM1_K
    assert rig.cam0.resolution == rig.cam1.resolution == (752, 480)
    assert rig.cam0.rate_hz == 20 and rig.imu.rate_hz == 200
    assert rig.cam0.distortion == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    np.testing.assert_allclose(
        rig.cam0.K, [[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]]
    )
    assert rig.imu.gyro_noise_density == 1.6968e-04
    assert rig.imu.accel_noise_density == 2.0e-3
    # discrete variance is density^2 / dt (not * dt)
    assert rig.imu.discrete_gyro_variance() == pytest.approx(1.6968e-04**2 * 200)
    np.testing.assert_array_equal(rig.imu.T_body_imu, np.eye(4))
    # cam1 sits ~11 cm along cam0's +x (the right camera)
    t_cam1_cam0 = rig.T_cam1_cam0[:3, 3]
    assert t_cam1_cam0[0] == pytest.approx(-0.110, abs=1e-3)
    assert dict(rig.yaml_texts).keys() == {"cam0", "cam1", "imu0"}
    assert check_camera(rig.cam0) == check_camera(rig.cam1) == []
    assert check_imu(rig.imu) == [] and check_stereo(rig) == []


@pytest.mark.parametrize("which", ["v101_micro", "mh01_first5"])
def test_real_sensor_yaml_equals_builtin(which: str, request: pytest.FixtureRequest) -> None:
    folder: Path = request.getfixturevalue(which)
    rig = load_rig(folder / "mav0")
    ref = default_rig()
    for a, b in ((rig.cam0, ref.cam0), (rig.cam1, ref.cam1)):
        assert _k(a) == _k(b)
        np.testing.assert_array_equal(a.T_body_cam, b.T_body_cam)
        assert a.distortion == b.distortion
    assert rig.imu == dataclasses.replace(ref.imu, T_body_imu=rig.imu.T_body_imu)


def test_pyyaml_alone_rejects_the_euroc_directive(v101_micro: Path) -> None:
    text = (v101_micro / "mav0" / "cam0" / "sensor.yaml").read_text()
    assert text.startswith("%YAML:1.0")
    with pytest.raises(yaml.YAMLError):
        yaml.safe_load(text)
    assert load_sensor_yaml(v101_micro / "mav0" / "cam0" / "sensor.yaml")["rate_hz"] == 20


@pytest.mark.parametrize(
    "head",
    [
        "%YAML:1.0\n",
        "%YAML 1.2\n---\n",
        "%YAML:1.0\n---\n",
        "",
        "\ufeff%YAML:1.0\n",
        "  %YAML:1.0\n",
    ],
)
def test_yaml_directive_variants(head: str) -> None:
    body = "rate_hz: 20\nresolution: [752, 480]\n"
    data = load_sensor_yaml_text(head + body, "x/sensor.yaml")
    assert data == {"rate_hz": 20, "resolution": [752, 480]}
    crlf = load_sensor_yaml_text((head + body).replace("\n", "\r\n"), "x/sensor.yaml")
    assert crlf == data


def test_opencv_matrix_tag() -> None:
    text = (
        "%YAML:1.0\n---\nT_BS: !!opencv-matrix\n  rows: 4\n  cols: 4\n  dt: d\n"
        "  data: [1, 0, 0, 0.1, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n"
    )
    data = load_sensor_yaml_text(text, "s.yaml")
    assert data["T_BS"]["data"][3] == 0.1


def _cam_yaml(tmp_path: Path, v101_micro: Path, old: str, new: str) -> Path:
    mav0 = tmp_path / "mav0"
    for s in ("cam0", "cam1", "imu0"):
        (mav0 / s).mkdir(parents=True)
        shutil.copy(v101_micro / "mav0" / s / "sensor.yaml", mav0 / s / "sensor.yaml")
    p = mav0 / "cam0" / "sensor.yaml"
    text = p.read_text()
    assert old in text
    p.write_text(text.replace(old, new))
    return mav0


@pytest.mark.parametrize(
    "old,new,needle",
    [
        ("intrinsics:", "intrinsix:", "missing key 'intrinsics'"),
        ("rate_hz: 20", "rate_hz: fast", "key 'rate_hz' must be a list of numbers"),
        ("resolution: [752, 480]", "resolution: [752]", "key 'resolution' must have 2 values"),
        ("T_BS:", "T_XX:", "missing key 'T_BS'"),
        ("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 1.0]", "key 'T_BS.data' must have 16 values"),
        ("intrinsics: [458.654,", "intrinsics: [-458.654,", "key 'intrinsics'"),
        ("367.215", "9367.215", "principal point"),
        ("camera_model: pinhole", "camera_model: omni", "camera_model 'omni'"),
        ("rate_hz: 20", "rate_hz: [20", "not valid YAML"),
        (
            "distortion_model: radial-tangential",
            "distortion_model: double_sphere",
            "key 'distortion_model': distortion model 'double_sphere' not supported",
        ),
        (
            "distortion_model: radial-tangential\ndistortion_coefficients: [-0.28340811,",
            "distortion_model: equidistant\ndistortion_coefficients: [0.01, 0.0,",
            "key 'distortion_coefficients' must have 4 values for distortion model "
            "'equidistant', has 5",
        ),
    ],
)
def test_errors_name_file_and_key(
    tmp_path: Path, v101_micro: Path, old: str, new: str, needle: str
) -> None:
    mav0 = _cam_yaml(tmp_path, v101_micro, old, new)
    with pytest.raises(CalibrationError) as ei:
        load_rig(mav0)
    msg = str(ei.value)
    assert needle in msg
    assert str(mav0 / "cam0" / "sensor.yaml") in msg
    assert "\n" not in msg


def test_equidistant_sensor_yaml(tmp_path: Path, v101_micro: Path) -> None:
    """EuRoC's sensor.yaml with `distortion_model: equidistant` (a Kannala-Brandt fisheye)."""
    mav0 = _cam_yaml(
        tmp_path, v101_micro, "distortion_model: radial-tangential", "distortion_model: equidistant"
    )
    p = mav0 / "cam0" / "sensor.yaml"
    text = p.read_text()
    start = text.index("distortion_coefficients:")
    p.write_text(text[:start] + "distortion_coefficients: [0.0035, 0.0007, -0.0021, 0.0002]\n")
    rig = load_rig(mav0)
    assert (
        rig.cam0.distortion_model == "equidistant"
        and rig.cam1.distortion_model == "radial-tangential"
    )
    assert type(rig.cam0.model).__name__ == "PinholeEquidistant"
    assert rig.cam0.distortion == (0.0035, 0.0007, -0.0021, 0.0002)


def test_missing_sensor_yaml_names_it(tmp_path: Path, v101_micro: Path) -> None:
    mav0 = _cam_yaml(tmp_path, v101_micro, "rate_hz", "rate_hz")
    (mav0 / "imu0" / "sensor.yaml").unlink()
    with pytest.raises(CalibrationError, match=r"imu0/sensor\.yaml: file not found"):
        load_rig(mav0)


def test_validate_false_still_builds(tmp_path: Path, v101_micro: Path) -> None:
    mav0 = _cam_yaml(tmp_path, v101_micro, "intrinsics: [458.654,", "intrinsics: [-458.654,")
    p = mav0 / "cam0" / "sensor.yaml"
    cam = camera_from_yaml(load_sensor_yaml(p), "cam0", p, validate=False)
    issues = check_camera(cam)
    assert [(i.severity, i.key) for i in issues] == [("error", "intrinsics")]


# ---- sanity checks on modified real calibrations -----------------------------------------------


def _cam(**kw: object) -> CameraCalib:
    return dataclasses.replace(default_rig().cam0, **kw)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "kw,severity,text",
    [
        ({"fx": 0.0}, "error", "focal lengths must be positive"),
        ({"cx": -5.0}, "error", "outside"),
        ({"width": 0}, "error", "resolution"),
        ({"rate_hz": 0.0}, "error", "rate_hz"),
        ({"cx": 50.0}, "warning", "far from the image centre"),
        ({"fy": 300.0}, "warning", "far from square"),
        ({"fx": 20.0, "fy": 20.0}, "warning", "field of view"),
        ({"distortion": (-1.2, 0.0, 0.0, 0.0)}, "warning", "folds back"),
        ({"distortion": (-0.28, 0.07, 0.2, 0.0)}, "warning", "tangential"),
    ],
)
def test_check_camera(kw: dict[str, object], severity: str, text: str) -> None:
    issues = check_camera(_cam(**kw))
    assert any(i.severity == severity and text in (i.message + i.key) for i in issues), issues


def test_check_transform() -> None:
    assert check_transform(np.eye(4)) == []
    refl = np.diag([1.0, 1.0, -1.0, 1.0])
    assert "determinant" in check_transform(refl)[0].message
    sheared = np.eye(4)
    sheared[0, 1] = 0.2
    assert check_transform(sheared)[0].severity == "error"
    slightly = np.eye(4)
    slightly[0, 1] = 1e-3
    assert check_transform(slightly)[0].severity == "warning"
    bottom = np.eye(4)
    bottom[3, 0] = 1.0
    assert "bottom row" in check_transform(bottom)[0].message
    far = make_T(np.eye(3), np.array([110.0, 0.0, 0.0]))
    assert "mm instead of m" in check_transform(far)[0].message


def test_check_stereo() -> None:
    rig = default_rig()
    c0, c1 = rig.cam0, rig.cam1
    assert check_stereo_pair(c0, c1) == []
    assert "left of cam0" in check_stereo_pair(c1, c0)[0].message
    same = check_stereo_pair(c0, c0)
    assert same[0].severity == "error" and "same place" in same[0].message
    wide = dataclasses.replace(c1, T_body_cam=c1.T_body_cam.copy())
    wide.T_body_cam[:3, 3] += 2.0 * wide.T_body_cam[:3, 0]
    assert any("0.02-1 m" in i.message for i in check_stereo_pair(c0, wide))
    turned = dataclasses.replace(
        c1, T_body_cam=c1.T_body_cam @ make_T(so3_exp(np.array([0.0, 0.5, 0.0])), np.zeros(3))
    )
    assert any("not roughly parallel" in i.message for i in check_stereo_pair(c0, turned))
    small = dataclasses.replace(c1, width=640)
    assert any(i.key == "resolution" for i in check_stereo_pair(c0, small))


def test_check_imu() -> None:
    imu = default_rig().imu
    assert check_imu(dataclasses.replace(imu, gyro_noise_density=-1.0))[0].severity == "error"
    assert "zero" in check_imu(dataclasses.replace(imu, accel_noise_density=0.0))[0].message
    assert "plausible" in check_imu(dataclasses.replace(imu, accel_random_walk=30.0))[0].message


def test_radial_fold_radius() -> None:
    assert radial_fold_radius((-0.28340811, 0.07395907, 0.0, 0.0), 1.0) is None
    r = radial_fold_radius((-1.0, 0.0, 0.0, 0.0), 1.0)
    assert r is not None and r == pytest.approx(np.sqrt(1 / 3), abs=0.01)
