"""ROS bags and MCAP as input (`dataset/bag/`): bags written with rosbags' own writers from the
real V1_01 micro data must read back exactly as the ASL folder does, on every container
(ROS 1 .bag, ROS 2 sqlite3 folder / .db3 file, ROS 2 MCAP folder / .mcap file)."""

from __future__ import annotations

import itertools
import re
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from eurocslam.dataset import open_sequence
from eurocslam.dataset.asl import AslSequence
from eurocslam.dataset.bag.files import is_bag_path
from eurocslam.dataset.bag.messages import header_stamp_ns
from eurocslam.dataset.bag.reader import BagSequence
from eurocslam.dataset.bag.topics import TopicMap
from eurocslam.dataset.bag.writer import write_rosbag
from eurocslam.dataset.calib import default_rig
from eurocslam.dataset.doctor.bag_checks import check_bag
from eurocslam.dataset.doctor.report import exit_code
from eurocslam.dataset.types import GroundTruth, ImuData
from eurocslam.errors import CalibrationError, DatasetError

CONTAINERS = {
    # name: (writer format, path of the input given the written path)
    "ros1": ("ros1", lambda p: p),
    "ros2-db3-folder": ("ros2-db3", lambda p: p),
    "ros2-db3-file": ("ros2-db3", lambda p: p / f"{p.name}.db3"),
    "ros2-mcap-folder": ("ros2-mcap", lambda p: p),
    "mcap-file": ("ros2-mcap", lambda p: p / f"{p.name}.mcap"),
}


@pytest.fixture(scope="module")
def asl(v101_micro: Path) -> SimpleNamespace:
    """The real micro sequence with its IMU and ground truth cropped to the camera span +- 0.5 s
    (the full 145 s IMU would only make the tests slower, not stronger)."""
    seq = AslSequence(v101_micro)
    t = seq.frame_times
    t0, t1 = int(t[0]) - 500_000_000, int(t[-1]) + 500_000_000
    gt = seq.groundtruth
    assert gt is not None
    keep = (gt.t_ns >= t0) & (gt.t_ns <= t1)
    gt_crop = GroundTruth(gt.t_ns[keep], gt.p[keep], gt.q_wxyz[keep])
    return SimpleNamespace(
        frames=seq.frames, entries=seq.entries, imu=seq.imu.slice(t0, t1), groundtruth=gt_crop,
        leica=None,
    )  # fmt: skip


@pytest.fixture(scope="module")
def asl_frames(asl: SimpleNamespace) -> list:
    """The 95 complete stereo pairs decoded once from the PNGs (68 MB; shared by the tests)."""
    return list(asl.frames())


