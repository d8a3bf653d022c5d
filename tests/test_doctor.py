"""The doctor on the two real folders: expected exit codes and findings, report formats."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from eurocslam.dataset.doctor.asl_checks import diagnose
from eurocslam.dataset.doctor.bag_checks import diagnose_bag
from eurocslam.dataset.doctor.image_checks import read_png_header
from eurocslam.dataset.doctor.report import ERROR, INFO, WARNING, DoctorReport


@pytest.fixture(scope="module")
def v101_report(v101_micro: Path) -> DoctorReport:
    return diagnose(v101_micro)


def _find(r: DoctorReport, severity: str, text: str) -> list:
    return [f for f in r.findings if f.severity == severity and text in f.message]


def test_v101_micro(v101_report: DoctorReport) -> None:
    r = v101_report
    assert r.exit_code == 1, r.format_text()
    assert r.errors == 0
    # the two real problems of this folder, and nothing else
    (missing,) = _find(r, WARNING, "4 of 99 listed image(s) missing")
    assert missing.file == "mav0/cam1/data.csv" and missing.line == 97
    assert "1403715278012143104.png" in missing.message
    (only,) = _find(r, WARNING, "4 timestamp(s) in cam1 only")
    assert only.file == "mav0/cam1/data.csv"
    assert r.warnings == 2 and r.count(INFO) == 0, r.format_text()
    assert r.stereo_pairs == 95
    assert r.image_headers_read == 190
    assert r.images_decoded == 48  # 24 per camera by default
    streams = {s.name: s for s in r.streams}
    assert streams["imu0"].rows == 29_120
    assert streams["imu0"].rate_hz == pytest.approx(200.0, rel=1e-3)
    assert streams["imu0"].rate_hz_yaml == 200
    assert streams["cam0"].rows == 95 and streams["cam1"].rows == 99
    assert streams["groundtruth"].rows == 2895
    assert "leica0" not in streams


def test_mh01_first5(mh01_first5: Path) -> None:
    r = diagnose(mh01_first5 / "mav0", full=True)
    assert r.exit_code == 1, r.format_text()
    assert r.errors == 0
    (imu,) = _find(r, WARNING, "IMU ends 0.185 s before the last stereo frame")
    assert imu.file == "mav0/imu0/data.csv" and "covers 7%" in imu.message
    (gt,) = _find(r, WARNING, "ground truth")
    assert "does not overlap" in gt.message and "evaluation" in gt.message
    (leica,) = _find(r, INFO, "leica0")
    assert leica.file == "mav0/leica0/data.csv"
    assert r.warnings == 2
    assert r.stereo_pairs == 5 and r.images_decoded == 10  # --full decodes all
    assert {s.name for s in r.streams} == {"cam0", "cam1", "imu0", "groundtruth", "leica0"}


def test_report_text_and_json(v101_report: DoctorReport) -> None:
    text = v101_report.format_text().splitlines()
    assert text[0].startswith("eurocslam doctor: ")
    assert text[-1].startswith("summary: 0 error(s), 2 warning(s), 0 note(s)")
    assert text[-1].endswith("-> exit 1 (warnings)")
    finding_lines = [ln for ln in text if ln.startswith(("ERROR", "WARNING", "INFO"))]
    assert finding_lines == [f.text() for f in v101_report.findings]
    assert all("mav0/cam1/data.csv:97" in ln for ln in finding_lines)
    d = json.loads(json.dumps(v101_report.to_dict()))
    assert d["exit_code"] == 1
    assert d["summary"]["warnings"] == 2 and d["summary"]["stereo_pairs"] == 95
    assert {f["severity"] for f in d["findings"]} == {WARNING}
    assert d["findings"][0]["file"] == "mav0/cam1/data.csv"
    assert [s["name"] for s in d["streams"]] == ["cam0", "cam1", "imu0", "groundtruth"]


def test_sample_size_and_progress(mh01_first5: Path) -> None:
    calls: list[str] = []
    r = diagnose(mh01_first5, sample=2, progress=lambda n, cam: calls.append(cam))
    assert r.images_decoded == 4 and calls == ["cam0", "cam0", "cam1", "cam1"]
    assert diagnose(mh01_first5, sample=0).images_decoded == 0


def test_png_header_of_real_image(v101_micro: Path) -> None:
    p = next((v101_micro / "mav0" / "cam0" / "data").iterdir())
    h = read_png_header(p)
    assert (h.width, h.height, h.bit_depth, h.colour_type, h.problem) == (752, 480, 8, 0, None)


def test_missing_path_is_an_error_finding(tmp_path: Path) -> None:
    r = diagnose(tmp_path / "absent")
    assert r.exit_code == 2
    assert r.findings[0].severity == ERROR and "no such file or folder" in r.findings[0].message
    assert r.streams == ()


def test_doctor_on_a_bag(mh01_first5: Path, tmp_path: Path) -> None:
    from eurocslam.dataset.asl import AslSequence
    from eurocslam.dataset.bag.writer import write_rosbag

    bag = write_rosbag(AslSequence(mh01_first5), tmp_path / "mh.bag", "ros1")
    r = diagnose_bag(bag)
    # the same two overlap problems as the folder, found on the bag
    assert r.exit_code == 1, r.format_text()
    assert any("IMU covers the cameras only partly" in f.message for f in r.findings)
    assert all(f.file == "mh.bag" for f in r.findings)
    broken = tmp_path / "broken.bag"
    broken.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 100)
    assert diagnose_bag(broken).exit_code == 2
