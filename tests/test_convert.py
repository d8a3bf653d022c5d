"""Round trip of `eurocslam convert` on real EuRoC data, read back by readers nobody here wrote:
rosbags (its own type definitions), mcap_ros2's decoder and the mcap reader with CRC checks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from eurocslam.cli import main
from eurocslam.convert import ConvertOptions, convert
from eurocslam.dataset import open_sequence
from eurocslam.dataset.types import StereoFrame
from eurocslam.errors import OutputError
from eurocslam.io import ros2
from eurocslam.io.sensor_streams import SensorStreams, StreamOptions

TS = get_typestore(Stores.ROS2_HUMBLE)


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _read_all(path: Path) -> list[tuple[str, int, object]]:
    """(topic, log_time, message) for every message, decoded by rosbags."""
    out = []
    with AnyReader([path], default_typestore=TS) as r:
        for con, t, raw in r.messages():
            out.append((con.topic, t, r.deserialize(raw, con.msgtype)))
    return out


@pytest.fixture(scope="module")
def v101_mcap(v101_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("conv") / "v101.mcap"
    src = open_sequence(v101_micro)
    res = convert(src, out, ConvertOptions(progress=False))
    return out, res


def test_v101_every_message_decodes_and_matches_source(v101_mcap, v101_micro: Path) -> None:
    path, res = v101_mcap
    assert path.exists() and not Path(str(path) + ".partial").exists()
    msgs = _read_all(path)
    src = open_sequence(v101_micro)

    # order: log times non-decreasing, /tf_static first and stamped at/before everything else
    times = [t for _, t, _ in msgs]
    assert all(np.diff(np.array(times, dtype=np.int64)) >= 0)
    assert msgs[0][0] == "/tf_static"
    assert _ns(msgs[0][2].transforms[0].header.stamp) <= times[0]

    by_topic: dict[str, list[tuple[int, object]]] = {}
    for topic, t, m in msgs:
        by_topic.setdefault(topic, []).append((t, m))

    # counts: 95 stereo pairs, the 4 listed-but-missing cam1 images reported, full IMU
    assert len(by_topic["/cam0/image_raw"]) == 95
    assert len(by_topic["/cam1/image_raw"]) == 95
    assert len(by_topic["/cam0/camera_info"]) == 95
    assert len(by_topic["/imu0"]) == len(src.imu) == 29120
    assert len(by_topic["/groundtruth/pose"]) == len(src.groundtruth)
    assert res.skips.counts.get("cam1 image listed but missing") == 4
    assert res.frames == 95

    # images: exact bytes of the PNGs, header stamp = log time = EuRoC timestamp
    entries = {e.t_ns: e for e in src.entries}
    for cam, attr in (("cam0", "left"), ("cam1", "right")):
        for k, (t, m) in enumerate(by_topic[f"/{cam}/image_raw"]):
            assert _ns(m.header.stamp) == t and m.header.frame_id == cam
            assert m.encoding == "mono8" and m.step == m.width == 752 and m.height == 480
            if k % 10 == 0:
                ref = cv2.imread(str(getattr(entries[t], attr)), cv2.IMREAD_UNCHANGED)
                assert bytes(m.data) == ref.tobytes()

    # IMU values and covariances
    imu = by_topic["/imu0"]
    t_imu = np.array([t for t, _ in imu])
    np.testing.assert_array_equal(t_imu, src.imu.t_ns)
    g = np.array(
        [[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for _, m in imu]
    )
    a = np.array(
        [
            [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
            for _, m in imu
        ]
    )
    np.testing.assert_array_equal(g, src.imu.gyro)
    np.testing.assert_array_equal(a, src.imu.accel)
    m0 = imu[0][1]
    assert m0.orientation_covariance[0] == -1
    rate = src.rig.imu.rate_hz
    assert m0.angular_velocity_covariance[0] == pytest.approx(
        src.rig.imu.gyro_noise_density**2 * rate
    )
    assert m0.linear_acceleration_covariance[8] == pytest.approx(
        src.rig.imu.accel_noise_density**2 * rate
    )

    # calibration: K, D and the body->camera transforms
    info0 = by_topic["/cam0/camera_info"][0][1]
    np.testing.assert_allclose(np.array(info0.k).reshape(3, 3), src.rig.cam0.K)
    np.testing.assert_allclose(info0.d[:4], src.rig.cam0.distortion)
    assert info0.distortion_model == "plumb_bob"
    info1 = by_topic["/cam1/camera_info"][0][1]
    assert info1.p[3] == pytest.approx(-info1.p[0] * src.rig.baseline, rel=1e-6)
    tfs = {tr.child_frame_id: tr for tr in msgs[0][2].transforms}
    assert set(tfs) == {"imu0", "cam0", "cam1"}
    tr = tfs["cam0"].transform
    np.testing.assert_allclose(
        [tr.translation.x, tr.translation.y, tr.translation.z], src.rig.cam0.T_body_cam[:3, 3]
    )

    # ground truth: pose and tf agree with the CSV (quaternion xyzw <- wxyz)
    gt = src.groundtruth
    t, pose = by_topic["/groundtruth/pose"][7]
    assert t == gt.t_ns[7] and pose.header.frame_id == "gt_world"
    np.testing.assert_allclose(
        [pose.pose.position.x, pose.pose.position.y, pose.pose.position.z], gt.p[7]
    )
    q = pose.pose.orientation
    np.testing.assert_allclose([q.w, q.x, q.y, q.z], gt.q_wxyz[7])
    tf7 = by_topic["/tf"][7][1].transforms[0]
    assert (tf7.header.frame_id, tf7.child_frame_id) == ("gt_world", "gt_body")
    paths = by_topic["/groundtruth/path"]
    path_t = np.array([t for t, _ in paths])
    assert np.all(np.diff(path_t) >= 1_000_000_000 - 1)  # at most 1 Hz
    assert len(paths[-1][1].poses) > len(paths[0][1].poses)


def test_v101_mcap_structure_crc_summary_metadata_qos(v101_mcap) -> None:
    from mcap_ros2.decoder import DecoderFactory

    path, res = v101_mcap
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == res.summary.message_count
        assert summary.chunk_indexes and all(c.compression == "zstd" for c in summary.chunk_indexes)
        for sch in summary.schemas.values():
            assert sch.encoding == "ros2msg"
            assert sch.data.decode() == ros2.schema_text(sch.name)
        qos = {}
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            qos[ch.topic] = yaml.safe_load(ch.metadata["offered_qos_profiles"])[0]
        assert qos["/tf_static"]["durability"] == 1  # transient local
        assert qos["/imu0"]["durability"] == 2  # volatile
        n = sum(1 for _ in reader.iter_messages())  # decompresses every chunk, checks CRCs
        assert n == summary.statistics.message_count
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        info = yaml.safe_load(meta["rosbag2"]["serialized_metadata"])
        assert info["storage_identifier"] == "mcap" and info["message_count"] == n
        counts = {
            t["topic_metadata"]["name"]: t["message_count"]
            for t in info["topics_with_message_count"]
        }
        assert counts["/cam1/image_raw"] == 95
        names = {a.name for a in reader.iter_attachments()}
        assert {"cam0/sensor.yaml", "cam1/sensor.yaml", "imu0/sensor.yaml"} <= names
    # mcap_ros2's own decoder reads every message too
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert sum(1 for _ in reader.iter_decoded_messages()) == n


def test_compress_threads_and_workers_write_the_same_messages(
    v101_mcap, v101_micro: Path, tmp_path: Path
) -> None:
    """Chunks compressed in background threads, more decode threads: the same messages in the
    same chunks (only the attachments' create times differ)."""
    out = tmp_path / "threads.mcap"
    convert(
        open_sequence(v101_micro),
        out,
        ConvertOptions(progress=False, workers=3, compress_threads=2),
    )

    def content(path: Path) -> tuple[list, list]:
        with path.open("rb") as f:
            r = make_reader(f, validate_crcs=True)
            msgs = [
                (c.topic, m.log_time, m.data) for _, c, m in r.iter_messages(log_time_order=False)
            ]
            chunks = [
                (c.uncompressed_size, c.compressed_size) for c in r.get_summary().chunk_indexes
            ]
        return msgs, chunks

    assert content(out) == content(v101_mcap[0])


def test_mh01_png_passthrough_leica_lz4(mh01_first5: Path, tmp_path: Path) -> None:
    out = tmp_path / "mh01.mcap"
    src = open_sequence(mh01_first5)
    res = convert(src, out, ConvertOptions(images="png", compression="lz4", progress=False))
    msgs = _read_all(out)
    topics = [t for t, _, _ in msgs]
    assert topics[0] == "/tf_static"
    assert topics.count("/cam0/image_raw/compressed") == 5
    assert topics.count("/leica0") == len(src.leica.t_ns) == 5
    first = next(m for t, _, m in msgs if t == "/cam1/image_raw/compressed")
    e0 = src.entries[0]
    assert first.format == "png" and bytes(first.data) == e0.right.read_bytes()
    le = next(m for t, _, m in msgs if t == "/leica0")
    np.testing.assert_allclose([le.point.x, le.point.y, le.point.z], src.leica.p[0])
    assert res.skips.total == 0
    with out.open("rb") as f:
        assert all(c.compression == "lz4" for c in make_reader(f).get_summary().chunk_indexes)


def test_decoded_frames_pass_their_png_files_through(mh01_first5: Path, tmp_path: Path) -> None:
    """`run --images png` hands run.mcap frames it has decoded already: an 8-bit grey PNG file
    goes in byte for byte (not encoded again); a frame without files, or whose file is not 8-bit
    grey (the reader converted it), is encoded from the pixels SLAM used."""
    src = open_sequence(mh01_first5)
    streams = SensorStreams(src, StreamOptions(images="png"))
    frame = next(iter(src.frames()))
    assert frame.left is not None and frame.left_path is not None and frame.right_path is not None
    enc = streams.encode_frame(frame)
    assert enc.cam0 is not None and enc.cam1 is not None
    assert frame.left_path.read_bytes() in enc.cam0 and frame.right_path.read_bytes() in enc.cam1
    bare = streams.encode_frame(StereoFrame(frame.t_ns, frame.left, frame.right))
    assert bare.cam0 is not None and frame.left_path.read_bytes() not in bare.cam0
    png16 = tmp_path / "left16.png"
    cv2.imwrite(str(png16), frame.left.astype(np.uint16) << 8)
    wide = streams.encode_frame(StereoFrame(frame.t_ns, frame.left, frame.right, png16))
    for enc_cam0 in (bare.cam0, wide.cam0):
        assert enc_cam0 is not None and png16.read_bytes() not in enc_cam0
        png = enc_cam0[enc_cam0.index(b"\x89PNG") :]
        decoded = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(decoded, frame.left)


def test_jpeg_crop_and_topic_selection(v101_micro: Path, tmp_path: Path) -> None:
    out = tmp_path / "crop.mcap"
    src = open_sequence(v101_micro)
    t0 = int(src.frame_times[0])
    opts = ConvertOptions(
        images="jpeg",
        compression="none",
        start=1.0,
        end=2.0,
        topics=frozenset({"/cam0/image_raw", "/imu0"}),
        progress=False,
    )
    convert(src, out, opts)
    msgs = _read_all(out)
    topics = {t for t, _, _ in msgs}
    assert topics == {"/cam0/image_raw/compressed", "/imu0"}
    t_ref = min(int(src.imu.t_ns[0]), t0, int(src.groundtruth.t_ns[0]))
    times = np.array([t for _, t, _ in msgs])
    assert times.min() >= t_ref + 1_000_000_000 and times.max() <= t_ref + 2_000_000_000
    img = next(m for t, _, m in msgs if t == "/cam0/image_raw/compressed")
    dec = cv2.imdecode(np.frombuffer(bytes(img.data), np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.format == "jpeg" and dec.shape == (480, 752)
    # absolute nanosecond bounds select the same window
    out2 = tmp_path / "crop2.mcap"
    convert(
        src,
        out2,
        ConvertOptions(
            images="jpeg",
            start=t_ref + 1e9,
            end=t_ref + 2e9,
            topics=frozenset({"/imu0"}),
            progress=False,
        ),
    )
    assert sum(1 for t, _, _ in _read_all(out2)) == sum(1 for t, _, _ in msgs if t == "/imu0")


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_interrupted_write_leaves_readable_partial(
    v101_micro: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    exc: BaseException,
) -> None:
    calls = {"n": 0}
    orig = SensorStreams.write_frame

    def failing(self, sink, frame):
        calls["n"] += 1
        if calls["n"] == 20:
            raise exc
        return orig(self, sink, frame)

    monkeypatch.setattr(SensorStreams, "write_frame", failing)
    out = tmp_path / "int.mcap"
    expected = KeyboardInterrupt if isinstance(exc, KeyboardInterrupt) else OutputError
    with pytest.raises(expected):
        convert(open_sequence(v101_micro), out, ConvertOptions(progress=False))
    partial = tmp_path / "int.mcap.partial"
    assert not out.exists() and partial.exists()
    (rec,) = [r for r in caplog.records if r.name == "eurocslam.convert"]
    assert rec.levelname == "WARNING" and rec.getMessage().startswith("eurocslam convert: stopped")
    assert "int.mcap.partial" in rec.getMessage() and "readable" in rec.getMessage()
    link = tmp_path / "partial-copy.mcap"  # rosbags picks its reader by the file suffix
    link.symlink_to(partial)
    msgs = _read_all(link)
    assert sum(1 for t, _, _ in msgs if t == "/cam0/image_raw") == 19
    with partial.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary().statistics.message_count == len(msgs)


def test_cli_convert_and_clear_errors(
    mh01_first5: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cli.mcap"
    assert main(["convert", str(mh01_first5), "-o", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "/cam0/image_raw" in text and "messages" in text
    assert out.exists()
    # bad input: one line, exit 2, no traceback
    assert main(["convert", str(tmp_path / "nope"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    out = tmp_path / "other.mcap"  # cli.mcap exists now: convert would refuse to replace it
    assert main(["convert", str(mh01_first5), "-o", str(out), "--topics", "/bogus"]) == 2
    err = capsys.readouterr().err
    assert "/bogus" in err and "Traceback" not in err
    assert main(["convert", str(mh01_first5), "-o", str(tmp_path / "x.bag")]) == 2


def test_rosbag2_metadata_record_opens_as_a_rosbag2_folder(
    mh01_first5: Path, tmp_path: Path
) -> None:
    """The `rosbag2` metadata record is a bag's metadata.yaml: written next to the MCAP it makes a
    rosbag2 folder that rosbags' rosbag2 Reader (which follows rosbag2's own rules) opens."""
    from rosbags.rosbag2 import Reader

    bag = tmp_path / "bag"
    out = bag / "mh01.mcap"
    convert(open_sequence(mh01_first5), out, ConvertOptions(progress=False))
    with out.open("rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["rosbag2"]
    info = yaml.safe_load(meta["serialized_metadata"])
    (bag / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    with Reader(bag) as r:
        counts = {c.topic: c.msgcount for c in r.connections}
        assert counts["/cam0/image_raw"] == 5 and counts["/tf_static"] == 1
        tf_static = next(c for c in r.connections if c.topic == "/tf_static")
        assert tf_static.ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"
        assert sum(1 for _ in r.messages()) == r.message_count == sum(counts.values())
