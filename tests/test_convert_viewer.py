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