@pytest.fixture(scope="module")
def bags(asl: SimpleNamespace, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One bag per writer format, from the real micro sequence (95 pairs, full IMU, GT)."""
    root = tmp_path_factory.mktemp("bags")
    written = {}
    for fmt in ("ros1", "ros2-db3", "ros2-mcap"):
        out = root / ("v101.bag" if fmt == "ros1" else f"v101_{fmt.replace('-', '_')}")
        written[fmt] = write_rosbag(asl, out, fmt)
    return {name: get(written[fmt]) for name, (fmt, get) in CONTAINERS.items()}


def _mini_seq(n: int = 6, size: tuple[int, int] = (752, 480), drop_right: int | None = None):
    """A tiny in-memory source: `n` random stereo pairs at 20 Hz, 200 Hz IMU, no ground truth."""
    rng = np.random.default_rng(0)
    w, h = size
    t0 = 1_403_715_273_262_142_976
    ts = [t0 + i * 50_000_000 for i in range(n)]
    imgs = [(rng.integers(0, 256, (h, w), dtype=np.uint8),) * 2 for _ in range(n)]
    imgs = [(a, rng.integers(0, 256, (h, w), dtype=np.uint8)) for a, _ in imgs]
    t_imu = np.arange(t0 - 100_000_000, ts[-1] + 100_000_000, 5_000_000, dtype=np.int64)
    imu = ImuData(t_imu, rng.normal(size=(t_imu.size, 3)), rng.normal(size=(t_imu.size, 3)))

    def frames(**_kw):
        for i, (t, (a, b)) in enumerate(zip(ts, imgs, strict=True)):
            yield SimpleNamespace(t_ns=t, left=a, right=None if i == drop_right else b)

    return SimpleNamespace(frames=frames, imu=imu, groundtruth=None, leica=None, ts=ts, imgs=imgs)


# ---- equality with the ASL reader --------------------------------------------------------------


@pytest.mark.parametrize("container", list(CONTAINERS))
def test_bag_reads_like_asl(
    container: str, bags: dict[str, Path], asl: SimpleNamespace, asl_frames: list
) -> None:
    path = bags[container]
    assert is_bag_path(path)
    if path.is_dir():  # a ROS 2 bag folder may also be given by its metadata.yaml
        assert open_sequence(path / "metadata.yaml", quiet=True).path == path
    seq = open_sequence(path, quiet=True)
    assert isinstance(seq, BagSequence)
    assert seq.stamp_source == "header stamp"
    assert seq.calib_source == "built-in EuRoC calibration"
    assert any("carries no calibration" in n for n in seq.notes)
    # the 4 cam1 rows of the micro data have no image: the bag has no message for them
    complete = [e.t_ns for e in asl.entries if e.left is not None and e.right is not None]
    assert len(complete) == 95
    np.testing.assert_array_equal(seq.frame_times, complete)
    got = list(seq.frames())
    want = asl_frames
    assert len(got) == len(want) == 95
    for g, w in zip(got, want, strict=True):
        assert g.t_ns == w.t_ns
        np.testing.assert_array_equal(g.left, w.left)
        np.testing.assert_array_equal(g.right, w.right)
    np.testing.assert_array_equal(seq.imu.t_ns, asl.imu.t_ns)
    np.testing.assert_array_equal(seq.imu.gyro, asl.imu.gyro)
    np.testing.assert_array_equal(seq.imu.accel, asl.imu.accel)
    assert seq.groundtruth is not None and asl.groundtruth is not None
    np.testing.assert_array_equal(seq.groundtruth.t_ns, asl.groundtruth.t_ns)
    np.testing.assert_allclose(seq.groundtruth.p, asl.groundtruth.p, atol=1e-12)
    np.testing.assert_allclose(seq.groundtruth.q_wxyz, asl.groundtruth.q_wxyz, atol=1e-12)
    assert seq.skips.total == 0


def test_time_crop_and_partial_iteration(bags: dict[str, Path], asl: SimpleNamespace) -> None:
    seq = BagSequence(bags["ros1"])
    t = seq.frame_times
    got = [f.t_ns for f in seq.frames(t_start_ns=int(t[10]), t_end_ns=int(t[20]))]
    assert got == t[10:21].tolist()
    # abandoning the generator early closes the reader; a new pass starts from the beginning
    it = seq.frames()
    first = next(it)
    it.close()
    assert next(seq.frames()).t_ns == first.t_ns == t[0]


@pytest.mark.parametrize("container", ["ros1", "mcap-file"])
def test_frames_stream_without_holding_the_bag(container: str, bags: dict[str, Path]) -> None:
    """95 pairs are 68 MB of pixels; streaming them must hold only a few at a time."""
    seq = BagSequence(bags[container])
    tracemalloc.start()
    try:
        n = sum(1 for _ in seq.frames())
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert n == 95
    assert peak < 20e6, f"peak {peak / 1e6:.1f} MB while streaming"


@pytest.mark.parametrize(("fmt", "compression"), [("ros1", "bz2"), ("ros1", "lz4"),
                                                  ("ros2-db3", "zstd")])  # fmt: skip
def test_compressed_bags(fmt: str, compression: str, tmp_path: Path) -> None:
    mini = _mini_seq()
    path = write_rosbag(mini, tmp_path / ("z.bag" if fmt == "ros1" else "z"), fmt,
                        compression=compression)  # fmt: skip
    seq = BagSequence(path)
    frames = list(seq.frames())
    assert [f.t_ns for f in frames] == mini.ts
    np.testing.assert_array_equal(frames[5].left, mini.imgs[5][0])
    np.testing.assert_array_equal(seq.imu.gyro, mini.imu.gyro)


# ---- encodings ---------------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["bgr8", "rgb8", "mono16"])
def test_colour_and_16bit_images_become_mono8(
    encoding: str, asl: SimpleNamespace, tmp_path: Path
) -> None:
    out = write_rosbag(asl, tmp_path / "enc.bag", "ros1", encoding=encoding, max_frames=4)
    seq = BagSequence(out)
    assert seq.image_info["cam0"].encoding == encoding
    got = list(seq.frames())
    want = list(itertools.islice(asl.frames(), 4))
    assert len(got) == 4
    for g, w in zip(got, want, strict=True):
        assert g.left is not None and g.left.dtype == np.uint8 and g.left.shape == (480, 752)
        np.testing.assert_array_equal(g.left, w.left)
        np.testing.assert_array_equal(g.right, w.right)


def _raw_bag(
    path: Path,
    *,
    encoding: str = "mono8",
    imu_type: str = "sensor_msgs/msg/Imu",
    cam_topics: tuple[str, str] = ("/cam0/image_raw", "/cam1/image_raw"),
    short_data_at: int | None = None,
) -> Path:
    """A 3-frame ROS 1 bag written directly with rosbags, for the cases write_rosbag refuses."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    t0 = 1_403_715_273_262_142_976
    with Writer(path) as w:
        cams = [w.add_connection(t, "sensor_msgs/msg/Image", typestore=ts) for t in cam_topics]
        imu = w.add_connection("/imu0", imu_type, typestore=ts)
        for i in range(3):
            t = t0 + i * 50_000_000
            stamp = T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9)
            hdr = T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="cam")
            img = T["sensor_msgs/msg/Image"](
                header=hdr, height=480, width=752, encoding=encoding, is_bigendian=0, step=752,
                data=np.zeros(480 * 752, np.uint8),
            )  # fmt: skip
            for k, c in enumerate(cams):
                msg = img
                if k == 0 and i == short_data_at:  # an interrupted copy: half the pixels
                    msg = T["sensor_msgs/msg/Image"](
                        header=hdr, height=480, width=752, encoding=encoding, is_bigendian=0,
                        step=752, data=np.zeros(480 * 752 // 2, np.uint8),
                    )  # fmt: skip
                w.write(c, t, ts.serialize_ros1(msg, "sensor_msgs/msg/Image"))
            if imu_type == "std_msgs/msg/String":
                w.write(imu, t, ts.serialize_ros1(T[imu_type](data="x"), imu_type))
            else:
                v3 = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.81)
                imu_msg = T[imu_type](
                    header=hdr, orientation=T["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1),
                    orientation_covariance=np.zeros(9), angular_velocity=v3,
                    angular_velocity_covariance=np.zeros(9), linear_acceleration=v3,
                    linear_acceleration_covariance=np.zeros(9),
                )  # fmt: skip
                w.write(imu, t, ts.serialize_ros1(imu_msg, imu_type))
    return path


def test_truncated_image_message_is_a_counted_skip(tmp_path: Path) -> None:
    path = _raw_bag(tmp_path / "short.bag", short_data_at=1)
    seq = BagSequence(path)
    assert len(list(seq.frames())) == 2
    assert seq.skips.counts == {"unreadable image message": 1}
    frames = list(seq.frames(include_incomplete=True))
    assert len(frames) == 3 and frames[1].left is None and frames[1].right is not None


def test_unsupported_encoding_names_topic_and_encoding(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"/cam0/image_raw.*'bayer_rggb8' is not supported"):
        BagSequence(_raw_bag(tmp_path / "bayer.bag", encoding="bayer_rggb8"))


# ---- errors ------------------------------------------------------------------------------------


def test_missing_topic_lists_what_the_bag_has(tmp_path: Path) -> None:
    # three image topics whose names form no stereo pair: the type alone cannot decide
    topics = ("/front/image", "/back/image", "/top/image")
    path = _raw_bag(tmp_path / "other.bag", cam_topics=topics)
    with pytest.raises(DatasetError) as e:
        BagSequence(path)
    msg = str(e.value)
    assert "no topic for cam0" in msg and "--topic cam0=TOPIC" in msg
    assert "cannot tell which image topics form the stereo pair" in msg
    assert "/front/image (sensor_msgs/msg/Image, 3)" in msg and "/imu0" in msg
    assert "\n" not in msg


def test_unknown_message_type_is_an_error(tmp_path: Path) -> None:
    path = _raw_bag(tmp_path / "string_imu.bag", imu_type="std_msgs/msg/String")
    with pytest.raises(DatasetError, match=r"/imu0 \(imu\) has message type std_msgs/msg/String"):
        BagSequence(path)


def test_not_a_bag_and_corrupt_bags(tmp_path: Path) -> None:
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all" * 100)
    with pytest.raises(DatasetError, match=r"junk.bag: cannot read as a ROS 1 bag"):
        BagSequence(junk)
    mc = tmp_path / "junk.mcap"
    mc.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    with pytest.raises(DatasetError, match=r"junk.mcap"):
        BagSequence(mc)
    with pytest.raises(DatasetError, match="no such file"):
        open_sequence(tmp_path / "absent.bag")
    txt = tmp_path / "notes.txt"
    txt.write_text("x")
    with pytest.raises(DatasetError, match="not a recognised input"):
        open_sequence(txt)


def test_truncated_bag_gives_a_clear_error(bags: dict[str, Path], tmp_path: Path) -> None:
    data = bags["ros1"].read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match=r"cut\.bag"):
        BagSequence(cut)


