"""Run outputs on their own: PLY map round trip, ground-truth overlay alignment."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eurocslam.errors import OutputError
from eurocslam.geometry import make_T, rot_z, so3_exp
from eurocslam.io.ply import read_ply, write_ply
from eurocslam.io.slam_topics import groundtruth_alignment, yaw_between


def test_ply_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(100, 3))
    seg = rng.integers(0, 3, 100)
    rgb = rng.integers(0, 256, (100, 3))
    p = tmp_path / "map.ply"
    write_ply(p, xyz, rgb=rgb, segment=seg)
    back = read_ply(p)
    np.testing.assert_allclose(back["x"], xyz[:, 0], rtol=1e-6)
    np.testing.assert_array_equal(back["segment"], seg)
    np.testing.assert_array_equal(back["green"], rgb[:, 1])
    assert p.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    write_ply(tmp_path / "empty.ply", np.zeros((0, 3)))
    assert read_ply(tmp_path / "empty.ply")["x"].size == 0


def test_ply_refuses_nan(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="non-finite"):
        write_ply(tmp_path / "bad.ply", np.array([[0.0, np.nan, 1.0]]))
    assert not (tmp_path / "bad.ply").exists()


def test_groundtruth_overlay_matches_position_and_yaw_only() -> None:
    # estimate = ground truth seen from a frame rotated by 0.7 rad of yaw and shifted
    R_gt = so3_exp(np.array([0.3, -0.2, 1.1]))
    T_gt = make_T(R_gt, np.array([1.0, 2.0, 0.5]))
    T_world_gtworld_true = make_T(rot_z(0.7), np.array([-3.0, 0.2, 1.0]))
    T_est = T_world_gtworld_true @ T_gt
    assert yaw_between(T_est[:3, :3], R_gt) == pytest.approx(0.7)
    T = groundtruth_alignment(T_est, T_gt)
    np.testing.assert_allclose(T, T_world_gtworld_true, atol=1e-9)
    # a tilt between the two is not absorbed (gravity is shared): only yaw is used
    T_tilted = make_T(so3_exp(np.array([0.05, 0.0, 0.0])) @ T_est[:3, :3], T_est[:3, 3])
    T2 = groundtruth_alignment(T_tilted, T_gt)
    np.testing.assert_allclose(T2[:3, :3] @ [0, 0, 1], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose((T2 @ T_gt)[:3, 3], T_est[:3, 3], atol=1e-12)
    # visual-only (no gravity in either frame: KITTI's world is its first camera, y down): the
    # whole first pose places the ground truth
    T3 = groundtruth_alignment(T_tilted, T_gt, yaw_only=False)
    np.testing.assert_allclose(T3 @ T_gt, T_tilted, atol=1e-12)


def test_left_out_frames_write_no_stats(mh01_first5: Path) -> None:
    """/slam/stats for every frame but those left out by `frontend.track_every`: a frame with no
    frontend result that was not left out (before the init, lost) still gets its (zero) counts."""
    from eurocslam.dataset import open_sequence
    from eurocslam.io.sensor_streams import SensorStreams
    from eurocslam.io.slam_topics import SlamMcapWriter
    from eurocslam.pipeline.records import FrameOutput, PipelineState

    seq = open_sequence(mh01_first5)
    topics: list[str] = []

    class ListSink:
        def write(self, topic: str, msgtype: str, log_time_ns: int, msg: bytes) -> None:
            topics.append(topic)

        def close(self) -> None:
            pass

    w = SlamMcapWriter(ListSink(), SensorStreams(seq), seq.groundtruth)
    init, tracking, lost = PipelineState.INIT, PipelineState.TRACKING, PipelineState.LOST
    frames = list(seq.frames())[:4]
    T = np.eye(4)
    outs = [
        FrameOutput(frames[0].t_ns, init, None, 0, False, None, None),
        FrameOutput(frames[1].t_ns, init, T, 0, False, None, None, left_out=True),
        FrameOutput(frames[2].t_ns, tracking, T, 0, False, None, None, left_out=True),
        FrameOutput(frames[3].t_ns, lost, None, 0, False, None, None),
    ]
    for frame, out in zip(frames, outs, strict=True):
        w.on_frame(frame, out)
    assert topics.count("/slam/state") == 4 and topics.count("/slam/stats") == 2
