"""`eurocslam run SEQ --live` end to end (slow): SLAM on a tiny synthetic sequence streams every
topic over the Foxglove WebSocket protocol while it runs, still writes run.mcap, keeps serving
the final state until the viewer disconnects, then exits 0. Loopback only, bounded waits."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from live_client import run_session

pytestmark = pytest.mark.slow

MAIN = {
    "/tf_static",
    "/tf",
    "/imu0",
    "/cam0/image_raw",
    "/cam1/image_raw",
    "/cam0/camera_info",
    "/slam/pose",
    "/slam/path",
    "/slam/landmarks",
    "/slam/drone",
    "/slam/features",
    "/slam/stats",
    "/groundtruth/drone",
    "/slam/position_error",
}


def test_run_live_streams_while_processing_and_writes_the_mcap(tmp_path: Path) -> None:
    from eurocslam.synth import SynthSpec, synthesize

    seq = synthesize(SynthSpec.tiny(seed=2), tmp_path / "seq")
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "eurocslam.cli",
            "run",
            str(seq),
            "-o",
            str(out),
            "--live",
            "--port",
            "0",
            "--rate",
            "0",
            "--no-progress",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert proc.stderr is not None
        url = None
        deadline = time.monotonic() + 120
        while url is None and time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
            m = re.search(r"live view on (ws://localhost:\d+)", line)
            if m:
                url = m.group(1)
                layout = re.search(r"Import from file > (\S+layout\.json) \(this run's", line)
        assert url, "run --live did not print its URL"
        # this run's layout, written before the run: its panels, framed on the ground truth
        assert layout, line
        lay = json.loads(Path(layout.group(1)).read_text())
        assert lay["configById"]["3D!map"]["followMode"] == "follow-none"
        assert (Path(layout.group(1)).parent / "layout-1.48.json").is_file()
        # stay until /slam/path_final (written at the very end) has come, and 3 s longer (the
        # server keeps the final state for the viewer), then disconnect: run exits
        seen: list[float] = []
        alive: list[bool] = []

        def done(g) -> bool:  # type: ignore[no-untyped-def]
            if "/slam/path_final" in g.messages and not seen:
                seen.append(time.monotonic())
            if seen and time.monotonic() - seen[0] > 3.0:
                alive.append(proc.poll() is None)
                return True
            return False

        got = run_session(url, timeout=300, idle_timeout=60, until=done)
        assert alive == [True]  # the run was over and still served the final state
        _, stderr = proc.communicate(timeout=60)
        assert proc.returncode == 0, stderr[-3000:]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert set(got.messages) >= MAIN, sorted(MAIN - set(got.messages))
    poses = got.decoded("/slam/pose")
    assert len(poses) >= 10 and poses[-1].header.frame_id == "world"
    assert got.decoded("/slam/drone")[-1].markers[0].header.frame_id == "body"
    assert got.decoded("/groundtruth/drone")[-1].markers[0].header.frame_id == "gt_body"
    err = got.decoded("/slam/position_error")[-1].data
    assert err[3] < 0.5  # a tiny synthetic flight: the estimate stays close to the truth
    assert len(got.decoded("/slam/landmarks")[-1].data) > 0
    assert "keeps the final state until the viewer disconnects" in stderr
    assert (out / "run.mcap").is_file() and not (out / "run.mcap.partial").exists()
    # what went live is what went into the file
    from eurocslam.io.playback import read_mcap_info

    info = read_mcap_info(out / "run.mcap")
    file_topics = {c.topic for c in info.channels.values()}
    assert set(got.messages) <= file_topics
