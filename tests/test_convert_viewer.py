"""Look at a converted file as a user would: Foxglove Studio 1.48 in headless Chromium
(../shared/tools/foxglove-viewer/view_mcap.sh) with layouts/convert-1.48.json. Both camera images
and the IMU plot must render and the viewer must report no problem. Slow (about 30 s)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from eurocslam.convert import ConvertOptions, convert
from eurocslam.dataset import open_sequence

REPO = Path(__file__).resolve().parents[1]
VIEWER = Path(
    os.environ.get(
        "EUROCSLAM_FOXGLOVE_VIEWER", REPO.parent / "shared/tools/foxglove-viewer/view_mcap.sh"
    )
)
LAYOUT = REPO / "layouts" / "convert-1.48.json"


@pytest.mark.slow
def test_foxglove_renders_converted_v101(v101_micro: Path, tmp_path: Path) -> None:
    if not VIEWER.exists():
        pytest.skip(f"viewer tool not available ({VIEWER})")
    if (
        shutil.which("node") is None
        or not Path(os.environ.get("CHROMIUM", "/usr/bin/chromium")).exists()
    ):
        pytest.skip("node or chromium not available")
    out = tmp_path / "v101.mcap"
    convert(open_sequence(v101_micro), out, ConvertOptions(end=4.7, progress=False))
    shots = tmp_path / "shots"
    r = subprocess.run(
        [str(VIEWER), str(out), str(LAYOUT), str(shots)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    log = (shots / "console.log").read_text()
    assert "No problems found" in log
    for panel in ("ImageViewPanel_cam0", "ImageViewPanel_cam1", "Plot_imu"):
        png = shots / f"panel_{panel}.png"
        assert png.exists() and png.stat().st_size > 10_000, f"{panel} did not render"
    # an image panel that shows a picture is far from uniform; an empty one is flat grey
    import cv2

    for panel in ("ImageViewPanel_cam0", "ImageViewPanel_cam1"):
        img = cv2.imread(str(shots / f"panel_{panel}.png"), cv2.IMREAD_GRAYSCALE)
        assert img is not None and float(img.std()) > 20.0, f"{panel} looks empty"
    # the plot draws coloured series (an empty plot is grey/white only)
    plot = cv2.imread(str(shots / "panel_Plot_imu.png"))
    hsv = cv2.cvtColor(plot, cv2.COLOR_BGR2HSV)
    assert int(((hsv[..., 1] > 120) & (hsv[..., 2] > 80)).sum()) > 2000, "IMU plot has no series"


ANNOTATION_LAYOUT = {
    "configById": {
        "ImageViewPanel!img": {
            "cameraTopic": "/cam0/image_raw",
            "enabledMarkerTopics": ["/cam0/features"],
            "synchronize": False,
            "transformMarkers": False,
            "mode": "fit",
        },
        "Plot!p": {
            "paths": [
                {"value": "/slam/bias.data[0]", "enabled": True, "timestampMethod": "receiveTime"},
                {"value": "/slam/n.data", "enabled": True, "timestampMethod": "receiveTime"},
            ],
            "showLegend": True,
            "isSynced": True,
            "xAxisVal": "timestamp",
        },
        "StateTransitions!s": {
            "paths": [{"value": "/slam/state.data", "timestampMethod": "receiveTime"}],
            "isSynced": True,
        },
    },
    "globalVariables": {},
    "userNodes": {},
    "playbackConfig": {"speed": 1},
    "layout": {
        "first": "ImageViewPanel!img",
        "second": {"first": "Plot!p", "second": "StateTransitions!s", "direction": "column"},
        "direction": "row",
    },
}


@pytest.mark.slow
def test_foxglove_renders_image_markers_numbers_and_state(v101_micro: Path, tmp_path: Path) -> None:
    """The builders `run` uses for feature overlays (ImageMarker), plot-friendly numbers
    (Float64MultiArray `.data[i]`, Float64) and tracking state (String) render in 1.48."""
    import json

    import cv2
    import numpy as np

    from eurocslam.io import ros2
    from eurocslam.io.mcap_writer import McapSink

    if not VIEWER.exists() or shutil.which("node") is None:
        pytest.skip("viewer tool or node not available")
    png = sorted((v101_micro / "mav0" / "cam0" / "data").glob("*.png"))[0]
    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    t0 = int(png.stem)
    out = tmp_path / "ann.mcap"
    with McapSink(out) as sink:
        for k in range(20):
            t = t0 + k * 50_000_000
            sink.write("/cam0/image_raw", ros2.IMAGE, t, ros2.image(t, "cam0", img))
            uv = np.array([[100 + 20 * j, 100 + 10 * j] for j in range(25)], float)
            cols = np.tile([[1.0, 0.0, 0.0, 1.0]], (25, 1))
            sink.write(
                "/cam0/features",
                ros2.IMAGE_MARKER,
                t,
                ros2.image_marker(t, "cam0", uv, scale=6, outline_colors=cols),
            )
            sink.write(
                "/slam/bias",
                ros2.FLOAT64_MULTI_ARRAY,
                t,
                ros2.float64_multi_array([np.sin(k / 3), 0.0], ["bgx", "bgy"]),
            )
            sink.write("/slam/n", ros2.FLOAT64, t, ros2.float64(float(k % 7)))
            sink.write("/slam/state", ros2.STRING, t, ros2.string("OK" if k % 5 else "LOST"))
    layout = tmp_path / "layout.json"
    layout.write_text(json.dumps(ANNOTATION_LAYOUT))
    shots = tmp_path / "shots"
    r = subprocess.run(
        [str(VIEWER), str(out), str(layout), str(shots)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
        env=dict(os.environ, SEEK="none"),
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "No problems found" in (shots / "console.log").read_text()
    # red feature dots drawn over the grey image
    im = cv2.imread(str(shots / "panel_ImageViewPanel_img.png"))
    red = (im[..., 2] > 200) & (im[..., 1] < 80) & (im[..., 0] < 80)
    assert int(red.sum()) > 200, "ImageMarker points not drawn"
    for panel in ("Plot_p", "StateTransitions_s"):
        hsv = cv2.cvtColor(cv2.imread(str(shots / f"panel_{panel}.png")), cv2.COLOR_BGR2HSV)
        assert int(((hsv[..., 1] > 120) & (hsv[..., 2] > 80)).sum()) > 500, f"{panel} empty"