# ---- topic map ---------------------------------------------------------------------------------


def test_topic_map_parsing() -> None:
    tm = TopicMap.from_specs(["cam0=/my/left", "right=my/right", "imu0=/my/imu"])
    assert tm.cam0 == ("/my/left",) and tm.cam1 == ("/my/right",) and tm.imu == ("/my/imu",)
    assert tm.explicit == {"cam0", "cam1", "imu"}
    assert tm.groundtruth == TopicMap().groundtruth
    with pytest.raises(DatasetError, match="unknown role 'lidar'"):
        TopicMap.from_specs(["lidar=/x"])
    with pytest.raises(DatasetError, match="expected ROLE=TOPIC"):
        TopicMap.from_specs(["/cam0"])


def test_user_topics(tmp_path: Path) -> None:
    mini = _mini_seq()
    tm = TopicMap(cam0=("/stereo/left",), cam1=("/stereo/right",), imu=("/mav/imu",))
    path = write_rosbag(mini, tmp_path / "renamed.bag", "ros1", topics=tm)
    # found by message type: the names say left and right, the one Imu topic is the IMU
    found = BagSequence(path)
    assert (found.stats["cam0"].topic, found.stats["cam1"].topic) == ("/stereo/left",
                                                                      "/stereo/right")  # fmt: skip
    assert found.stats["imu"].topic == "/mav/imu"
    assert any("stereo pair found by names (left/right)" in n for n in found.notes)
    np.testing.assert_array_equal(found.imu.t_ns, mini.imu.t_ns)
    seq = open_sequence(
        path, topics={"left": "/stereo/left", "cam1": "/stereo/right", "imu": "/mav/imu"},
        quiet=True,
    )  # fmt: skip
    frames = list(seq.frames())
    assert [f.t_ns for f in frames] == mini.ts
    np.testing.assert_array_equal(frames[2].right, mini.imgs[2][1])
    # an explicitly mapped optional role must exist
    with pytest.raises(DatasetError, match="no topic for groundtruth"):
        BagSequence(path, topics=TopicMap.from_specs(["cam0=/stereo/left", "cam1=/stereo/right",
                                                      "imu=/mav/imu", "gt=/mocap"]))  # fmt: skip
    with pytest.raises(DatasetError, match="applies to ROS bags"):
        open_sequence(tmp_path, topics={"cam0": "/x"})


