"""Trajectory files: exact round trips, segments, format detection, and clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eurocslam.errors import EvalError
from eurocslam.eval.synthetic import smooth_trajectory
from eurocslam.timebase import ns_to_seconds_str, seconds_str_to_ns
from eurocslam.trajectory import Trajectory
from eurocslam.trajectory_io import (
    count_repeated_stamps,
    read_euroc_csv,
    read_trajectory,
    read_tum,
    write_euroc_csv,
    write_tum,
)


def _traj(n: int = 50, seed: int = 0) -> Trajectory:
    t = smooth_trajectory(n, 20.0, seed)
    # odd nanosecond stamps, to prove the round trip is exact
    rng = np.random.default_rng(seed)
    t_ns = t.t_ns + rng.integers(0, 999, size=n)
    return Trajectory(np.sort(t_ns), t.p, t.q_wxyz, None, "t")


def _same_rotation(q1: np.ndarray, q2: np.ndarray, tol: float = 1e-8) -> None:
    # q and -q are the same rotation
    d = np.minimum(np.abs(q1 - q2).max(axis=1), np.abs(q1 + q2).max(axis=1))
    assert d.max() < tol


@pytest.mark.parametrize(
    ("tok", "ns"),
    [
        ("1403636580.838555648", 1403636580838555648),
        ("1.403636578922881365e+09", 1403636578922881365),
        ("12", 12_000_000_000),
        ("0.5", 500_000_000),
        (".25", 250_000_000),
        ("-1.5", -1_500_000_000),
        ("1.0000000005", 1_000_000_001),  # rounded half up at the 10th digit
        ("1.00000000049", 1_000_000_000),
    ],
)
def test_seconds_string_to_ns_is_exact(tok: str, ns: int) -> None:
    assert seconds_str_to_ns(tok) == ns


def test_ns_to_seconds_string_round_trip() -> None:
    for v in (0, 1, 999_999_999, 1_403_636_580_838_555_648, -1_500_000_000, -1):
        assert seconds_str_to_ns(ns_to_seconds_str(v)) == v


def test_tum_round_trip_exact_ns(tmp_path: Path) -> None:
    tr = _traj()
    f = tmp_path / "a.tum"
    write_tum(f, tr)
    back = read_tum(f)
    assert np.array_equal(back.t_ns, tr.t_ns)
    assert np.abs(back.p - tr.p).max() < 1e-9
    _same_rotation(back.q_wxyz, tr.q_wxyz)
    assert back.segment is None
    assert not (tmp_path / "a.tum.partial").exists()


def test_euroc_round_trip_with_segments(tmp_path: Path) -> None:
    tr = _traj(40)
    seg = np.repeat(np.array([0, 1, 2], dtype=np.int64), [10, 20, 10])
    tr = Trajectory(tr.t_ns, tr.p, tr.q_wxyz, seg, "t")
    f = tmp_path / "a.csv"
    write_euroc_csv(f, tr)
    assert f.read_text().splitlines()[0].endswith(",segment")
    back = read_euroc_csv(f)
    assert np.array_equal(back.t_ns, tr.t_ns)
    assert np.array_equal(back.segment, seg)
    assert [sid for sid, _ in back.segments()] == [0, 1, 2]
    assert [len(s) for _, s in back.segments()] == [10, 20, 10]


def test_tum_segments_as_comment_lines_and_evo_reads_them(tmp_path: Path) -> None:
    from evo.tools import file_interface

    tr = _traj(30)
    seg = np.repeat(np.array([3, 7], dtype=np.int64), [12, 18])
    tr = Trajectory(tr.t_ns, tr.p, tr.q_wxyz, seg, "t")
    f = tmp_path / "seg.tum"
    write_tum(f, tr)
    text = f.read_text()
    assert "# segment 3\n" in text and "# segment 7\n" in text
    back = read_tum(f)
    assert np.array_equal(back.segment, seg)
    # evo ignores the comment lines and reads one trajectory; its float seconds agree to 1 us
    evo_traj = file_interface.read_tum_trajectory_file(str(f))
    assert evo_traj.num_poses == 30
    assert np.abs(evo_traj.timestamps - tr.t_ns / 1e9).max() < 1e-6
    assert np.abs(evo_traj.positions_xyz - tr.p).max() < 1e-9


def test_format_detected_from_content_not_extension(tmp_path: Path) -> None:
    tr = _traj(10)
    a, b = tmp_path / "really_tum.csv", tmp_path / "really_euroc.txt"
    write_tum(a, tr)
    write_euroc_csv(b, tr)
    ta, tb = read_trajectory(a), read_trajectory(b)
    assert np.array_equal(ta.t_ns, tb.t_ns)
    _same_rotation(ta.q_wxyz, tb.q_wxyz)


def test_reads_asl_groundtruth_17_columns(euroc_dir: Path) -> None:
    gt = read_trajectory(euroc_dir / "groundtruth/V1_02_medium.csv")
    assert len(gt) == 16702
    assert gt.t_ns[0] == 1403715524907143168
    # first row: q_RS_w, x, y, z = 0.161996, 0.789985, -0.205376, 0.554528 (w first in the file)
    assert np.allclose(gt.q_wxyz[0], [0.161996, 0.789985, -0.205376, 0.554528], atol=1e-5)
    assert np.allclose(gt.p[0], [0.515356, 1.996773, 0.971104])


def test_reads_tum_groundtruth_with_header(euroc_dir: Path) -> None:
    gt = read_trajectory(euroc_dir / "groundtruth/MH_01_easy.txt")
    assert gt.t_ns[0] == 1403636580838560000
    # file: qx qy qz qw = -0.153029 -0.827383 -0.082152 0.534108
    assert np.allclose(gt.q_wxyz[0], [0.534108, -0.153029, -0.827383, -0.082152], atol=1e-5)


def test_repeated_stamps_are_kept_and_counted(tmp_path: Path) -> None:
    f = tmp_path / "dup.tum"
    f.write_text("1.0 0 0 0 0 0 0 1\n1.1 1 0 0 0 0 0 1\n1.1 2 0 0 0 0 0 1\n1.2 3 0 0 0 0 0 1\n")
    tr = read_tum(f)
    assert len(tr) == 4
    assert count_repeated_stamps(tr) == 1


def _err(tmp_path: Path, text: str, name: str = "x.txt", **kw: object) -> str:
    f = tmp_path / name
    f.write_text(text)
    with pytest.raises(EvalError) as e:
        read_trajectory(f, **kw)  # type: ignore[arg-type]
    msg = str(e.value)
    assert str(f) in msg
    return msg


def test_errors_name_file_and_line(tmp_path: Path) -> None:
    good = "1.0 0 0 0 0 0 0 1\n"
    assert ":2:" in _err(tmp_path, good + "1.1 0 0 0 0 0 1\n")  # 7 columns
    assert ":3:" in _err(tmp_path, good + good.replace("1.0", "1.1") + "1.2 0 x 0 0 0 0 1\n")
    assert "non-finite" in _err(tmp_path, good + "1.1 nan 0 0 0 0 0 1\n")
    assert "zero-norm" in _err(tmp_path, good + "1.1 0 0 0 0 0 0 0\n")
    assert "backwards" in _err(tmp_path, good + "0.9 0 0 0 0 0 0 1\n")
    assert "not a number" in _err(tmp_path, "abc 0 0 0 0 0 0 1\n")
    assert "no poses" in _err(tmp_path, "# only a comment\n\n")
    assert "needs 8" in _err(tmp_path, "1 2 3\n")


def test_seconds_nanoseconds_mixups_detected(tmp_path: Path) -> None:
    # a TUM file holding nanoseconds
    msg = _err(tmp_path, "1403636580838555648 0 0 0 0 0 0 1\n", "ns.tum")
    assert "looks like nanoseconds" in msg
    msg = _err(tmp_path, "1403636580838.5 0 0 0 0 0 0 1\n", "ns2.tum")
    assert "looks like nanoseconds" in msg
    # a EuRoC CSV holding seconds (decimal) ...
    msg = _err(tmp_path, "#timestamp,x,y,z,qw,qx,qy,qz\n1403636580.83,0,0,0,1,0,0,0\n", "s.csv")
    assert "looks like seconds" in msg
    # ... or small integers
    msg = _err(tmp_path, "0,0,0,0,1,0,0,0\n12,0,0,0,1,0,0,0\n", "s2.csv")
    assert "looks like seconds" in msg
    # override works
    f = tmp_path / "ns.tum"
    tr = read_trajectory(f, time_unit="ns")
    assert tr.t_ns[0] == 1403636580838555648


def test_nanosecond_tum_with_trailing_zero_fraction(tmp_path: Path) -> None:
    # ORB-SLAM3 writes "1403636579763555584.000000" style stamps
    f = tmp_path / "orb.txt"
    f.write_text("1403636579763555584.000000 0 0 0 0 0 0 1\n")
    assert read_trajectory(f, time_unit="ns").t_ns[0] == 1403636579763555584


def test_binary_and_folder_inputs_are_errors(tmp_path: Path) -> None:
    b = tmp_path / "b.bin"
    b.write_bytes(b"\x89\xff\xfe\x00" * 10)
    with pytest.raises(EvalError, match="not a text file"):
        read_trajectory(b)
    with pytest.raises(EvalError, match="is a folder"):
        read_trajectory(tmp_path)
    with pytest.raises(EvalError, match="file not found"):
        read_trajectory(tmp_path / "missing.tum")


def test_write_error_is_output_error(tmp_path: Path) -> None:
    from eurocslam.errors import OutputError

    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError):
        write_tum(tmp_path / "file" / "sub.tum", _traj(3))


def test_free_text_comments_are_not_headers(tmp_path: Path) -> None:
    f = tmp_path / "c.tum"
    f.write_text(
        "# poses of each segment after a reset are in a new world frame w x y z\n"
        "1.0 0 0 0 0 0 0 1\n1.1 1 0 0 0 0 0 1\n"
    )
    tr = read_tum(f)
    assert tr.segment is None
    assert np.allclose(tr.q_wxyz, [1, 0, 0, 0])


def test_reads_what_the_run_writes(tmp_path: Path) -> None:
    tr = _traj(20)
    seg = np.repeat(np.array([0, 1], dtype=np.int64), [8, 12])
    tr = Trajectory(tr.t_ns, tr.p, tr.q_wxyz, seg, "final")
    write_tum(tmp_path / "f.tum", tr, "eurocslam vio: final trajectory, body in world\nline two")
    back = read_trajectory(tmp_path / "f.tum")
    assert np.array_equal(back.segment, seg) and np.array_equal(back.t_ns, tr.t_ns)
