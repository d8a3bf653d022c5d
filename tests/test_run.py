"""`eurocslam run` end to end on the real V1_01 micro (cropped): every output, read back."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from eurocslam.backend.types import ImuCheck
from eurocslam.cli import main
from eurocslam.config import load_config
from eurocslam.dataset import open_sequence
from eurocslam.io.ply import read_ply
from eurocslam.pipeline.summary import RunSummary
from eurocslam.run_options import RunOptions
from eurocslam.runner import run_slam
from eurocslam.synth import SynthSpec, synthesize
from eurocslam.trajectory_io import read_euroc_csv, read_tum

SLAM_TOPICS = {
    "/tf",
    "/slam/pose",
    "/slam/path",
    "/slam/landmarks",
    "/slam/features",
    "/slam/state",
    "/slam/stats",
    "/slam/position_error",
    "/groundtruth/drone",
    "/slam/imu_bias",
    "/slam/velocity",
    "/slam/drone",
    "/slam/path_final",
    "/slam/places",
}
SENSOR_TOPICS = {
    "/cam0/image_raw",
    "/cam1/image_raw",
    "/cam0/camera_info",
    "/imu0",
    "/tf_static",
    "/groundtruth/pose",
}


@pytest.fixture(scope="module")
def run_out(v101_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("run") / "out"
    rc = main(["run", str(v101_micro), "-o", str(out), "--end", "1.0", "--no-progress"])
    assert rc == 0
    return out


def test_outputs_written(run_out: Path) -> None:
    for name in (
        "run.mcap",
        "trajectory_online.tum",
        "trajectory_online.csv",
        "trajectory_final.tum",
        "trajectory_final.csv",
        "map.ply",
        "config.yaml",
        "summary.json",
        "summary.txt",
        "layout.json",
        "layout-1.48.json",
    ):
        assert (run_out / name).is_file(), name
    assert not (run_out / "run.mcap.partial").exists()
    on = read_tum(run_out / "trajectory_online.tum")
    fin = read_euroc_csv(run_out / "trajectory_final.csv")
    assert len(on) == len(fin) >= 19
    assert np.array_equal(on.t_ns, fin.t_ns)
    summary = json.loads((run_out / "summary.json").read_text())
    assert summary["frames_with_pose"] == summary["frames"] == len(on)
    assert summary["init_modes"] == ["static"]
    assert {"orb", "tracking", "backend", "output"} <= set(summary["timings"])
    cpu = summary["cpu_by_thread"]  # the run's CPU split by thread adds up to its CPU time
    assert cpu["tracking"] > 0 and len(cpu["extraction_workers"]) == 2 and cpu["reader"] > 0
    total = cpu["tracking"] + sum(cpu["extraction_workers"]) + cpu["reader"] + cpu["other"]
    assert total == pytest.approx(summary["cpu_s"], abs=0.01)
    assert summary["realtime_bounds"]["cores"] >= summary["realtime_factor"] * 0.95
    (check,) = summary["imu_check"]  # the final batch's IMU check, one per segment
    assert set(check) == {"ratio", "accel_scale", "ratio_after"}
    assert "final batch: " in (run_out / "summary.txt").read_text()
    ply = read_ply(run_out / "map.ply")
    assert ply["x"].size == summary["landmarks"] > 0
    # the resolved config (the mode decided) reloads to the same values
    resolved = dataclasses.replace(load_config(None), mode="stereo-inertial")
    assert load_config(run_out / "config.yaml") == resolved


def test_mcap_holds_sensor_streams_and_estimate(run_out: Path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts: dict[str, int] = {}
    last_t = 0
    with open(run_out / "run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, ros_msg in reader.iter_decoded_messages(log_time_order=False):
            assert message.log_time >= last_t  # written in log-time order
            last_t = message.log_time
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/slam/pose":
                assert ros_msg.header.frame_id == "world"
            if channel.topic == "/slam/stats":
                assert ros_msg.layout.dim[0].label.startswith("state,")
    assert set(counts) >= SLAM_TOPICS, set(counts)
    assert set(counts) >= SENSOR_TOPICS, set(counts)
    n = counts["/slam/pose"]
    assert counts["/cam0/image_raw"] == n and counts["/slam/state"] == n
    assert counts["/tf_static"] >= 2  # body->sensors, and world->gt_world (overlay)


def test_tracking_every_second_frame_writes_every_image(v101_micro: Path, tmp_path: Path) -> None:
    """`frontend.track_every: 2` on real images: every frame has a pose and its images in
    run.mcap; /slam/stats only for the frames tracked (plots join them); the summary says how
    many got the IMU's pose."""
    from mcap.reader import make_reader

    cfg = tmp_path / "every2.yaml"
    cfg.write_text("frontend:\n  track_every: 2\n")
    out = tmp_path / "o"
    args = ["run", str(v101_micro), "-o", str(out), "--end", "1.0", "--no-progress"]
    assert main([*args, "--config", str(cfg)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    paths = summary["track_paths"]
    n, between = summary["frames"], paths["imu_between"] + paths.get("vo_between", 0)
    assert summary["frames_with_pose"] == n >= 19 and n // 2 - 1 <= between <= n // 2
    assert "imu_between" in (out / "summary.txt").read_text()
    counts: dict[str, int] = {}
    with open(out / "run.mcap", "rb") as f:
        for _, channel, _ in make_reader(f).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts["/cam0/image_raw"] == counts["/cam1/image_raw"] == counts["/slam/pose"] == n
    assert counts["/slam/stats"] == n - between


def test_png_images_go_into_run_mcap_as_their_files(v101_micro: Path, tmp_path: Path) -> None:
    """`run --images png`: the frames SLAM decoded go into run.mcap as EuRoC's PNG files, byte
    for byte (not encoded again)."""
    from mcap.reader import make_reader

    out = tmp_path / "o"
    args = ["run", str(v101_micro), "-o", str(out), "--end", "0.5", "--no-progress"]
    assert main([*args, "--images", "png"]) == 0
    files = {e.t_ns: e.left for e in open_sequence(v101_micro).entries}
    n = 0
    with open(out / "run.mcap", "rb") as f:
        for _, _, m in make_reader(f).iter_messages(topics=["/cam0/image_raw/compressed"]):
            assert files[m.log_time].read_bytes() in m.data
            n += 1
    assert n >= 10


def test_bad_config_is_a_clean_error(
    v101_micro: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(yaml.safe_dump({"backend": {"lag_seconds": 2}}))
    rc = main(["run", str(v101_micro), "-o", str(tmp_path / "o"), "--config", str(cfg)])
    assert rc == 2
    err = capsys.readouterr().err
    assert "backend.lag_seconds" in err and "Traceback" not in err


def test_missing_sequence_is_a_clean_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["run", str(tmp_path / "nope"), "-o", str(tmp_path / "o")])
    assert rc == 2
    assert "nope" in capsys.readouterr().err


def test_summary_splits_the_cpu_time_by_thread() -> None:
    """Where the CPU went, and the real-time factor it allows: 100 s of data at 90 s of CPU on
    2 cores allows 2.22x; the tracking thread's 40 s alone, 2.5x."""
    s = RunSummary(duration_s=100.0, cpu_s=90.0, tracking_cpu_s=40.0, cores=2)
    s.worker_cpu_s, s.reader_cpu_s = [20.0, 19.0], 6.0
    assert s.other_cpu_s == pytest.approx(5.0)
    assert s.realtime_bounds() == pytest.approx((100 / 45, 2.5))
    cpu, bound = [x for x in s.lines() if x.startswith(("CPU seconds by", "at this CPU"))]
    assert cpu == (
        "CPU seconds by thread: tracking thread 40.0, extraction workers 20.0 + 19.0, "
        "frame reader 6.0, other threads 5.0"
    )
    assert bound.endswith("at most 2.22 on 2 core(s) and 2.50 for the tracking thread")
    d = s.to_dict()
    assert d["cpu_by_thread"]["extraction_workers"] == [20.0, 19.0]
    assert d["realtime_bounds"] == {"cores": 2.222, "tracking_thread": 2.5}
    # extraction inline (no workers, no reader thread): the rest is the other threads'
    inline = RunSummary(duration_s=10.0, cpu_s=9.0, tracking_cpu_s=8.0, cores=2)
    assert "CPU seconds by thread: tracking thread 8.0, other threads 1.0" in inline.lines()
    # not measured (a summary built elsewhere): no lines, nulls in the JSON
    empty = RunSummary(duration_s=1.0, cpu_s=1.0)
    assert not [x for x in empty.lines() if x.startswith("CPU seconds by")]
    assert empty.to_dict()["cpu_by_thread"]["other"] is None
    json.dumps(empty.to_dict(), allow_nan=False)


def test_summary_reports_the_imu_check() -> None:
    s = RunSummary(imu_checks=[ImuCheck(0.31), ImuCheck(4.2, 7.0, 1.2), ImuCheck(math.nan)])
    lines = [x for x in s.lines() if x.startswith("final batch")]
    assert lines[0].endswith("0.31x the stereo residuals (chi-square per redundancy)")
    assert lines[1].endswith("accelerometer covariances scaled by 7.0: 1.20x")
    assert lines[2] == "final batch: too few IMU or stereo factors to check the IMU"
    d = s.to_dict()["imu_check"]
    assert d[0] == {"ratio": 0.31, "accel_scale": 1.0, "ratio_after": None}
    assert d[2]["ratio"] is None
    json.dumps(d, allow_nan=False)


def test_the_progress_bar_says_when_the_final_batch_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """After the last frame the bar names the final batch (seconds long on a long sequence),
    rather than sitting at 100 % in silence."""
    seq = synthesize(SynthSpec.tiny(seed=2), tmp_path / "tiny")
    run_slam(open_sequence(seq), tmp_path / "out", options=RunOptions(mcap=False, progress=True))
    last = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert "100%" in last and "final batch: optimising the whole trajectory and map" in last
