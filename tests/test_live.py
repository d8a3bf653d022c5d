"""Live view: the foxglove-sdk server behind `LiveSink`, seen by a Foxglove-protocol client.

Every server binds to 127.0.0.1 on a free port; every wait is bounded."""

from __future__ import annotations

import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from eurocslam.dataset.calib import default_rig
from eurocslam.errors import DatasetError, OutputError
from eurocslam.io import drone, ros2, ros2_calib
from eurocslam.io.live import LiveSink
from eurocslam.io.mcap_writer import McapSink
from eurocslam.io.pacing import PacingClock
from eurocslam.io.playback import advertise_mcap, play_mcap, read_mcap_info
from live_client import playback_control, run_session

T0 = 1_403_715_273_262_142_976
N_FRAMES = 20  # 20 Hz -> 1 s of data
MAIN_TOPICS = {
    "/tf_static",
    "/tf",
    "/cam0/image_raw",
    "/cam0/camera_info",
    "/imu0",
    "/slam/pose",
    "/slam/path",
    "/slam/landmarks",
    "/slam/drone",
    "/slam/stats",
}


def _img(k: int) -> np.ndarray:
    rng = np.random.default_rng(k)
    return rng.integers(0, 255, size=(48, 64), dtype=np.uint8)


def _T_world_body(k: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [0.05 * k, 0.01 * k, 1.0]
    return T


def _write_run_like(sink, n: int = N_FRAMES) -> None:  # type: ignore[no-untyped-def]
    """The main topics of a run, built with the project's message builders, in log-time order."""
    rig = default_rig()
    info0, _ = ros2_calib.stereo_camera_infos(rig)
    gcov, acov = ros2_calib.imu_covariances(rig.imu)
    sink.write(
        "/tf_static",
        ros2.TF_MESSAGE,
        T0,
        ros2.tf_message(
            [
                ros2.Transform(T0, "body", "cam0", rig.cam0.T_body_cam),
                ros2.Transform(T0, "body", "cam1", rig.cam1.T_body_cam),
            ]
        ),
    )
    stamps: list[int] = []
    for k in range(n):
        t = T0 + k * 50_000_000
        T = _T_world_body(k)
        stamps.append(t)
        sink.write(
            "/tf", ros2.TF_MESSAGE, t, ros2.tf_message([ros2.Transform(t, "world", "body", T)])
        )
        sink.write("/cam0/image_raw", ros2.IMAGE, t, ros2.image(t, "cam0", _img(k)))
        sink.write(
            "/cam0/camera_info", ros2.CAMERA_INFO, t, ros2_calib.camera_info(t, "cam0", info0)
        )
        sink.write("/slam/pose", ros2.POSE_STAMPED, t, ros2.pose_stamped(t, "world", T))
        sink.write(
            "/slam/path",
            ros2.PATH,
            t,
            ros2.path(t, "world", stamps, np.stack([_T_world_body(i) for i in range(k + 1)])),
        )
        pts = np.column_stack([np.arange(k + 3.0), np.ones(k + 3), np.zeros(k + 3)])
        sink.write("/slam/landmarks", ros2.POINT_CLOUD2, t, ros2.point_cloud2(t, "world", pts))
        sink.write("/slam/drone", drone.MSGTYPE, t, drone.drone_markers("body", t))
        sink.write(
            "/slam/stats",
            ros2.FLOAT64_MULTI_ARRAY,
            t,
            ros2.float64_multi_array([k, 100 + k], ["frame", "features"]),
        )
        for j in range(10):  # 200 Hz IMU up to the next frame
            ti = t + j * 5_000_000
            sink.write(
                "/imu0",
                ros2.IMU,
                ti,
                ros2.imu(ti, "imu0", [0.0, 0.01 * j, 0.0], [9.81, 0.0, 0.0], gcov, acov),
            )


@pytest.fixture(scope="module")
def run_mcap(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("live") / "run.mcap"
    with McapSink(path, compression="none") as sink:
        _write_run_like(sink)
    return path


def _complete(got) -> bool:  # type: ignore[no-untyped-def]
    return len(got.messages.get("/imu0", [])) >= 10 * N_FRAMES


def _check_main_topics(got) -> None:  # type: ignore[no-untyped-def]
    assert set(got.messages) >= MAIN_TOPICS, sorted(MAIN_TOPICS - set(got.messages))
    imgs = got.decoded("/cam0/image_raw")
    assert len(imgs) == N_FRAMES
    for k, im in enumerate(imgs):
        assert (im.height, im.width, im.encoding) == (48, 64, "mono8")
        assert bytes(im.data) == _img(k).tobytes()
    poses = got.decoded("/slam/pose")
    assert [p.pose.position.x for p in poses] == pytest.approx([0.05 * k for k in range(N_FRAMES)])
    assert poses[0].header.frame_id == "world"
    tf = got.decoded("/tf")[-1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("world", "body")
    static = got.decoded("/tf_static")[0].transforms
    assert {s.child_frame_id for s in static} == {"cam0", "cam1"}
    assert len(got.decoded("/slam/path")[-1].poses) == N_FRAMES
    cloud = got.decoded("/slam/landmarks")[-1]
    assert cloud.width == N_FRAMES + 2
    imu = got.decoded("/imu0")
    assert len(imu) == 10 * N_FRAMES and imu[0].linear_acceleration.x == pytest.approx(9.81)
    assert imu[0].orientation_covariance[0] == -1
    markers = got.decoded("/slam/drone")[-1].markers
    assert {m.header.frame_id for m in markers} == {"body"} and all(m.frame_locked for m in markers)
    stats = got.decoded("/slam/stats")[-1]
    assert list(stats.data) == [N_FRAMES - 1, 100 + N_FRAMES - 1]
    info = got.decoded("/cam0/camera_info")[0]
    assert info.k[0] == pytest.approx(default_rig().cam0.K[0, 0])
    # log times are the data times, in order per topic
    for topic, msgs in got.messages.items():
        if topic != "/tf_static":  # latched: re-sent on subscribe
            times = [t for t, _ in msgs]
            assert times == sorted(times), topic


# ---- pacing ---------------------------------------------------------------------------------
def test_pacing_clock_follows_rate_and_as_fast_as_possible() -> None:
    clock = PacingClock(4.0)
    t = time.monotonic()
    for k in range(9):  # 0.4 s of data at 4x -> 0.1 s
        assert clock.wait(T0 + k * 50_000_000)
    assert 0.08 < time.monotonic() - t < 0.6
    fast = PacingClock(0)
    t = time.monotonic()
    for k in range(1000):
        fast.wait(T0 + k * 1_000_000_000)
    assert time.monotonic() - t < 0.5
    assert fast.rate is None


def test_pacing_clock_pause_resume_and_stop() -> None:
    clock = PacingClock(None)
    clock.pause()
    done = threading.Event()

    def producer() -> None:
        clock.wait(T0)
        done.set()

    th = threading.Thread(target=producer, daemon=True)
    th.start()
    assert not done.wait(0.3)  # paused: blocked
    clock.resume()
    assert done.wait(2.0)
    clock.stop()
    assert clock.wait(T0 + 1) is False
    th.join(2.0)


def test_pacing_clock_does_not_burst_after_falling_behind() -> None:
    clock = PacingClock(1.0)
    clock.wait(T0)
    time.sleep(0.7)  # the producer was slow: 0.7 s behind a 0.05 s data step
    clock.wait(T0 + 50_000_000)
    t = time.monotonic()
    clock.wait(T0 + 100_000_000)  # re-anchored: this one waits ~0.05 s, not 0
    assert time.monotonic() - t > 0.03


def test_pacing_clock_rejects_bad_rates() -> None:
    with pytest.raises(ValueError):
        PacingClock(-1.0)
    with pytest.raises(ValueError):
        PacingClock(math.nan)


# ---- LiveSink in process --------------------------------------------------------------------
@pytest.mark.parametrize("subprotocol", ["foxglove.websocket.v1", "foxglove.sdk.v1"])
def test_live_sink_streams_every_main_topic(subprotocol: str) -> None:
    sink = LiveSink(port=0, rate=None)
    try:
        assert re.fullmatch(r"ws://localhost:\d+", sink.url)
        for topic, msgtype in [
            ("/tf_static", ros2.TF_MESSAGE),
            ("/tf", ros2.TF_MESSAGE),
            ("/cam0/image_raw", ros2.IMAGE),
            ("/cam0/camera_info", ros2.CAMERA_INFO),
            ("/imu0", ros2.IMU),
            ("/slam/pose", ros2.POSE_STAMPED),
            ("/slam/path", ros2.PATH),
            ("/slam/landmarks", ros2.POINT_CLOUD2),
            ("/slam/drone", drone.MSGTYPE),
            ("/slam/stats", ros2.FLOAT64_MULTI_ARRAY),
        ]:
            sink.advertise(topic, msgtype)

        def produce() -> None:
            assert sink.wait_for_client(10.0)
            time.sleep(0.3)  # let the client subscribe to every advertised channel
            _write_run_like(sink)

        th = threading.Thread(target=produce, daemon=True)
        th.start()
        got = run_session(
            sink.url,
            subprotocol=subprotocol,
            timeout=20,
            until=_complete,
        )
        th.join(10)
        assert got.subprotocol == subprotocol
        assert "time" in got.server_info["capabilities"]
        for c in got.channels.values():
            assert (c["encoding"], c["schemaEncoding"]) == ("cdr", "ros2msg")
            assert c["schema"].split("\n", 1)[0]  # root definition first
        _check_main_topics(got)
        assert got.times and got.times[-1] >= T0  # the viewer's clock follows the data time
        assert sink.stats.messages == 1 + N_FRAMES * (10 + 8)  # tf_static; per frame: 10 IMU + 8
    finally:
        sink.close()


def test_latched_tf_static_reaches_a_late_viewer() -> None:
    sink = LiveSink(port=0, rate=None)
    try:
        sink.write(
            "/tf_static",
            ros2.TF_MESSAGE,
            T0,
            ros2.tf_message([ros2.Transform(T0, "body", "cam0", np.eye(4))]),
        )
        sink.write("/slam/pose", ros2.POSE_STAMPED, T0, ros2.pose_stamped(T0, "world", np.eye(4)))
        # the viewer connects after both were sent: only the latched one comes again
        got = run_session(
            sink.url, timeout=5, idle_timeout=1.5, until=lambda g: "/tf_static" in g.messages
        )
        assert got.decoded("/tf_static")[0].transforms[0].child_frame_id == "cam0"
        assert "/slam/pose" not in got.messages
    finally:
        sink.close()


def test_viewer_disconnect_is_clean_and_a_new_viewer_can_connect() -> None:
    sink = LiveSink(port=0, rate=None)
    try:
        sink.advertise("/slam/pose", ros2.POSE_STAMPED)
        stop = threading.Event()

        def produce() -> None:
            k = 0
            while not stop.is_set():
                t = T0 + k * 50_000_000
                sink.write(
                    "/slam/pose",
                    ros2.POSE_STAMPED,
                    t,
                    ros2.pose_stamped(t, "world", _T_world_body(k)),
                )
                k += 1
                time.sleep(0.01)

        th = threading.Thread(target=produce, daemon=True)
        th.start()
        for _ in range(2):  # connect, receive, disconnect - twice
            got = run_session(
                sink.url, timeout=10, until=lambda g: len(g.messages.get("/slam/pose", [])) >= 5
            )
            assert len(got.messages["/slam/pose"]) >= 5
            assert sink.wait_all_disconnected(5.0)
            assert sink.n_clients == 0
        stop.set()
        th.join(5)
        assert not th.is_alive()  # the producer never blocked on a gone viewer
    finally:
        sink.close()


def test_port_in_use_is_a_clear_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(OutputError, match=rf"127\.0\.0\.1:{port}.*--port"):
            LiveSink(port=port)


def test_write_after_close_and_type_change_are_errors() -> None:
    sink = LiveSink(port=0, rate=None)
    sink.write("/x", ros2.FLOAT64, T0, ros2.float64(1.0))
    with pytest.raises(OutputError, match="/x"):
        sink.write("/x", ros2.STRING, T0, ros2.string("a"))
    sink.close()
    sink.close()  # idempotent
    with pytest.raises(OutputError, match="after close"):
        sink.write("/x", ros2.FLOAT64, T0, ros2.float64(1.0))


# ---- playing a recorded MCAP ----------------------------------------------------------------
def test_read_mcap_info(run_mcap: Path, tmp_path: Path) -> None:
    info = read_mcap_info(run_mcap)
    assert info.start_ns == T0
    assert info.end_ns == T0 + (N_FRAMES - 1) * 50_000_000 + 9 * 5_000_000
    assert {c.topic for c in info.channels.values()} == MAIN_TOPICS
    latched = {c.topic for c in info.channels.values() if c.latched}
    assert latched == {"/tf_static"}  # from the file's transient-local QoS
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap at all")
    with pytest.raises(DatasetError, match=r"bad\.mcap"):
        read_mcap_info(bad)
    with pytest.raises(DatasetError, match="no such file"):
        read_mcap_info(tmp_path / "missing.mcap")


def test_play_mcap_serves_the_file_paced(run_mcap: Path) -> None:
    info = read_mcap_info(run_mcap)
    sink = LiveSink(port=0, rate=2.0, playback_range_ns=(info.start_ns, info.end_ns))
    result: dict = {}
    try:
        advertise_mcap(info, sink)

        def play() -> None:
            assert sink.wait_for_client(10.0)
            time.sleep(0.3)
            t = time.monotonic()
            result["res"] = play_mcap(info, sink)
            result["wall"] = time.monotonic() - t

        th = threading.Thread(target=play, daemon=True)
        th.start()
        got = run_session(sink.url, timeout=20, until=_complete)
        th.join(10)
        assert "playbackControl" in got.server_info["capabilities"]
        _check_main_topics(got)
        # a viewer on the older protocol name never gets frames it does not know (playback
        # state: Foxglove Studio 1.x would take it for an error and reconnect)
        assert got.subprotocol == "foxglove.websocket.v1" and not got.playback_states
        res = result["res"]
        assert res.finished and res.messages == info.message_count
        span = (info.end_ns - info.start_ns) / 1e9
        assert span / 2.0 * 0.8 < result["wall"] < span / 2.0 + 3.0  # paced at 2x
    finally:
        sink.close()


def test_play_mcap_pause_and_seek_from_the_viewer(run_mcap: Path) -> None:
    info = read_mcap_info(run_mcap)
    sink = LiveSink(port=0, rate=1.0, playback_range_ns=(info.start_ns, info.end_ns))
    result: dict = {}
    seek_to = T0 + 15 * 50_000_000
    try:
        advertise_mcap(info, sink)
        th = threading.Thread(
            target=lambda: (
                sink.wait_for_client(10.0),
                time.sleep(0.3),
                result.setdefault("res", play_mcap(info, sink)),
            ),
            daemon=True,
        )
        th.start()
        sent: list[str] = []

        def control(got, ws):  # type: ignore[no-untyped-def]
            n = len(got.messages.get("/slam/pose", []))
            now = time.monotonic()
            if n >= 3 and not sent:
                sent.append("pause")
                result["paused_at"] = now
                return playback_control(1, 1.0, None, "pause-1")
            if sent == ["pause"] and "n1" not in result and now - result["paused_at"] > 0.4:
                result["n1"] = n  # messages in flight when the pause arrived are in by now
            if sent == ["pause"] and now - result["paused_at"] > 1.0:
                result["n2"] = n
                sent.append("seek")
                return playback_control(0, 4.0, seek_to, "seek-1")
            return None

        got = run_session(
            sink.url,
            subprotocol="foxglove.sdk.v1",  # playback control is part of the newer protocol
            timeout=20,
            on_message=control,
            idle_timeout=3,
            until=lambda g: bool(g.playback_states) and g.playback_states[-1][1] == 3,
        )  # Ended
        th.join(10)
        assert sent == ["pause", "seek"]
        assert result["n2"] == result["n1"]  # nothing played while paused
        assert result["n2"] < 15  # so the seek to frame 15 is a jump forward
        res = result["res"]
        assert res.finished and res.seeks == 1
        pose_times = [t for t, _ in got.messages["/slam/pose"]]
        assert pose_times.count(seek_to) == 1
        i = pose_times.index(seek_to)
        assert i == result["n2"]  # the first pose after the seek is the seek target
        assert pose_times[i - 1] < seek_to - 50_000_000  # the frames in between were skipped
        assert pose_times[-1] == T0 + (N_FRAMES - 1) * 50_000_000
        assert sink.clock.rate == 4.0
    finally:
        sink.close()


# ---- the command, as a user runs it ---------------------------------------------------------
def _sigint_default() -> None:
    # a child inherits an ignored SIGINT (pytest started in the background by a
    # non-interactive shell), and Python then never raises KeyboardInterrupt: the Ctrl-C
    # test would wait forever. Restore the default so Python installs its handler.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start_play(mcap: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "eurocslam.cli", "play", str(mcap), "--live", "--port", "0", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        preexec_fn=_sigint_default if os.name == "posix" else None,
    )
    deadline = time.monotonic() + 30
    lines = []
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"on (ws://localhost:\d+)", line)
        if m:
            return proc, m.group(1)
    proc.kill()
    raise AssertionError("play did not print its URL: " + "".join(lines))


def test_play_command_stops_cleanly_on_ctrl_c(run_mcap: Path) -> None:
    proc, url = _start_play(run_mcap, "--rate", "0.2", "--keep-serving", "--no-wait")
    try:
        got = run_session(
            url, timeout=15, until=lambda g: len(g.messages.get("/slam/pose", [])) >= 2
        )
        assert len(got.messages["/slam/pose"]) >= 2
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=15)
        assert proc.returncode == 0, err
        assert "stopped (Ctrl-C)" in err
        assert "Traceback" not in err
    finally:
        if proc.poll() is None:
            proc.kill()


def test_play_command_exits_when_the_viewer_disconnects(run_mcap: Path) -> None:
    proc, url = _start_play(run_mcap, "--rate", "0.2", "--no-wait")
    try:
        got = run_session(
            url, timeout=15, until=lambda g: len(g.messages.get("/slam/pose", [])) >= 2
        )
        assert len(got.messages["/slam/pose"]) >= 2
        _, err = proc.communicate(timeout=20)  # grace period 3 s, then a clean exit
        assert proc.returncode == 0, err
        assert "the viewer disconnected" in err
        assert "Traceback" not in err
    finally:
        if proc.poll() is None:
            proc.kill()


def test_play_command_bad_input_is_one_line(tmp_path: Path) -> None:
    from eurocslam.cli import main

    bad = tmp_path / "x.mcap"
    bad.write_text("nope")
    assert main(["play", str(bad), "--live", "--port", "0"]) == 2
    assert main(["play", str(tmp_path / "none.mcap"), "--live", "--port", "0"]) == 2
    assert main(["play", str(bad)]) == 2  # --live missing