# ---- stamps and pairing ------------------------------------------------------------------------


def test_zero_header_stamps_fall_back_to_log_time(tmp_path: Path) -> None:
    mini = _mini_seq()
    path = write_rosbag(mini, tmp_path / "zero", "ros2-mcap", zero_header_stamps=True)
    seq = BagSequence(path)
    assert seq.stamp_source == "log time"
    assert any("zero header stamp" in n for n in seq.notes)
    assert [f.t_ns for f in seq.frames()] == mini.ts
    np.testing.assert_array_equal(seq.imu.t_ns, mini.imu.t_ns)


def test_unpaired_frames_are_counted_and_yielded_on_request(tmp_path: Path) -> None:
    mini = _mini_seq(drop_right=3)
    seq = BagSequence(write_rosbag(mini, tmp_path / "drop.bag", "ros1"))
    assert len(seq.frame_times) == 6
    assert seq.skips.counts == {"frame in cam0 only": 1}
    assert [f.t_ns for f in seq.frames()] == [t for i, t in enumerate(mini.ts) if i != 3]
    full = list(seq.frames(include_incomplete=True))
    assert len(full) == 6 and full[3].right is None and full[3].left is not None
    findings = check_bag(seq.path)
    assert any(f.severity == "warning" and "1 in cam0 only" in f.message for f in findings)
    assert exit_code(findings) == 1


