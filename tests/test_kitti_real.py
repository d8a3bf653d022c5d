"""The real KITTI excerpt (../shared/data/kitti_excerpt, skipped where absent): the reader, doctor,
convert, and the same trajectory from its KITTI layout and from a stereo-only ASL copy."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from eurocslam.camera import rectify_stereo
from eurocslam.config import VISUAL_ONLY, RunConfig
from eurocslam.convert import convert
from eurocslam.dataset import AslSequence, KittiSequence, open_sequence
from eurocslam.dataset.doctor.kitti_checks import diagnose_kitti
from eurocslam.pipeline.records import FrameOutput
from eurocslam.pipeline.slam import SlamPipeline
from kitti_helpers import kitti_to_asl


@pytest.fixture(scope="module")
def k2(kitti_excerpt: Path) -> Path:
    return kitti_excerpt / "sequences" / "k2"


def test_reader_on_the_excerpt(k2: Path) -> None:
    s = open_sequence(k2)
    assert isinstance(s, KittiSequence)
    assert len(s.frame_times) == 51 and s.rig.imu is None and len(s.imu) == 0
    # times.txt holds KITTI's own stamps (9.64 Hz, not the nominal 10): the frames carry them,
    # and the rate is theirs (the reader takes the median interval; KITTI's jitter by ~0.1 %)
    stamps_s = np.array([float(x) for x in (k2 / "times.txt").read_text().split()])
    assert len(stamps_s) == 51 and stamps_s[-1] == pytest.approx(5.185269, abs=1e-6)
    assert np.abs(s.frame_times - s.frame_times[0] - stamps_s * 1e9).max() <= 1
    c0 = s.rig.cam0
    assert (c0.width, c0.height) == (1241, 376)
    assert c0.rate_hz == pytest.approx(50 / 5.185269, rel=1e-3)
    assert (c0.fx, c0.fy, c0.cx, c0.cy) == (718.856, 718.856, 607.1928, 185.2157)
    assert s.rig.baseline == pytest.approx(0.537, abs=5e-4)
    assert s.rig.baseline == 386.1448 / 718.856
    gt = s.groundtruth
    assert gt is not None and len(gt) == 51 and np.allclose(gt.p[0], 0.0, atol=1e-9)
    path = float(np.linalg.norm(np.diff(gt.p, axis=0), axis=1).sum())
    assert path == pytest.approx(51.8, abs=0.1)
    frames = list(s.frames())
    assert len(frames) == 51 and not s.skips.total
    assert frames[0].left is not None and frames[0].left.shape == (376, 1241)
    assert rectify_stereo(s.rig).passthrough


def test_doctor_is_clean_on_the_excerpt(k2: Path) -> None:
    r = diagnose_kitti(k2)
    assert r.exit_code == 0, [f.text() for f in r.findings]
    assert r.stereo_pairs == 51 and r.image_headers_read == 102


def test_convert_the_excerpt(k2: Path, tmp_path: Path) -> None:
    out = tmp_path / "k2.mcap"
    res = convert(open_sequence(k2), out)
    assert res.frames == 51
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None
        counts = {
            summary.channels[cid].topic: n
            for cid, n in summary.statistics.channel_message_counts.items()  # type: ignore[union-attr]
        }
    assert counts["/cam0/image_raw"] == counts["/cam1/image_raw"] == 51
    assert counts["/groundtruth/pose"] == 51 and counts["/tf_static"] == 1
    assert "/imu0" not in counts
    back = open_sequence(out)
    assert len(back.frame_times) == 51 and back.rig.baseline == 386.1448 / 718.856


def test_asl_copy_gives_the_same_trajectory(k2: Path, tmp_path: Path) -> None:
    """The excerpt as a stereo-only ASL folder (no imu0/) gives the same trajectory as its KITTI
    layout: the same rig, the same images, the same times."""
    asl = AslSequence(kitti_to_asl(k2, tmp_path / "k2_asl"))
    kitti = KittiSequence(k2)
    assert asl.rig.imu is None and len(asl.imu) == 0
    for a, b in ((asl.rig.cam0, kitti.rig.cam0), (asl.rig.cam1, kitti.rig.cam1)):
        assert (a.fx, a.fy, a.cx, a.cy, a.resolution) == (b.fx, b.fy, b.cx, b.cy, b.resolution)
        assert np.array_equal(a.T_body_cam, b.T_body_cam) and a.rate_hz == b.rate_hz
    assert asl.frame_times.tolist() == kitti.frame_times.tolist()
    cfg = dataclasses.replace(RunConfig(), mode=VISUAL_ONLY)
    steps: dict[str, list[tuple[object, ...]]] = {"asl": [], "kitti": []}

    def record(key: str) -> Callable[[FrameOutput], None]:
        def on(out: FrameOutput) -> None:
            fe = out.frontend
            seen = None if fe is None else (fe.n_features, fe.n_stereo, fe.n_tracked)
            uv = None if fe is None else fe.stereo_uv.tobytes()
            steps[key].append((out.t_ns, out.state, out.is_keyframe, seen, uv))

        return on

    ra = SlamPipeline(asl, cfg).run(on_progress=record("asl"))
    rk = SlamPipeline(kitti, cfg).run(on_progress=record("kitti"))
    assert ra.summary.frames == rk.summary.frames == 51
    assert steps["asl"] == steps["kitti"]  # frame by frame: states, keyframes, tracking counts
    assert ra.online.t_ns.tolist() == rk.online.t_ns.tolist()
    assert ra.final.t_ns.tolist() == rk.final.t_ns.tolist()
    for a, k in ((ra.online, rk.online), (ra.final, rk.final)):
        assert np.allclose(a.T_world_body(), k.T_world_body(), rtol=0, atol=1e-9)
    assert len(ra.summary.resets) == len(rk.summary.resets)


def test_the_excerpt_in_one_piece_within_10_cm(k2: Path) -> None:
    """Issue #21's bar on real moving imagery: one segment, no reset, a pose for every frame,
    Sim(3) ATE <= 0.10 m (the excerpt's stereo geometry and ground truth disagree in scale by
    about 5 %, so SE(3) is not the measure here). Measured: 0.04 m, scale 0.95."""
    from eurocslam.eval.align import align

    seq = KittiSequence(k2)
    res = SlamPipeline(seq, RunConfig()).run()
    s = res.summary
    assert s.mode == VISUAL_ONLY and s.segments == 1 and not s.resets
    assert s.frames_with_pose == s.frames == 51
    gt = seq.groundtruth
    idx = np.searchsorted(gt.t_ns, res.final.t_ns)
    assert np.array_equal(gt.t_ns[idx], res.final.t_ns)
    G, P = gt.p[idx], res.final.p
    a = align("sim3", G, P)
    ate = float(np.sqrt(np.mean(np.sum((G - (a.s * P @ a.R.T + a.t)) ** 2, axis=1))))
    assert ate <= 0.10, ate
