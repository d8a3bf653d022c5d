"""doctor, convert and eval on synthetic KITTI odometry folders made here; the rectified rig passed
through without remapping."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from eurocslam.camera import is_rectified, rectify_stereo
from eurocslam.cli import main
from eurocslam.convert import convert
from eurocslam.dataset import KittiSequence, default_rig, open_sequence
from eurocslam.dataset.doctor.kitti_checks import diagnose_kitti
from eurocslam.eval.synthetic import perturb, random_similarity
from eurocslam.frontend.stereo import StereoRectifier
from eurocslam.geometry import make_T, so3_exp
from eurocslam.trajectory import Trajectory
from eurocslam.trajectory_io import write_tum
from kitti_helpers import BASELINE, CX, CY, FX, make_kitti


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    return make_kitti(tmp_path / "kitti", n=8)


# ---- doctor ---------------------------------------------------------------------------------


def test_doctor_passes_a_clean_sequence(seq: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["doctor", str(seq)]) == 0
    out = capsys.readouterr().out
    assert "no IMU (KITTI): a stereo-only sequence, runs visual-only" in out
    assert "poses/00.txt: 8 poses" in out and out.rstrip().endswith("-> exit 0 (ok)")
    report = diagnose_kitti(seq)
    assert report.stereo_pairs == 8 and report.image_headers_read == 16
    assert report.images_decoded == 16
    assert [s.name for s in report.streams] == ["frames", "groundtruth"]


def test_doctor_findings_name_file_and_row(seq: Path) -> None:
    (seq / "image_1" / "000005.png").write_bytes(b"\x89PNG\r\n\x1a\n")  # truncated
    (seq.parent.parent / "poses" / "00.txt").unlink()
    (seq / "times.txt").write_text("".join(f"{0.1 * i:.6e}\n" for i in range(7)) + "1.5\n")
    r = diagnose_kitti(seq)
    by = {(f.severity, f.check): f for f in r.findings}
    img = by[("warning", "images")]
    assert img.file == "sequences/00/image_1" and "000005.png" in img.message
    assert "the reader skips them" in img.message
    gap = by[("warning", "timestamps")]
    assert gap.file == "sequences/00/times.txt" and gap.line == 8
    assert by[("info", "files")].file in ("poses/00.txt", None)
    assert r.exit_code == 1 and r.stereo_pairs == 7

    (seq / "calib.txt").write_text((seq / "calib.txt").read_text().replace("P1:", "Q1:"))
    (seq / "image_0" / "000003.png").unlink()
    r = diagnose_kitti(seq)
    errors = [f for f in r.findings if f.severity == "error"]
    calib = next(f for f in errors if f.check == "calibration")
    assert calib.file == "sequences/00/calib.txt" and "no 'P1:' row" in calib.message
    images = next(f for f in errors if f.check == "images")
    assert "000003.png (row 4)" in images.message and images.file == "sequences/00/image_0"
    assert any(f.check == "reader" for f in errors) and r.exit_code == 2


def test_doctor_names_a_bad_times_row(seq: Path) -> None:
    (seq / "times.txt").write_text("0.0\n0.1\n0.1\n")
    f = next(f for f in diagnose_kitti(seq).findings if f.check == "timestamps")
    assert (f.severity, f.file, f.line) == ("error", "sequences/00/times.txt", 3)
    assert "is not after the previous row's" in f.message


# ---- convert --------------------------------------------------------------------------------


def test_convert_writes_images_camera_info_tf_static_and_ground_truth(
    seq: Path, tmp_path: Path
) -> None:
    out = tmp_path / "k.mcap"
    convert(open_sequence(seq), out)
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        topics = {c.topic for c in reader.get_summary().channels.values()}
        msgs: dict[str, list[object]] = {}
        for _, ch, _, msg in reader.iter_decoded_messages():
            msgs.setdefault(ch.topic, []).append(msg)
        atts = {a.name for a in reader.iter_attachments()}
    assert topics == {
        "/tf_static",
        "/cam0/image_raw",
        "/cam1/image_raw",
        "/cam0/camera_info",
        "/cam1/camera_info",
        "/groundtruth/pose",
        "/groundtruth/path",
        "/tf",
    }  # no /imu0
    assert atts == {"cam0/sensor.yaml", "cam1/sensor.yaml"}
    assert len(msgs["/cam0/image_raw"]) == len(msgs["/groundtruth/pose"]) == 8
    (static,) = msgs["/tf_static"]
    frames = {t.child_frame_id: t.transform.translation for t in static.transforms}  # type: ignore[attr-defined]
    assert set(frames) == {"cam0", "cam1"} and frames["cam1"].x == pytest.approx(BASELINE)
    info = msgs["/cam1/camera_info"][0]
    assert list(info.p) == pytest.approx([FX, 0, CX, -FX * BASELINE, 0, FX, CY, 0, 0, 0, 1, 0])  # type: ignore[attr-defined]
    assert list(info.d) == [0.0] * 5 and list(info.r) == list(np.eye(3).ravel())  # type: ignore[attr-defined]
    # the MCAP reads back as an input: the same rig from its attachments, no IMU
    back = open_sequence(out)
    assert back.rig.imu is None and len(back.imu) == 0
    assert back.rig.baseline == KittiSequence(seq).rig.baseline
    assert back.frame_times.tolist() == KittiSequence(seq).frame_times.tolist()
    assert not [n for n in back.notes if "zero header stamp" in n]  # t = 0 is a real stamp


# ---- eval -----------------------------------------------------------------------------------


def _estimate(seq: Path, path: Path) -> Path:
    """The ground truth seen from another world frame, with 1 cm noise, as a TUM file."""
    gt = KittiSequence(seq).groundtruth
    assert gt is not None
    traj = Trajectory(gt.t_ns, gt.p, gt.q_wxyz)
    est = perturb(traj, random_similarity(3), noise_m=0.01, seed=1)
    write_tum(path, est)
    return path


@pytest.mark.parametrize("form", ["poses file", "sequence folder"])
def test_eval_against_kitti_poses(
    seq: Path, tmp_path: Path, form: str, capsys: pytest.CaptureFixture[str]
) -> None:
    est = _estimate(seq, tmp_path / "est.tum")
    ref = seq.parent.parent / "poses" / "00.txt" if form == "poses file" else seq
    assert main(["eval", str(est), str(ref), "--json", str(tmp_path / "r.json")]) == 0
    res = json.loads((tmp_path / "r.json").read_text())["results"][0]
    assert res["matched"] == 8 and res["ate_trans_m"]["rmse"] < 0.03
    err = capsys.readouterr().err
    assert "KITTI poses (T_world_cam0), stamped by" in err and "times.txt" in err


def test_eval_kitti_poses_without_times_names_both_paths(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    est = _estimate(seq, tmp_path / "est.tum")
    lone = tmp_path / "elsewhere" / "00.txt"
    lone.parent.mkdir()
    shutil.copy(seq.parent.parent / "poses" / "00.txt", lone)
    assert main(["eval", str(est), str(lone)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "carries no timestamps" in err[0]
    assert str(tmp_path / "sequences" / "00" / "times.txt") in err[0]
    assert str(tmp_path / "elsewhere" / "times.txt") in err[0]
    # a times.txt beside the poses file stamps them
    shutil.copy(seq / "times.txt", lone.parent / "times.txt")
    assert main(["eval", str(est), str(lone), "-q"]) == 0


def test_eval_kitti_sequence_without_poses(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    seq = make_kitti(tmp_path / "k", poses=False)
    est = tmp_path / "est.tum"
    est.write_text("0.0 0 0 0 0 0 0 1\n0.1 1 0 0 0 0 0 1\n")
    assert main(["eval", str(est), str(seq)]) == 2
    err = capsys.readouterr().err
    assert "no ground truth for this KITTI sequence" in err and "poses/00.txt not found" in err


# ---- rectified input is not rectified again -------------------------------------------------


def test_rectified_rig_passes_through_with_its_exact_geometry(seq: Path) -> None:
    rig = KittiSequence(seq).rig
    assert is_rectified(rig)
    rect = rectify_stereo(rig, alpha=0.0)
    g = rect.geometry
    assert rect.passthrough
    assert (g.fx, g.fy, g.cx, g.cy) == (FX, FX, CX, CY)
    assert g.baseline == -(-FX * BASELINE) / FX  # exactly -P1[0,3]/P1[0,0]
    assert np.array_equal(g.T_body_rect0, np.eye(4))
    assert np.array_equal(rect.R_rect0_cam0, np.eye(3)) and rect.P1[0, 3] == -FX * g.baseline
    rectifier = StereoRectifier(rig)
    assert rectifier._map0 is None and rectifier._map1 is None  # no remap tables
    frame = next(KittiSequence(seq).frames())
    assert frame.left is not None and frame.right is not None
    assert np.array_equal(rectifier.rectify_left(frame.left), frame.left)
    assert np.array_equal(rectifier.rectify_right(frame.right), frame.right)
    uv = np.array([[0.0, 0.0], [12.25, 99.5], [159.0, 119.0]])
    assert np.array_equal(rectifier.raw_to_rect0(uv), uv)
    assert np.array_equal(rectifier.rect0_to_raw(uv), uv)


def test_a_rig_that_needs_rectifying_is_still_rectified(seq: Path) -> None:
    import dataclasses

    assert not is_rectified(default_rig()) and not rectify_stereo(default_rig()).passthrough
    rig = KittiSequence(seq).rig
    turn = make_T(so3_exp(np.array([0.0, 0.01, 0.0])), np.zeros(3))
    tilted = dataclasses.replace(rig.cam1, T_body_cam=rig.cam1.T_body_cam @ turn)
    other_cx = dataclasses.replace(rig.cam1, cx=CX + 1.0)
    distorted = dataclasses.replace(
        rig.cam0, distortion=(0.01, 0.0, 0.0, 0.0), distortion_model="radial-tangential"
    )
    for r in (
        dataclasses.replace(rig, cam1=tilted),
        dataclasses.replace(rig, cam1=other_cx),
        dataclasses.replace(rig, cam0=distorted),
    ):
        assert not is_rectified(r)
        rectifier = StereoRectifier(r)
        assert not rectifier.passthrough and rectifier._map0 is not None


def test_bench_takes_a_kitti_sequence(seq: Path, tmp_path: Path) -> None:
    from eurocslam.eval.bench.sequences import check_sequence_folder
    from eurocslam.eval.bench.task import RunRecord, _evaluate_run
    from eurocslam.eval.evaluate import EvalConfig

    assert check_sequence_folder("k", seq) is None
    out = tmp_path / "run"
    out.mkdir()
    _estimate(seq, out / "trajectory_final.tum")
    rec = RunRecord("k", 0, out)
    _evaluate_run(rec, seq, EvalConfig())
    assert rec.ok and rec.final is not None
    no_gt = make_kitti(tmp_path / "other", poses=False)
    assert "a KITTI sequence without" in str(check_sequence_folder("k", no_gt))
