"""Sinks: reorder buffer (watermark, bound, late messages), tee, threaded writer, MCAP sink
ordering and crash safety."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from eurocslam.errors import OutputError
from eurocslam.io import ros2
from eurocslam.io.mcap_writer import McapSink
from eurocslam.io.qos import qos_profile_yaml
from eurocslam.io.sink import ReorderBuffer, Sink, TeeSink, ThreadedSink


class ListSink:
    def __init__(self) -> None:
        self.msgs: list[tuple[str, str, int, bytes]] = []
        self.closed = False

    def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
        self.msgs.append((topic, msgtype, log_time_ns, msg))

    def close(self) -> None:
        self.closed = True


def test_reorder_buffer_merges_producers_in_time_order() -> None:
    out = ListSink()
    assert isinstance(out, Sink)
    rb = ReorderBuffer(out)
    rb.write("/a", "x", 30, b"a30")
    rb.write("/b", "x", 10, b"b10")
    rb.write("/a", "x", 20, b"a20")
    rb.write("/b", "x", 20, b"b20")  # same time as a20: arrival order kept
    rb.advance(20)
    assert [m[3] for m in out.msgs] == [b"b10", b"a20", b"b20"]
    assert rb.pending == 1
    rb.write("/b", "x", 25, b"b25")  # newer than what was flushed: fine
    with pytest.raises(OutputError, match="log-time order"):
        rb.write("/c", "x", 15, b"late")  # older than a flushed message
    rb.close()
    assert [m[2] for m in out.msgs] == [10, 20, 20, 25, 30] and out.closed


def test_reorder_buffer_memory_bound_flushes_oldest() -> None:
    out = ListSink()
    rb = ReorderBuffer(out, max_bytes=100)
    # two producers, each in order, interleaved with jitter: never more than ~100 bytes held
    for t in range(0, 1000, 10):
        rb.write("/a", "x", t, b"." * 20)
        rb.write("/b", "x", t - 5, b"." * 20)
        assert rb.pending * 20 <= 100
    times = [m[2] for m in out.msgs]
    assert times == sorted(times) and len(times) > 80
    # a message older than what the bound already forced out is an error, not silent disorder
    with pytest.raises(OutputError, match="log-time order"):
        rb.write("/c", "x", 0, b".")
    rb.close()
    assert len(out.msgs) == 200


def test_tee_and_threaded_sink_deliver_everything_in_order() -> None:
    a, b = ListSink(), ListSink()
    ts = ThreadedSink(TeeSink([a, b]), batch_items=7)
    for t in range(1000):
        ts.write("/t", "x", t, bytes([t % 256]))
    ts.close()
    assert [m[2] for m in a.msgs] == list(range(1000)) == [m[2] for m in b.msgs]
    assert a.closed and b.closed


def test_threaded_sink_reports_writer_errors() -> None:
    class Failing(ListSink):
        def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
            raise OSError("disk full")

    ts = ThreadedSink(Failing(), batch_items=1)
    with pytest.raises(OutputError, match="disk full"):
        for t in range(100):
            ts.write("/t", "x", t, b"x")
        ts.close()


def test_mcap_sink_rejects_out_of_order_and_type_change(tmp_path: Path) -> None:
    out = tmp_path / "o.mcap"
    s = McapSink(out)
    s.write("/p", ros2.FLOAT64, 10, ros2.float64(1.0))
    with pytest.raises(OutputError, match="log-time order"):
        s.write("/p", ros2.FLOAT64, 5, ros2.float64(1.0))
    with pytest.raises(OutputError, match="already has type"):
        s.write("/p", ros2.STRING, 11, ros2.string("x"))
    with pytest.raises(OutputError, match="no ROS 2 definition"):
        s.write("/q", "nope_msgs/msg/Nope", 12, b"")
    s.close()
    assert out.exists() and not (tmp_path / "o.mcap.partial").exists()
    with out.open("rb") as f:
        assert make_reader(f).get_summary().statistics.message_count == 1


def test_mcap_sink_exception_in_with_block_leaves_readable_partial(tmp_path: Path) -> None:
    out = tmp_path / "c.mcap"
    with pytest.raises(RuntimeError), McapSink(out, compression="lz4") as s:
        for t in range(50):
            s.write("/p", ros2.POSE_STAMPED, t, ros2.pose_stamped(t, "w", np.eye(4)))
        raise RuntimeError("crash")
    partial = tmp_path / "c.mcap.partial"
    assert not out.exists() and partial.exists()
    with partial.open("rb") as f:
        r = make_reader(f, validate_crcs=True)
        assert sum(1 for _ in r.iter_messages()) == 50


def test_bad_compression_and_unwritable_output(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="compression"):
        McapSink(tmp_path / "x.mcap", compression="gzip")
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError, match="cannot create"):
        McapSink(tmp_path / "file" / "x.mcap")


def test_qos_yaml_is_what_rosbags_parses() -> None:
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2.metadata import parse_qos

    (q,) = parse_qos(qos_profile_yaml(transient_local=True))
    assert q.durability == QosDurability.TRANSIENT_LOCAL
    assert q.reliability == QosReliability.RELIABLE
    (q,) = parse_qos(qos_profile_yaml())
    assert q.durability == QosDurability.VOLATILE
