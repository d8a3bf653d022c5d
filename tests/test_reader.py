"""The ASL reader on the real EuRoC folders: counts, exact values, pairing, laziness."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import cv2
import numpy as np
import pytest

from eurocslam.dataset import open_sequence
from eurocslam.dataset.asl import AslSequence, read_numeric_csv, resolve_mav0
from eurocslam.dataset.images import decode_image_bytes
from eurocslam.errors import DatasetError


@pytest.fixture(scope="module")
def v101(v101_micro: Path) -> AslSequence:
    return AslSequence(v101_micro)


def test_v101_counts(v101: AslSequence) -> None:
    assert v101.name == "V1_01_easy_micro"
    assert len(v101.entries) == 99  # 95 pairs + 4 rows listed in cam1 only (images missing)
    assert len(v101.complete_entries) == 95
    assert v101.skips.counts == {"cam1 image listed but missing": 4, "frame in cam1 only": 4}
    assert len(v101.imu) == 29_120
    assert v101.groundtruth is not None and len(v101.groundtruth) == 2895
    assert v101.leica is None
    assert np.all(np.diff(v101.frame_times) > 0)
    assert np.all(np.diff(v101.imu.t_ns) > 0)


def test_v101_exact_values(v101: AslSequence, v101_micro: Path) -> None:
    # first IMU row, as in the file: integer ns exact, floats to the last digit
    assert v101.imu.t_ns[0] == 1403715273262142976
    assert v101.imu.t_ns.dtype == np.int64
    assert v101.imu.gyro[0, 0] == -0.0020943951023931952
    assert v101.imu.accel[0, 0] == 9.0874956666666655
    gt = v101.groundtruth
    assert gt is not None
    np.testing.assert_array_equal(gt.p[0], [0.878895, 2.1834, 0.948427])
    q = np.array([0.069433, -0.824237, -0.106942, -0.551702])
    np.testing.assert_allclose(gt.q_wxyz[0], q / np.linalg.norm(q), rtol=0, atol=1e-15)
    assert gt.bg is not None and gt.bg[0, 2] == 0.0770299
    assert gt.T_world_body().shape == (2895, 4, 4)


def test_v101_frames_stream_lazily(v101_micro: Path) -> None:
    seq = AslSequence(v101_micro)
    tracemalloc.start()
    n = 0
    first = None
    for f in seq.frames():
        assert f.complete and f.left is not None and f.right is not None
        assert f.left.dtype == np.uint8 and f.left.shape == (480, 752)
        if first is None:
            first = f
        n += 1
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert n == 95
    # 95 pairs decoded are 68 MB; streaming holds a few at a time
    assert peak < 15e6, peak
    assert first is not None and first.left_path is not None
    np.testing.assert_array_equal(
        first.left, cv2.imread(str(first.left_path), cv2.IMREAD_GRAYSCALE)
    )
    # the 4 missing cam1 images: counted once each, skipped
    assert seq.skips.counts["cam1 image listed but missing"] == 4


def test_frames_include_incomplete_and_time_crop(v101: AslSequence) -> None:
    t = v101.frame_times
    tail = list(v101.frames(include_incomplete=True, t_start_ns=int(t[94])))
    assert len(tail) == 5
    assert tail[0].complete
    assert all(f.left is None and f.right is None for f in tail[1:])
    mid = list(v101.frames(t_start_ns=int(t[10]), t_end_ns=int(t[12])))
    assert [f.t_ns for f in mid] == t[10:13].tolist()


def test_imu_slice(v101: AslSequence) -> None:
    t = v101.frame_times
    s = v101.imu.slice(int(t[0]), int(t[1]))
    assert len(s) == 11  # 50 ms at 200 Hz, both ends included
    assert s.t_ns[0] == t[0] and s.t_ns[-1] == t[1]


def test_mh01_first5(mh01_first5: Path) -> None:
    seq = open_sequence(mh01_first5 / "mav0")  # the mav0/ folder is accepted too
    assert seq.name == "MH_01_easy_first5"
    frames = list(seq.frames())
    assert len(frames) == 5
    assert seq.skips.total == 0
    assert seq.leica is not None and len(seq.leica.t_ns) == 5
    np.testing.assert_array_equal(seq.leica.p[0], [4.7822997174796811, -1.8155736277079491,
                                                   0.84462707370341705])  # fmt: skip
    assert seq.groundtruth is not None and len(seq.groundtruth) == 5
    assert len(seq.imu) == 5
    paths = seq.sensor_yaml_paths()
    assert set(paths) == {"cam0", "cam1", "imu0", "state_groundtruth_estimate0", "leica0", "body"}


def test_resolve_mav0(v101_micro: Path, tmp_path: Path) -> None:
    assert resolve_mav0(v101_micro) == v101_micro / "mav0"
    assert resolve_mav0(v101_micro / "mav0") == v101_micro / "mav0"
    with pytest.raises(DatasetError, match="no such file or folder"):
        resolve_mav0(tmp_path / "absent")
    with pytest.raises(DatasetError, match="not an EuRoC ASL sequence"):
        resolve_mav0(tmp_path)


def test_numeric_csv_fast_and_slow_paths_agree(v101_micro: Path, tmp_path: Path) -> None:
    src = v101_micro / "mav0" / "imu0" / "data.csv"
    fast = read_numeric_csv(src, 7)
    # a blank line and spaces after commas force the row-by-row path
    lines = src.read_text().splitlines()[:200]
    odd = tmp_path / "imu.csv"
    odd.write_text("\n".join([lines[0], "", *[ln.replace(",", ", ") for ln in lines[1:]]]) + "\n")
    slow = read_numeric_csv(odd, 7)
    np.testing.assert_array_equal(slow.t_ns, fast.t_ns[:199])
    np.testing.assert_array_equal(slow.values, fast.values[:199])
    assert slow.line_numbers[0] == 3 and fast.line_numbers[0] == 2


def test_decode_image_bytes(v101_micro: Path) -> None:
    png = next((v101_micro / "mav0" / "cam0" / "data").iterdir()).read_bytes()
    ok = decode_image_bytes(png)
    assert ok.image is not None and ok.problem is None and ok.converted is None
    assert decode_image_bytes(b"").problem == "empty file"
    assert "truncated" in (decode_image_bytes(png[:1000]).problem or "")
    assert decode_image_bytes(b"not an image").problem == "not a decodable image"
