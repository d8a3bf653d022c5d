"""The KITTI odometry reader on small synthetic KITTI folders made here: calib.txt, times.txt,
poses, images, and every kind of bad file -> a one-line error naming the file and row."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from eurocslam.dataset import KittiSequence, has_imu, open_sequence
from eurocslam.dataset.kitti_files import read_times
from eurocslam.errors import DatasetError
from eurocslam.geometry import quat_wxyz_to_rot
from kitti_helpers import BASELINE, CX, CY, FX, HEIGHT, WIDTH, gt_poses, make_kitti, write_image


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    return make_kitti(tmp_path / "kitti", n=6)


def test_reads_calibration_times_images_and_poses(seq: Path) -> None:
    s = open_sequence(seq)
    assert isinstance(s, KittiSequence) and s.name == "00"
    rig = s.rig
    for cam in (rig.cam0, rig.cam1):
        assert (cam.fx, cam.fy, cam.cx, cam.cy) == (FX, FX, CX, CY)
        assert (cam.width, cam.height) == (WIDTH, HEIGHT)
        assert cam.distortion == (0.0, 0.0, 0.0, 0.0) and cam.rate_hz == 10.0
    # body = cam0; cam1 at +baseline along x, the baseline exactly -P1[0,3]/P1[0,0]
    assert np.array_equal(rig.cam0.T_body_cam, np.eye(4))
    assert rig.cam1.T_body_cam[0, 3] == -(-FX * BASELINE) / FX
    assert np.array_equal(rig.cam1.T_body_cam[:3, :3], np.eye(3))
    assert rig.cam1.T_body_cam[1, 3] == rig.cam1.T_body_cam[2, 3] == 0.0
    assert rig.baseline == pytest.approx(BASELINE, abs=1e-15)
    # no IMU: visual-only
    assert rig.imu is None and len(s.imu) == 0 and not has_imu(s) and s.leica is None
    # times: exact ns from the seconds of times.txt
    assert s.frame_times.tolist() == [i * 100_000_000 for i in range(6)]
    frames = list(s.frames())
    assert [f.t_ns for f in frames] == s.frame_times.tolist()
    assert frames[0].left is not None and frames[0].left.shape == (HEIGHT, WIDTH)
    assert frames[0].left.dtype == np.uint8 and frames[0].left_path == seq / "image_0/000000.png"
    # ground truth: T_world_cam0 of every frame, stamped by times.txt
    gt = s.groundtruth
    assert gt is not None and gt.t_ns.tolist() == s.frame_times.tolist()
    want = gt_poses(6)
    assert np.allclose(gt.p, want[:, :3, 3], atol=1e-8)
    assert np.allclose(quat_wxyz_to_rot(gt.q_wxyz), want[:, :3, :3], atol=1e-8)
    # the rig's sensor.yaml texts read back to the same cameras (MCAP attachments)
    assert dict(rig.yaml_texts).keys() == {"cam0", "cam1"}


def test_times_are_exact_decimal(tmp_path: Path) -> None:
    p = tmp_path / "times.txt"
    p.write_text("0.000000e+00\n1.036592e-01\n\n1403636580.838555648\n")
    t, lines = read_times(p)
    assert t.tolist() == [0, 103_659_200, 1_403_636_580_838_555_648]
    assert lines.tolist() == [1, 2, 4]


def test_rate_from_times_and_colour_images(tmp_path: Path) -> None:
    seq = make_kitti(tmp_path / "k", n=4)
    (seq / "times.txt").write_text("0.0\n0.05\n0.1\n0.15\n")
    write_image(seq / "image_1" / "000002.png", np.random.default_rng(1), colour=True)
    s = KittiSequence(seq)
    assert s.rig.cam0.rate_hz == pytest.approx(20.0)
    frames = list(s.frames())
    assert len(frames) == 4 and frames[2].right is not None and frames[2].right.ndim == 2
    assert s.skips.counts == {"cam1 image converted (colour to mono)": 1}


def test_without_poses_has_no_groundtruth(tmp_path: Path) -> None:
    s = KittiSequence(make_kitti(tmp_path / "k", poses=False))
    assert s.groundtruth is None


def test_unreadable_image_is_a_counted_skip(seq: Path) -> None:
    (seq / "image_0" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\ngarbage")
    s = KittiSequence(seq)
    assert [f.t_ns for f in s.frames()] == [0, 100_000_000, 300_000_000, 400_000_000, 500_000_000]
    assert s.skips.counts == {"unreadable image": 1}
    assert "000002.png" in s.skips.lines()[0]
    incomplete = list(s.frames(include_incomplete=True))
    assert len(incomplete) == 6 and incomplete[2].left is None and incomplete[2].right is not None


def test_dataset_root_is_refused_with_a_hint(seq: Path) -> None:
    root = seq.parent.parent
    with pytest.raises(DatasetError, match=r"a KITTI dataset root; give one sequence folder"):
        open_sequence(root)


# ---- bad files -> one line naming file and row ----------------------------------------------


def _edit(rel: str, fn: Callable[[str], str]) -> Callable[[Path], None]:
    def apply(seq: Path) -> None:
        p = seq / rel
        p.write_text(fn(p.read_text()))

    return apply


def _lines(fn: Callable[[list[str]], list[str]]) -> Callable[[str], str]:
    return lambda text: "\n".join(fn(text.splitlines())) + "\n"


def _replace_row(i: int, row: str) -> Callable[[str], str]:
    return _lines(lambda ls: [row if k == i else ln for k, ln in enumerate(ls)])


def _unlink(rel: str) -> Callable[[Path], None]:
    return lambda seq: (seq / rel).unlink()


BAD: dict[str, tuple[Callable[[Path], None], str]] = {
    "missing times.txt": (_unlink("times.txt"), r"times\.txt: file not found"),
    "missing calib.txt": (_unlink("calib.txt"), r"calib\.txt: file not found"),
    "calib without P1": (
        _edit("calib.txt", _lines(lambda ls: [ln for ln in ls if not ln.startswith("P1:")])),
        r"calib\.txt: no 'P1:' row",
    ),
    "calib non-numeric": (
        _edit("calib.txt", lambda t: t.replace("P1: ", "P1: abc ", 1)),
        r"calib\.txt:2 \(P1\): non-numeric value 'abc'",
    ),
    "calib row too short": (
        _edit("calib.txt", _replace_row(0, "P0: 1 0 2 0 0 1 2 0 0 0 1")),
        r"calib\.txt:1 \(P0\): expected 12 numbers \(3x4 row-major\), found 11",
    ),
    "calib row without a name": (
        _edit("calib.txt", _replace_row(2, "130 0 80 0 0 130 60 0 0 0 1 0")),
        r"calib\.txt:3: expected 'NAME: 12 numbers'",
    ),
    "calib negative baseline": (
        _edit("calib.txt", _replace_row(1, "P1: 130 0 80.5 65 0 130 60.25 0 0 0 1 0")),
        r"calib\.txt:2 \(P1\): baseline .* image_1 must be the right camera",
    ),
    "times non-numeric": (
        _edit("times.txt", _replace_row(2, "abc")),
        r"times\.txt:3: 'abc' is not a time in seconds",
    ),
    "times two values": (
        _edit("times.txt", _replace_row(1, "0.1 0.2")),
        r"times\.txt:2: expected one time in seconds",
    ),
    "times not increasing": (
        _edit("times.txt", _replace_row(3, "2.000000e-01")),
        r"times\.txt:4: time 0\.200000000 s is not after the previous row's 0\.200000000 s",
    ),
    "times negative": (
        _edit("times.txt", _replace_row(0, "-1.0")),
        r"times\.txt:1: negative time",
    ),
    "times empty": (_edit("times.txt", lambda t: "\n"), r"times\.txt: no rows"),
    "more times than images": (
        _edit("times.txt", lambda t: t + "6.000000e-01\n"),
        r"image_0: 6 images but .*times\.txt has 7 rows \(one image per row: "
        r"000006\.png missing \(row 7 of times\.txt\)\)",
    ),
    "an image missing": (
        _unlink("image_1/000003.png"),
        r"image_1: 5 images but .*times\.txt has 6 rows .*000003\.png missing \(row 4 of",
    ),
    "an image too many": (
        lambda seq: write_image(seq / "image_0" / "000006.png", np.random.default_rng(2)),
        r"image_0: 7 images but .*times\.txt has 6 rows .*000006\.png has no row in times\.txt",
    ),
    "no image folder": (
        lambda seq: [p.unlink() for p in (seq / "image_1").iterdir()] and (seq / "image_1").rmdir(),
        r"image_1: image folder not found",
    ),
    "poses row count": (
        lambda seq: _edit("../../poses/00.txt", _lines(lambda ls: ls[:-1]))(seq),
        r"poses/00\.txt: 5 pose rows but .*times\.txt has 6 rows",
    ),
    "poses non-numeric": (
        lambda seq: _edit("../../poses/00.txt", lambda t: t.replace("e", "x", 1))(seq),
        r"poses/00\.txt:1: non-numeric value",
    ),
    "poses row too short": (
        lambda seq: _edit("../../poses/00.txt", _replace_row(2, "1 0 0 0 0 1 0 0 0 0 1"))(seq),
        r"poses/00\.txt:3: expected 12 numbers \(3x4 row-major T_world_cam0\), found 11",
    ),
    "poses not a rotation": (
        lambda seq: _edit("../../poses/00.txt", _replace_row(1, "2 0 0 0 0 1 0 0 0 0 1 0"))(seq),
        r"poses/00\.txt:2: the 3x3 part is not a rotation",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_give_one_line_naming_file_and_row(seq: Path, case: str) -> None:
    damage, pattern = BAD[case]
    damage(seq)
    with pytest.raises(DatasetError, match=pattern) as ei:
        open_sequence(seq)
    assert "\n" not in str(ei.value)
    assert str(seq.parent.parent) in str(ei.value)  # the file is named by its path


def test_bad_file_through_the_cli_is_one_stderr_line(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from eurocslam.cli import main

    (seq / "times.txt").write_text("0.0\n0.1\nxyz\n0.3\n0.4\n0.5\n")
    assert main(["run", str(seq), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "times.txt:3: 'xyz' is not a time in seconds" in err[0]
    assert not (tmp_path / "out").exists()


def test_rig_sensor_yaml_texts_read_back_exactly(seq: Path) -> None:
    from eurocslam.dataset.calib import rig_from_texts

    rig = KittiSequence(seq).rig
    back = rig_from_texts(dict(rig.yaml_texts), "attachments")
    assert back.imu is None
    for a, b in ((back.cam0, rig.cam0), (back.cam1, rig.cam1)):
        assert (a.fx, a.fy, a.cx, a.cy, a.resolution, a.rate_hz) == (
            b.fx,
            b.fy,
            b.cx,
            b.cy,
            b.resolution,
            b.rate_hz,
        )
        assert np.array_equal(a.T_body_cam, b.T_body_cam) and a.distortion == b.distortion
