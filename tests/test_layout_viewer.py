"""The layout in a real viewer (slow): `eurocslam run` on a tiny synthetic sequence, then Foxglove
Studio 1.48 in headless Chromium (../shared/tools/foxglove-viewer) opens run.mcap with
layouts/eurocslam-1.48.json, and connects to `eurocslam play --live`. Any player problem
(schema, decoding, unreadable data) fails the test. Skipped without Node, Chromium or the tool."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_layout import LAYOUT, LAYOUT_148, RUN_FRAMES, RUN_TOPICS, referenced

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
TOOL = Path(os.environ.get("FOXGLOVE_VIEWER", REPO.parent / "shared/tools/foxglove-viewer"))
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "foxglove-viewer"


def _need_viewer() -> None:
    if not (TOOL / "view_mcap.sh").exists():
        pytest.skip(f"Foxglove viewer tool not available ({TOOL})")
    if shutil.which("node") is None:
        pytest.skip("node not installed")
    if not Path(os.environ.get("CHROMIUM", "/usr/bin/chromium")).exists():
        pytest.skip("chromium not installed (../shared/tools/foxglove-viewer/setup.sh installs it)")
    check = subprocess.run([str(TOOL / "setup.sh"), "--check"], capture_output=True)
    if check.returncode != 0:
        setup = subprocess.run(
            [str(TOOL / "setup.sh")], capture_output=True, text=True, timeout=900
        )
        if setup.returncode != 0:
            pytest.skip(f"viewer setup failed: {setup.stderr[-500:]}")


@pytest.fixture(scope="module")
def run_mcap(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from eurocslam.cli import main
    from eurocslam.synth import SynthSpec, synthesize

    base = tmp_path_factory.mktemp("viewer")
    seq = synthesize(SynthSpec.tiny(seed=1), base / "seq")
    assert main(["run", str(seq), "-o", str(base / "out"), "--no-progress"]) == 0
    return base / "out" / "run.mcap"


def test_run_writes_every_topic_and_frame_the_layout_uses(run_mcap: Path) -> None:
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    frames: set[str] = set()
    with open(run_mcap, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        types = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        for schema, _ch, msg in reader.iter_messages(topics=["/tf", "/tf_static"]):
            for tr in store.deserialize_cdr(msg.data, schema.name).transforms:
                frames |= {tr.header.frame_id, tr.child_frame_id}
    for topic, msgtype in RUN_TOPICS.items():
        assert types.get(topic) == msgtype, f"run.mcap: {topic} is {types.get(topic)}"
    assert frames >= RUN_FRAMES
    for layout in (LAYOUT, LAYOUT_148):
        topics, used_frames = referenced(json.loads(layout.read_text()))
        assert set(topics) <= set(types)
        assert used_frames <= frames


def _check_console(outdir: Path, layout: Path = LAYOUT_148) -> str:
    log = (outdir / "console.log").read_text()
    assert "[error] Player problem" not in log, log[-3000:]
    alerts = [line for line in log.splitlines() if line.startswith("[alerts]")]
    assert alerts and "No problems found" in alerts[-1], alerts
    panels = sorted(p.name for p in outdir.glob("panel_*.png"))
    assert len(panels) == len(json.loads(layout.read_text())["configById"]), panels
    return log


def test_recorded_run_in_foxglove_studio(run_mcap: Path, tmp_path: Path) -> None:
    _need_viewer()
    out = tmp_path / "shots"
    proc = subprocess.run(
        [str(TOOL / "view_mcap.sh"), str(run_mcap), str(LAYOUT_148), str(out)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    _check_console(out)


def test_live_view_in_foxglove_studio(run_mcap: Path, tmp_path: Path) -> None:
    """Studio 1.48 speaks `foxglove.websocket.v1`: this is the relay in front of foxglove-sdk."""
    _need_viewer()
    play = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "eurocslam.cli",
            "play",
            str(run_mcap),
            "--live",
            "--port",
            "0",
            "--loop",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    web = None
    try:
        assert play.stderr is not None
        url = None
        deadline = time.monotonic() + 60
        while url is None and time.monotonic() < deadline:
            m = re.search(r"on ws://localhost:(\d+)", play.stderr.readline())
            if m:
                url = f"ws://127.0.0.1:{m.group(1)}"
        assert url, "play did not print its URL"
        shutil.copy(LAYOUT_148, tmp_path / "layout.json")
        env = {**os.environ, "NODE_PATH": str(CACHE / "node_modules")}
        web = subprocess.Popen(
            ["node", str(TOOL / "serve.js"), "0", str(CACHE / "www"), str(tmp_path)],
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        assert web.stdout is not None
        base = None
        while base is None and time.monotonic() < deadline:
            m = re.search(r"http://127\.0\.0\.1:\d+", web.stdout.readline())
            if m:
                base = m.group(0)
        assert base, "serve.js did not start"
        page = f"{base}/?ds=foxglove-websocket&ds.url={url}&layoutUrl={base}/layout.json"
        out = tmp_path / "shots"
        shot = subprocess.run(
            ["node", str(TOOL / "shoot.js"), page, str(out), "5000"],
            capture_output=True,
            text=True,
            timeout=600,
            env={**env, "AFTER_LOAD_SCRIPT": str(TOOL / "after_alerts.js")},
        )
        assert shot.returncode == 0, shot.stdout[-2000:] + shot.stderr[-2000:]
        _check_console(out)
        assert play.poll() is None  # still serving: the viewer never broke the server
    finally:
        for p in (web, play):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    p.kill()


def _pixels_near(png: Path, rgb: tuple[int, int, int], tol: int = 60) -> int:
    import cv2
    import numpy as np

    im = cv2.imread(str(png))[:, :, ::-1].astype(int)
    return int((np.abs(im - np.array(rgb)).sum(axis=2) < tol).sum())


def test_visual_only_run_in_its_own_layout(kitti_excerpt: Path, tmp_path: Path) -> None:
    """The real KITTI excerpt (60 m drive, no IMU, stamps from 0 s) with the layout `run` wrote
    for it: no IMU panels, and the 3D panel framed on the drive, so that the ground-truth path
    (green) is drawn; the shipped drone-framed layout shows none of it (checked by hand: 0 green
    pixels)."""
    from eurocslam.cli import main

    _need_viewer()
    out = tmp_path / "out"
    seq = kitti_excerpt / "sequences" / "k2"
    assert main(["run", str(seq), "-o", str(out), "--no-imu", "--no-progress"]) == 0
    layout = out / "layout-1.48.json"
    shots = tmp_path / "shots"
    proc = subprocess.run(
        [str(TOOL / "view_mcap.sh"), str(out / "run.mcap"), str(layout), str(shots)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    _check_console(shots, layout)
    panels = {p.name for p in shots.glob("panel_*.png")}
    assert "panel_Plot_position.png" in panels and not any("gyro" in p for p in panels)
    three_d = shots / "panel_3D_map.png"
    assert _pixels_near(three_d, (0x26, 0xD9, 0x5A)) >= 10  # the ground-truth path
    assert _pixels_near(three_d, (0xFF, 0x7A, 0x1A)) >= 100  # the estimated path