@pytest.mark.parametrize("zero_stamps", [False, True])
def test_unsynchronised_cameras_pair_on_the_nearest_stamp(
    zero_stamps: bool, tmp_path: Path
) -> None:
    """cam1 stamped 1.5 ms after cam0 (header stamps, or log times when headers are zero)."""
    mini = _mini_seq()
    path = write_rosbag(
        mini, tmp_path / "offset.bag", "ros1", cam1_offset_ns=1_500_000,
        zero_header_stamps=zero_stamps,
    )  # fmt: skip
    seq = BagSequence(path)
    assert seq.stamp_source == ("log time" if zero_stamps else "header stamp")
    assert any("6 stereo pairs joined on the nearest stamp" in n and "1.500 ms" in n
               for n in seq.notes)  # fmt: skip
    frames = list(seq.frames())
    assert [f.t_ns for f in frames] == mini.ts  # a pair takes the cam0 stamp
    np.testing.assert_array_equal(frames[4].right, mini.imgs[4][1])
    assert seq.skips.total == 0
    # beyond the tolerance (5 ms at 20 Hz) nothing is paired
    far = BagSequence(write_rosbag(mini, tmp_path / "far.bag", "ros1", cam1_offset_ns=20_000_000))
    assert list(far.frames()) == []
    assert far.skips.counts == {"frame in cam0 only": 6, "frame in cam1 only": 6}


