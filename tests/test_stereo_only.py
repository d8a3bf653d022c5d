"""Stereo-only ASL folders (no `imu0/`): the reader, doctor, convert, and `run`, which goes
visual-only by itself. The sequence is a short rendered one with its imu0/ removed."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from eurocslam.cli import main
from eurocslam.config import RunConfig
from eurocslam.dataset import AslSequence, has_imu, load_rig, open_sequence
from eurocslam.dataset.doctor.asl_checks import diagnose
from eurocslam.errors import CalibrationError, ConfigError, DatasetError
from eurocslam.io.layout import translate_to_studio_148
from eurocslam.pipeline.slam import SlamPipeline


@pytest.fixture(scope="module")
def stereo_only(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from eurocslam.synth import SynthSpec, synthesize

    seq = synthesize(SynthSpec(duration_s=1.5, seed=4), tmp_path_factory.mktemp("so") / "seq")
    shutil.rmtree(seq / "mav0" / "imu0")
    return seq


def test_reader_has_no_imu(stereo_only: Path) -> None:
    s = open_sequence(stereo_only)
    assert isinstance(s, AslSequence)
    assert s.rig.imu is None and len(s.imu) == 0 and not has_imu(s)
    assert len(s.frame_times) == 31 and s.groundtruth is not None
    assert load_rig(stereo_only).imu is None
    assert "imu0" not in s.sensor_yaml_paths()


def test_an_imu0_folder_must_still_be_complete(stereo_only: Path, tmp_path: Path) -> None:
    seq = tmp_path / "seq"
    shutil.copytree(stereo_only, seq)
    (seq / "mav0" / "imu0").mkdir()
    with pytest.raises(CalibrationError, match=r"imu0/sensor\.yaml: file not found"):
        AslSequence(seq)
    (seq / "mav0" / "imu0" / "sensor.yaml").write_text(
        (Path(__file__).parents[1] / "src/eurocslam/data/euroc_calib/imu0/sensor.yaml").read_text()
    )
    with pytest.raises(DatasetError, match=r"imu0/data\.csv: file not found"):
        AslSequence(seq)


def test_doctor_notes_the_missing_imu(
    stereo_only: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    r = diagnose(stereo_only)
    notes = [f for f in r.findings if f.check == "files"]
    assert [(f.severity, f.file) for f in notes] == [("info", "mav0/imu0")]
    assert "stereo-only" in notes[0].message and r.errors == 0
    assert r.stereo_pairs == 31 and "imu0" not in [s.name for s in r.streams]
    assert main(["doctor", str(stereo_only)]) == r.exit_code


def test_convert_writes_no_imu(stereo_only: Path, tmp_path: Path) -> None:
    out = tmp_path / "so.mcap"
    assert main(["convert", str(stereo_only), "-o", str(out), "--no-progress"]) == 0
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        topics = {c.topic for c in reader.get_summary().channels.values()}
        static = next(m for _, c, _, m in reader.iter_decoded_messages(topics=["/tf_static"]))
        atts = {a.name for a in reader.iter_attachments()}
    assert "/imu0" not in topics
    assert {"/cam0/image_raw", "/cam1/camera_info", "/groundtruth/pose"} <= topics
    assert {t.child_frame_id for t in static.transforms} == {"cam0", "cam1"}
    assert "imu0/sensor.yaml" not in atts and "cam0/sensor.yaml" in atts
    # asking for the IMU topic of a sequence without one is an error naming it
    assert (
        main(["convert", str(stereo_only), "-o", str(tmp_path / "x.mcap"), "--topics", "/imu0"])
        == 2
    )
    # and the MCAP is a stereo-only input again
    back = open_sequence(out)
    assert back.rig.imu is None and len(back.imu) == 0 and not has_imu(back)


def test_run_goes_visual_only_by_itself(
    stereo_only: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog
) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "out"
    assert main(["run", str(stereo_only), "-o", str(out), "--no-progress"]) == 0
    cap = capsys.readouterr()
    assert "has no IMU data: running visual-only" in cap.err + caplog.text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "visual-only"
    assert summary["frames_with_pose"] == summary["frames"] == 31
    assert (out / "trajectory_final.tum").is_file()
    with open(out / "run.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert "/imu0" not in topics and "/slam/pose" in topics
    # nothing estimates IMU biases or a velocity without an IMU: no topics of zeros
    assert not {"/slam/imu_bias", "/slam/velocity"} & topics
    # the run's own layout: no IMU panels, the 3D panel on the run, a copy for Foxglove 1.48
    layout = json.loads((out / "layout.json").read_text())
    assert "Plot!gyro" not in layout["configById"] and "Plot!position" in layout["configById"]
    assert json.loads((out / "layout-1.48.json").read_text()) == translate_to_studio_148(layout)
    cam = layout["configById"]["3D!map"]["cameraState"]
    p = np.loadtxt(out / "trajectory_final.tum")[:, 1:4]
    assert np.all(p.min(axis=0) - 1e-3 <= cam["targetOffset"])
    assert np.all(cam["targetOffset"] <= p.max(axis=0) + 1e-3)
    assert f"Layouts > Import from file > {out / 'layout.json'}" in cap.out
    with open(out / "run.mcap", "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    first = int(meta["eurocslam"]["first_stamp_ns"])
    assert meta["eurocslam"]["time_base"] == ("relative" if first < 6e17 else "unix")


def test_stereo_inertial_asked_for_without_an_imu_is_an_error(stereo_only: Path) -> None:
    import dataclasses

    cfg = dataclasses.replace(RunConfig(), mode="stereo-inertial")
    with pytest.raises(ConfigError, match="no IMU data for mode stereo-inertial"):
        SlamPipeline(open_sequence(stereo_only), cfg)
