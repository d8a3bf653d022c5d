"""`eurocslam convert`, `doctor` and `run` on ROS bags and MCAP, end to end through the CLI.

Bags are written with rosbags' writers from the first 20 real V1_01 micro frames; `convert`'s
MCAP must read back (through the same bag reader) with the ASL folder's images, IMU, ground truth
and calibration, and `run` must give the same trajectory from a bag as from the ASL folder.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from eurocslam.cli import main
from eurocslam.dataset import open_sequence
from eurocslam.dataset.asl import AslSequence
from eurocslam.dataset.bag.reader import BagSequence
from eurocslam.dataset.bag.topics import TopicMap
from eurocslam.dataset.bag.writer import write_rosbag
from eurocslam.dataset.calib import default_rig
from eurocslam.dataset.types import GroundTruth

N = 20  # frames per test bag


@pytest.fixture(scope="module")
def micro(v101_micro: Path) -> SimpleNamespace:
    """The first N real frames, IMU and ground truth cropped to them (+-0.2 s)."""
    seq = AslSequence(v101_micro)
    frames = list(itertools.islice(seq.frames(), N))
    t0, t1 = frames[0].t_ns - 200_000_000, frames[-1].t_ns + 200_000_000
    gt = seq.groundtruth
    assert gt is not None
    k = (gt.t_ns >= t0) & (gt.t_ns <= t1)

    def frames_fn(**_kw):
        return iter(frames)

    return SimpleNamespace(
        frames=frames_fn, frame_list=frames, imu=seq.imu.slice(t0, t1),
        groundtruth=GroundTruth(gt.t_ns[k], gt.p[k], gt.q_wxyz[k]), leica=None,
    )  # fmt: skip


@pytest.fixture(scope="module")
def inputs(micro: SimpleNamespace, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("cli_bags")
    out = {"ros1": write_rosbag(micro, root / "m.bag", "ros1")}
    db3 = write_rosbag(micro, root / "m_db3", "ros2-db3")
    mc = write_rosbag(micro, root / "m_mcap", "ros2-mcap")
    out |= {"ros2-folder": db3, "db3-file": db3 / "m_db3.db3", "mcap-file": mc / "m_mcap.mcap"}
    return out


def _same_as_micro(seq: BagSequence, micro: SimpleNamespace) -> None:
    got = list(seq.frames())
    assert [f.t_ns for f in got] == [f.t_ns for f in micro.frame_list]
    for g, w in zip(got, micro.frame_list, strict=True):
        np.testing.assert_array_equal(g.left, w.left)
        np.testing.assert_array_equal(g.right, w.right)
    np.testing.assert_array_equal(seq.imu.t_ns, micro.imu.t_ns)
    np.testing.assert_array_equal(seq.imu.gyro, micro.imu.gyro)
    np.testing.assert_array_equal(seq.imu.accel, micro.imu.accel)
    assert seq.groundtruth is not None
    np.testing.assert_array_equal(seq.groundtruth.t_ns, micro.groundtruth.t_ns)
    np.testing.assert_allclose(seq.groundtruth.p, micro.groundtruth.p, atol=1e-12)


@pytest.mark.parametrize("kind", ["ros1", "ros2-folder", "db3-file", "mcap-file"])
def test_convert_bag_to_mcap_round_trip(
    kind: str, inputs: dict[str, Path], micro: SimpleNamespace, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "out.mcap"
    assert main(["convert", str(inputs[kind]), "-o", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "carries no calibration: using the built-in EuRoC" in err
    assert out.exists() and not Path(str(out) + ".partial").exists()
    seq = open_sequence(out, quiet=True)
    assert isinstance(seq, BagSequence)
    # the calibration travels as attachments and comes back from them
    assert seq.calib_source == "out.mcap attachments"
    ref = default_rig()
    for cam, want in ((seq.rig.cam0, ref.cam0), (seq.rig.cam1, ref.cam1)):
        np.testing.assert_array_equal(cam.K, want.K)
        np.testing.assert_array_equal(cam.D, want.D)
        np.testing.assert_array_equal(cam.T_body_cam, want.T_body_cam)
        assert cam.resolution == want.resolution
    assert seq.rig.imu.gyro_noise_density == ref.imu.gyro_noise_density
    _same_as_micro(seq, micro)
    # and convert reads its own output again (MCAP -> MCAP), png-compressed this time
    out2 = tmp_path / "again.mcap"
    assert main(["convert", str(out), "-o", str(out2), "--images", "png", "--no-progress"]) == 0
    seq2 = open_sequence(out2, quiet=True)
    assert seq2.stats["cam0"].topic == "/cam0/image_raw/compressed"
    _same_as_micro(seq2, micro)


def test_convert_with_topic_map_and_calib(micro: SimpleNamespace, tmp_path: Path) -> None:
    tm = TopicMap(cam0=("/stereo/left",), cam1=("/stereo/right",), imu=("/mav/imu",))
    bag = write_rosbag(micro, tmp_path / "renamed.bag", "ros1", topics=tm)
    calib = tmp_path / "calib"
    for name, text in default_rig().yaml_texts:
        (calib / name).mkdir(parents=True)
        (calib / name / "sensor.yaml").write_text(text)
    found = tmp_path / "found.mcap"  # topics found by type (names left/right, one Imu)
    assert main(["convert", str(bag), "-o", str(found), "--no-progress"]) == 0
    _same_as_micro(open_sequence(found, quiet=True), micro)
    out = tmp_path / "renamed.mcap"
    args = ["convert", str(bag), "-o", str(out), "--no-progress", "--calib", str(calib),
            "--topic", "cam0=/stereo/left", "--topic", "cam1=/stereo/right",
            "--topic", "imu=/mav/imu"]  # fmt: skip
    assert main(args) == 0
    seq = open_sequence(out, quiet=True)
    assert seq.stats["cam0"].topic == "/cam0/image_raw"  # written under the standard names
    _same_as_micro(seq, micro)


def test_convert_errors_are_one_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 100)
    assert main(["convert", str(bad), "-o", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("eurocslam convert: error:") and "bad.bag" in err
    assert "Traceback" not in err
    assert main(["convert", str(bad), "-o", str(tmp_path / "x.mcap"), "--topic", "cam0"]) == 2
    assert "expected ROLE=TOPIC" in capsys.readouterr().err


def test_doctor_on_bags(inputs: dict[str, Path], tmp_path: Path, capsys) -> None:
    assert main(["doctor", str(inputs["ros1"])]) == 0
    out = capsys.readouterr().out
    assert f"stereo pairs: {N} joined on header stamp" in out
    # a bag without the camera topics: error, exit 2, the bag's topics listed
    junk = tmp_path / "other.bag"
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(junk) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        w.write(c, 1, ts.serialize_ros1(ts.types["std_msgs/msg/String"](data="hi"), c.msgtype))
    assert main(["doctor", str(junk)]) == 2
    out = capsys.readouterr().out
    assert "no topic for cam0" in out and "/chatter (std_msgs/msg/String, 1)" in out


def test_doctor_on_convert_output(inputs: dict[str, Path], tmp_path: Path, capsys) -> None:
    out = tmp_path / "c.mcap"
    assert main(["convert", str(inputs["mcap-file"]), "-o", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["doctor", str(out)]) == 0
    text = capsys.readouterr().out
    assert "calibration: c.mcap attachments" in text


def test_run_on_a_bag_and_on_its_own_output(
    inputs: dict[str, Path], micro: SimpleNamespace, tmp_path: Path
) -> None:
    """`run` straight on a ROS 1 bag (20 real frames); its run.mcap is itself a valid input."""
    out = tmp_path / "run"
    assert main(["run", str(inputs["ros1"]), "-o", str(out), "--no-progress"]) == 0
    rows = (out / "trajectory_online.tum").read_text().splitlines()
    assert len([r for r in rows if r and not r.startswith("#")]) == N
    seq = open_sequence(out / "run.mcap", quiet=True)
    assert seq.calib_source == "run.mcap attachments"
    _same_as_micro(seq, micro)


@pytest.mark.slow
def test_run_on_a_bag_equals_run_on_the_asl_folder(v101_micro: Path, tmp_path: Path) -> None:
    """The SLAM does not care where frames come from: the 95 real micro pairs through a ROS 1
    bag and through the ASL folder give the same trajectory."""
    asl = AslSequence(v101_micro)
    bag = write_rosbag(asl, tmp_path / "v101.bag", "ros1")
    for src, out in ((v101_micro, "asl"), (bag, "bag")):
        assert main(["run", str(src), "-o", str(tmp_path / out), "--no-progress"]) == 0

    def poses(name: str) -> dict[str, str]:
        rows = (tmp_path / name / "trajectory_final.tum").read_text().splitlines()
        return {r.split()[0]: r for r in rows if r and not r.startswith("#")}

    a, b = poses("asl"), poses("bag")
    assert len(b) == 95
    # the ASL folder lists 4 cam1 rows without images; the bag has no messages for them
    assert set(b) <= set(a)
    assert all(a[t] == b[t] for t in b)


@pytest.mark.slow
def test_run_on_a_synthetic_sequence_packed_into_a_bag(tmp_path: Path) -> None:
    """`eurocslam synth` output (moving, exact ground truth) packed into a ROS 2 MCAP bag: `run`
    on the bag gives the trajectory `run` gives on the ASL folder, and it follows the ground
    truth carried in the bag."""
    from eurocslam import synth
    from eurocslam.eval.align import umeyama

    asl_dir = synth.synthesize(synth.SynthSpec.tiny(seed=3), tmp_path / "syn", workers=1)
    asl = AslSequence(asl_dir)
    bag = write_rosbag(asl, tmp_path / "syn_bag", "ros2-mcap")
    calib = ["--calib", str(asl_dir / "mav0")]  # the synthetic rig travels beside the bag
    for src, out, extra in ((bag, "bag", calib), (asl_dir, "asl", [])):
        assert main(["run", str(src), "-o", str(tmp_path / out), "--no-progress", *extra]) == 0
    rows = {}
    for out in ("bag", "asl"):
        text = (tmp_path / out / "trajectory_final.tum").read_text().splitlines()
        rows[out] = [r for r in text if r and not r.startswith("#")]
    assert rows["bag"] == rows["asl"]
    assert len(rows["bag"]) >= 0.95 * len(asl.frame_times)
    # the estimate follows the ground truth that travelled in the bag (SE(3)-aligned ATE)
    seq = open_sequence(bag, quiet=True)
    gt = seq.groundtruth
    assert gt is not None
    est = np.array([[float(v) for v in r.split()[:4]] for r in rows["bag"]])
    t_est = np.round(est[:, 0] * 1e9).astype(np.int64)
    hi = np.clip(np.searchsorted(gt.t_ns, t_est), 1, len(gt) - 1)
    nearer_lo = np.abs(gt.t_ns[hi - 1] - t_est) < np.abs(gt.t_ns[hi] - t_est)
    idx = np.where(nearer_lo, hi - 1, hi)
    close = np.abs(gt.t_ns[idx] - t_est) < 1_000_000
    assert close.all()
    x, y = est[close, 1:4], gt.p[idx[close]]
    r, t, _ = umeyama(x, y, with_scale=False)
    ate = float(np.sqrt(np.mean(np.sum((x @ r.T + t - y) ** 2, axis=1))))
    assert ate < 0.02, f"ATE {ate:.3f} m"  # 2.4 mm measured, over a 1.2 m path
