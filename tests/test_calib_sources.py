"""Calibration sources: TUM-VI's folder as distributed (dso/camchain.yaml, dso/imu_config.yaml,
mav0/mocap0), a Kalibr camchain (+ imu.yaml) beside an ASL folder or named by --calib FILE|DIR,
a camera-only camchain, the default IMU noise with its note, and every bad calibration giving a
one-line error that names the file and the key (reader, doctor, CLI)."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from eurocslam.dataset import open_sequence
from eurocslam.dataset.asl import AslSequence
from eurocslam.dataset.calib_sources import (
    KALIBR,
    SENSOR_YAML,
    load_calibration,
    sources_in,
    tumvi_rig,
)
from eurocslam.dataset.doctor.asl_checks import diagnose
from eurocslam.dataset.rig import CameraCalib, ImuCalib
from eurocslam.errors import CalibrationError
from eurocslam.eval.loaders import load_groundtruth
from eurocslam.geometry import inv_T

T0 = 1_520_530_308_199_447_626  # a TUM-VI-like first timestamp [ns]
CALIB = resources.files("eurocslam") / "data" / "tumvi_calib"


def _same_camera(a: CameraCalib, b: CameraCalib) -> bool:
    return dataclasses.replace(a, T_body_cam=b.T_body_cam) == b and np.array_equal(
        a.T_body_cam, b.T_body_cam
    )


def _same_imu(a: ImuCalib | None, b: ImuCalib | None) -> bool:
    assert a is not None and b is not None
    return dataclasses.replace(a, T_body_imu=b.T_body_imu) == b and np.array_equal(
        a.T_body_imu, b.T_body_imu
    )


def _chain() -> dict:
    return yaml.safe_load((CALIB / "camchain.yaml").read_text())


def _write_yaml(path: Path, data: dict) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def make_tumvi_folder(root: Path, frames: int = 6, size: int = 512) -> Path:
    """A TUM-VI folder as distributed, small: dso/ calibration, 20 Hz images, 200 Hz IMU (at
    rest), mocap0 ground truth (8 columns). Returns `root`."""
    rng = np.random.default_rng(0)
    t_cam = T0 + 50_000_000 * np.arange(frames, dtype=np.int64)
    for cam in ("cam0", "cam1"):
        (root / "mav0" / cam / "data").mkdir(parents=True)
        rows = ["#timestamp [ns],filename"]
        for t in t_cam:
            img = rng.integers(0, 255, (size, size), dtype=np.uint8)
            cv2.imwrite(str(root / "mav0" / cam / "data" / f"{t}.png"), img)
            rows.append(f"{t},{t}.png")
        (root / "mav0" / cam / "data.csv").write_text("\n".join(rows) + "\n")
    t_imu = T0 - 100_000_000 + 5_000_000 * np.arange(frames * 10 + 40, dtype=np.int64)
    (root / "mav0" / "imu0").mkdir(parents=True)
    imu = [
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
        "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
    ]
    imu += [f"{t},0.001,-0.002,0.0005,0.1,9.79,0.2" for t in t_imu]
    (root / "mav0" / "imu0" / "data.csv").write_text("\n".join(imu) + "\n")
    (root / "mav0" / "mocap0").mkdir(parents=True)
    gt = [
        "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],"
        "q_RS_z []"
    ]
    gt += [f"{t},0.5,1.0,1.2,0.7071068,0.0,0.7071068,0.0" for t in t_imu[::2]]
    (root / "mav0" / "mocap0" / "data.csv").write_text("\n".join(gt) + "\n")
    (root / "dso").mkdir()
    shutil.copy(CALIB / "camchain.yaml", root / "dso" / "camchain.yaml")
    shutil.copy(CALIB / "imu_config.yaml", root / "dso" / "imu_config.yaml")
    return root


@pytest.fixture
def tumvi(tmp_path: Path) -> Path:
    return make_tumvi_folder(tmp_path / "dataset-room1_512_16")


# ---- TUM-VI as distributed -----------------------------------------------------------------


def test_tumvi_folder_opens_with_no_flags(tumvi: Path) -> None:
    seq = open_sequence(tumvi, quiet=True)
    assert isinstance(seq, AslSequence)
    rig = seq.rig
    assert rig.cam0.distortion_model == rig.cam1.distortion_model == "equidistant"
    assert rig.cam0.resolution == (512, 512) and rig.cam0.fx == 190.97847715128717
    assert rig.cam0.rate_hz == 20.0 and rig.imu is not None and rig.imu.rate_hz == 200.0
    assert rig.imu.accel_noise_density == 0.0028 and rig.imu.gyro_random_walk == 0.000022
    # T_body_cam = T_cam_imu^-1 (body = IMU)
    T_cam0_imu = np.array(_chain()["cam0"]["T_cam_imu"], dtype=float)
    np.testing.assert_allclose(rig.cam0.T_body_cam, inv_T(T_cam0_imu), atol=1e-15)
    assert rig.baseline == pytest.approx(0.1011, abs=1e-4)
    assert any("dso/camchain.yaml" in n for n in seq.notes)
    # the ground truth is mocap0's 8 columns: poses, no velocity or biases
    assert seq.groundtruth is not None and seq.groundtruth.v is None
    assert len(seq.groundtruth) == 50 and seq.groundtruth_path == tumvi / "mav0/mocap0/data.csv"
    assert len(list(seq.frames())) == 6
    # sensor.yaml texts for MCAP attachments and ASL copies read back to the same rig
    from eurocslam.dataset.calib import rig_from_texts

    back = rig_from_texts(dict(rig.yaml_texts), "attachments")
    assert _same_camera(back.cam0, rig.cam0) and _same_camera(back.cam1, rig.cam1)
    assert _same_imu(back.imu, rig.imu)
    assert _same_camera(tumvi_rig().cam1, rig.cam1)  # the packaged TUM-VI calibration


def test_eval_finds_mocap0(tumvi: Path) -> None:
    gt = load_groundtruth(tumvi)
    assert gt.source.endswith("mav0/mocap0/data.csv") and len(gt.traj.t_ns) == 50


def test_doctor_on_a_tumvi_folder(tumvi: Path) -> None:
    report = diagnose(tumvi)
    errors = [f for f in report.findings if f.severity == "error"]
    assert errors == [], errors
    msgs = [f.message for f in report.findings]
    assert any("the reader uses Kalibr" in m and "dso/camchain.yaml" in m for m in msgs)
    assert not any("file missing" in m for m in msgs)  # no sensor.yaml is expected here


# ---- Kalibr beside an ASL folder, --calib FILE|DIR -------------------------------------------


def _kalibr_beside(tumvi: Path, chain: dict, imu: bool = True) -> Path:
    """The TUM-VI folder with its calibration as Kalibr writes it beside the sequence."""
    shutil.rmtree(tumvi / "dso")
    _write_yaml(tumvi / "camchain-imucam-room1.yaml", chain)
    if imu:
        kalibr_imu = {
            "imu0": {
                **yaml.safe_load((CALIB / "imu_config.yaml").read_text()),
                "T_i_b": np.eye(4).tolist(),
            }
        }
        _write_yaml(tumvi / "imu-room1.yaml", kalibr_imu)
    return tumvi


def test_kalibr_camchain_beside_an_asl_folder(tumvi: Path) -> None:
    _kalibr_beside(tumvi, _chain())
    [src] = sources_in(tumvi / "mav0")
    assert src.kind == KALIBR and src.imu_path == tumvi / "imu-room1.yaml"
    seq = AslSequence(tumvi)
    assert _same_camera(seq.rig.cam0, tumvi_rig().cam0) and _same_imu(seq.rig.imu, tumvi_rig().imu)


def test_calib_file_and_dir_override_the_folders_own(tumvi: Path, tmp_path: Path) -> None:
    """--calib FILE (a camchain) and --calib DIR (a folder holding one) beat dso/."""
    chain = _chain()
    chain["cam0"]["intrinsics"][0] = 191.5
    f = _write_yaml(tmp_path / "mine" / "camchain.yaml", chain)
    shutil.copy(CALIB / "imu_config.yaml", tmp_path / "mine" / "imu.yaml")
    for calib in (f, f.parent):
        seq = open_sequence(tumvi, calib=calib, quiet=True)
        assert seq.rig.cam0.fx == 191.5 and seq.rig.imu is not None
        assert any(str(f) in n for n in seq.notes)  # type: ignore[union-attr]
    assert load_calibration(f, tumvi / "mav0").source.imu_path == tmp_path / "mine" / "imu.yaml"


def test_camchain_without_imu_yaml_uses_the_default_noise(tumvi: Path) -> None:
    _kalibr_beside(tumvi, _chain(), imu=False)
    seq = AslSequence(tumvi)
    assert seq.rig.imu is not None and seq.rig.imu.rate_hz == 200.0  # measured from imu0
    assert seq.rig.imu.accel_noise_density == 2.8e-3  # imu_noise_defaults.yaml
    assert any("imu_noise_defaults.yaml are used" in n for n in seq.notes)
    report = diagnose(tumvi)
    assert any("no imu.yaml beside it" in f.message for f in report.findings)


def test_camera_only_camchain_is_visual_only(tumvi: Path) -> None:
    chain = _chain()
    T_c1_c0 = np.array(chain["cam1"]["T_cam_imu"]) @ inv_T(np.array(chain["cam0"]["T_cam_imu"]))
    for cam in ("cam0", "cam1"):
        del chain[cam]["T_cam_imu"]
    chain["cam1"]["T_cn_cnm1"] = T_c1_c0.tolist()
    _kalibr_beside(tumvi, chain, imu=False)
    seq = AslSequence(tumvi)
    assert seq.rig.imu is None
    np.testing.assert_array_equal(seq.rig.cam0.T_body_cam, np.eye(4))  # body = cam0
    np.testing.assert_allclose(seq.rig.T_cam1_cam0, T_c1_c0, atol=1e-12)
    assert any("camera-only calibration" in n for n in seq.notes)


def test_doctor_flags_disagreeing_placements(tumvi: Path) -> None:
    chain = _chain()
    T = np.array(chain["cam1"]["T_cam_imu"]) @ inv_T(np.array(chain["cam0"]["T_cam_imu"]))
    T[0, 3] += 0.01  # 1 cm off
    chain["cam1"]["T_cn_cnm1"] = T.tolist()
    _write_yaml(tumvi / "dso" / "camchain.yaml", chain)
    report = diagnose(tumvi)
    [f] = [f for f in report.findings if f.key == "cam1.T_cn_cnm1"]
    assert f.severity == "warning" and "10.0 mm" in f.message


# ---- bad calibrations: one line naming the file and the key --------------------------------


def _five_coefficients(c: dict) -> None:
    c["cam0"]["distortion_coeffs"] = [0.0035, 0.0007, -0.002, 0.0002, 0.0]


def _unknown_model(c: dict) -> None:
    c["cam1"]["distortion_model"] = "fov"


def _non_rigid(c: dict) -> None:
    c["cam0"]["T_cam_imu"][0][0] = -0.5  # a rotation that is not orthonormal


def _wrong_size(c: dict) -> None:
    c["cam1"]["resolution"] = [1024, 1024]


def _omni(c: dict) -> None:
    c["cam0"]["camera_model"] = "omni"


def _no_intrinsics(c: dict) -> None:
    del c["cam1"]["intrinsics"]


BAD = {
    "equidistant with five coefficients": (
        _five_coefficients,
        "key 'cam0.distortion_coeffs' must have 4 values for distortion model 'equidistant', has 5",
    ),
    "unknown distortion model": (
        _unknown_model,
        "key 'cam1.distortion_model': distortion model 'fov' not supported",
    ),
    "non-rigid T_cam_imu": (_non_rigid, "key 'cam0.T_cam_imu': rotation is not orthonormal"),
    "cameras disagree with the images' size": (
        _wrong_size,
        "key 'cam1.resolution' is [1024, 1024] but the cam1 images are 512x512",
    ),
    "omni camera": (_omni, "key 'cam0.camera_model': 'omni' not supported"),
    "missing intrinsics": (_no_intrinsics, "missing key 'intrinsics'"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_calibration_names_file_and_key(tumvi: Path, case: str) -> None:
    edit, needle = BAD[case]
    chain = _chain()
    edit(chain)
    path = _write_yaml(tumvi / "dso" / "camchain.yaml", chain)
    with pytest.raises(CalibrationError) as e:
        AslSequence(tumvi)
    msg = str(e.value)
    assert needle in msg and str(path) in msg and "\n" not in msg, msg
    # the doctor reports it as an error (and still runs its other checks)
    report = diagnose(tumvi)
    assert report.exit_code == 2
    assert any(needle.split(":")[0].strip("key '") in (f.key or f.message) for f in report.findings)


def test_imu_yaml_missing_key_names_it(tumvi: Path) -> None:
    data = yaml.safe_load((tumvi / "dso" / "imu_config.yaml").read_text())
    del data["gyroscope_random_walk"]
    path = _write_yaml(tumvi / "dso" / "imu_config.yaml", data)
    with pytest.raises(CalibrationError, match=f"{path}: missing key 'gyroscope_random_walk'"):
        AslSequence(tumvi)


def test_calib_flag_errors(tumvi: Path, tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="calibration file or folder not found"):
        AslSequence(tumvi, calib=tmp_path / "nope.yaml")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CalibrationError, match="no calibration in this folder"):
        AslSequence(tumvi, calib=tmp_path / "empty")


def test_sources_in_order(tumvi: Path, v101_micro: Path) -> None:
    # EuRoC's sensor.yaml first, TUM-VI's dso/ next, a Kalibr camchain beside last
    for cam in ("cam0", "cam1", "imu0"):
        shutil.copy(v101_micro / "mav0" / cam / "sensor.yaml", tumvi / "mav0" / cam)
    _write_yaml(tumvi / "camchain.yaml", _chain())
    kinds = [(s.kind, s.path.name) for s in sources_in(tumvi / "mav0")]
    assert kinds == [(SENSOR_YAML, "mav0"), (KALIBR, "camchain.yaml"), (KALIBR, "camchain.yaml")]
    assert [s.path.parent.name for s in sources_in(tumvi / "mav0")][1] == "dso"


def test_cli_doctor_and_run_take_calib(tumvi: Path, tmp_path: Path) -> None:
    """`doctor --calib FILE` on an ASL folder, a bad camchain's one-line CLI error."""
    exe = [sys.executable, "-c", "import sys; from eurocslam.cli import main; sys.exit(main())"]
    f = _write_yaml(tmp_path / "c" / "camchain.yaml", _chain())
    shutil.copy(CALIB / "imu_config.yaml", tmp_path / "c" / "imu.yaml")
    r = subprocess.run(
        [*exe, "doctor", str(tumvi), "--calib", str(f)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode in (0, 1), r.stdout + r.stderr
    assert "camchain.yaml" in r.stdout
    chain = _chain()
    _five_coefficients(chain)
    _write_yaml(tumvi / "dso" / "camchain.yaml", chain)
    r = subprocess.run(
        [*exe, "run", str(tumvi), "-o", str(tmp_path / "out"), "--no-progress"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "cam0.distortion_coeffs" in lines[0], r.stderr