def test_header_stamp_parser_matches_both_serializations() -> None:
    from rosbags.typesys import Stores, get_typestore

    t = 1_403_715_273_262_142_976
    for store, ros2 in ((Stores.ROS1_NOETIC, False), (Stores.ROS2_HUMBLE, True)):
        ts = get_typestore(store)
        stamp = ts.types["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9)
        kw = {"seq": 7} if not ros2 else {}
        hdr = ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id="imu0", **kw)
        msg = ts.types["geometry_msgs/msg/PointStamped"](
            header=hdr, point=ts.types["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=3.0)
        )
        ser = ts.serialize_cdr if ros2 else ts.serialize_ros1
        assert header_stamp_ns(ser(msg, "geometry_msgs/msg/PointStamped"), ros2) == t
    # big-endian CDR
    ts = get_typestore(Stores.ROS2_HUMBLE)
    raw = ts.serialize_cdr(msg, "geometry_msgs/msg/PointStamped", little_endian=False)
    assert header_stamp_ns(raw, True) == t


# ---- calibration -------------------------------------------------------------------------------


def _calib_dir(root: Path, width: int, height: int, fx: float) -> Path:
    """A calibration folder: EuRoC's sensor.yaml files with another resolution and fx."""
    for name, text in default_rig().yaml_texts:
        d = root / name
        d.mkdir(parents=True)
        if name.startswith("cam"):
            text = text.replace("resolution: [752, 480]", f"resolution: [{width}, {height}]")
            text = re.sub(
                r"intrinsics: \[[^\]]*\]",
                f"intrinsics: [{fx}, {fx}, {width / 2}, {height / 2}]",
                text,
            )
        (d / "sensor.yaml").write_text(text)
    return root


def test_non_euroc_images_need_a_calibration(tmp_path: Path) -> None:
    path = write_rosbag(_mini_seq(size=(640, 400)), tmp_path / "small.bag", "ros1")
    with pytest.raises(
        CalibrationError, match=r"640x400 and the bag carries no calibration.*--calib"
    ):
        BagSequence(path)
    calib = _calib_dir(tmp_path / "calib", 640, 400, 400.0)
    seq = open_sequence(path, calib=calib, quiet=True)
    assert seq.rig.cam0.width == 640 and seq.rig.cam0.fx == 400.0
    assert seq.calib_source == str(calib)
    assert not any("carries no calibration" in n for n in seq.notes)
    assert len(list(seq.frames())) == 6
    # a given calibration that disagrees with the images is an error too
    wrong = _calib_dir(tmp_path / "wrong", 752, 480, 400.0)
    with pytest.raises(CalibrationError, match=r"640x400 but the calibration .* says 752x480"):
        BagSequence(path, calib=wrong)


def test_mcap_attachments_provide_the_calibration(tmp_path: Path) -> None:
    """An MCAP with the sensor.yaml files attached (as `eurocslam convert` writes them)."""
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    mini = _mini_seq(size=(320, 200))
    src = write_rosbag(mini, tmp_path / "src", "ros2-mcap")
    calib = _calib_dir(tmp_path / "calib", 320, 200, 250.0)
    # re-pack the rosbag2 MCAP's messages into a stand-alone MCAP with attachments
    out = tmp_path / "with_calib.mcap"
    ts = get_typestore(Stores.ROS2_HUMBLE)
    from rosbags.highlevel import AnyReader

    with AnyReader([src]) as reader, out.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        chans = {}
        for c in reader.connections:
            text, _ = ts.generate_msgdef(c.msgtype, ros_version=2)
            sid = w.register_schema(c.msgtype, "ros2msg", text.encode())
            chans[c.topic] = w.register_channel(c.topic, "cdr", sid)
        for c, t, raw in reader.messages():
            w.add_message(chans[c.topic], log_time=t, data=bytes(raw), publish_time=t)
        for s in ("cam0", "cam1", "imu0"):
            data = (calib / s / "sensor.yaml").read_bytes()
            w.add_attachment(t, t, f"mav0/{s}/sensor.yaml", "application/yaml", data)
        w.finish()
    seq = open_sequence(out, quiet=True)
    assert seq.calib_source == "with_calib.mcap attachments"
    assert seq.rig.cam0.fx == 250.0 and seq.rig.cam1.width == 320
    assert [f.t_ns for f in seq.frames()] == mini.ts


# ---- ground truth from EuRoC's raw Vicon -------------------------------------------------------


def test_vicon_transform_is_moved_to_the_body_frame(asl: SimpleNamespace, tmp_path: Path) -> None:
    path = write_rosbag(asl, tmp_path / "vicon.bag", "ros1", groundtruth="vicon", max_frames=2)
    seq = BagSequence(path)
    assert seq.stats["groundtruth"].topic == "/vicon/firefly_sbx/firefly_sbx"
    assert any("vicon0 T_BS" in n for n in seq.notes)
    assert seq.groundtruth is not None and asl.groundtruth is not None
    np.testing.assert_allclose(seq.groundtruth.p, asl.groundtruth.p, atol=1e-9)
    dots = np.abs(np.sum(seq.groundtruth.q_wxyz * asl.groundtruth.q_wxyz, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)


# ---- doctor ------------------------------------------------------------------------------------


def test_check_bag_on_a_good_bag(bags: dict[str, Path], asl: SimpleNamespace) -> None:
    findings = check_bag(bags["ros2-mcap-folder"])
    text = "\n".join(f"{f.severity}: {f.message}" for f in findings)
    assert exit_code(findings) == 0, text
    assert "stereo pairs: 95 joined on header stamp" in text
    assert "/imu0: rate 200.0 Hz" in text and "/cam0/image_raw: rate 20.0 Hz" in text
    assert f"imu: /imu0 [sensor_msgs/msg/Imu] {len(asl.imu)} messages" in text


def test_check_bag_reports_open_errors(tmp_path: Path) -> None:
    path = _raw_bag(tmp_path / "other.bag", cam_topics=("/a/image", "/b/image", "/c/image"))
    findings = check_bag(path)
    assert exit_code(findings) == 2
    assert findings[0].severity == "error" and "no topic for cam0" in findings[0].message


def test_machine_hall_bag_with_leica(mh01_first5: Path, tmp_path: Path) -> None:
    """MH_01's first 5 real pairs with its Leica positions (EuRoC's `/leica/position`)."""
    asl = AslSequence(mh01_first5)
    assert asl.leica is not None and len(asl.leica.t_ns) > 0
    seq = BagSequence(write_rosbag(asl, tmp_path / "mh01.bag", "ros1"))
    assert seq.stats["leica"].topic == "/leica/position"
    assert seq.leica is not None
    np.testing.assert_array_equal(seq.leica.t_ns, asl.leica.t_ns)
    np.testing.assert_array_equal(seq.leica.p, asl.leica.p)
    got, want = list(seq.frames()), list(asl.frames())
    assert len(got) == len(want) == 5
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g.left, w.left)
        np.testing.assert_array_equal(g.right, w.right)
