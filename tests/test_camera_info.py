"""The CameraInfo in run.mcap describes the rectification the run's frontend used."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from eurocslam.cli import main
from eurocslam.dataset import open_sequence
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor
from eurocslam.synth import SynthSpec, synthesize


def _camera_infos(mcap: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """R (3x3) and P (3x4) of the first CameraInfo of each camera."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    with open(mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        topics = ["/cam0/camera_info", "/cam1/camera_info"]
        for _, channel, _, msg in reader.iter_decoded_messages(topics=topics):
            if channel.topic not in out:
                out[channel.topic] = (
                    np.asarray(msg.r, dtype=np.float64).reshape(3, 3),
                    np.asarray(msg.p, dtype=np.float64).reshape(3, 4),
                )
    return out


def test_camera_info_uses_the_configured_rectify_alpha(tmp_path: Path) -> None:
    seq = synthesize(SynthSpec.tiny(seed=2), tmp_path / "tiny", workers=1)
    cfg = tmp_path / "alpha.yaml"
    cfg.write_text(yaml.safe_dump({"frontend": {"rectify_alpha": 0.5}}))
    out = tmp_path / "out"
    rc = main(["run", str(seq), "-o", str(out), "--config", str(cfg), "--no-progress"])
    assert rc == 0
    infos = _camera_infos(out / "run.mcap")
    assert set(infos) == {"/cam0/camera_info", "/cam1/camera_info"}

    rig = open_sequence(seq).rig
    used = Extractor.for_rig(rig, FrontendConfig(rectify_alpha=0.5)).rectifier
    default = Extractor.for_rig(rig, FrontendConfig()).rectifier
    for topic, R, P in (
        ("/cam0/camera_info", used.R_rect0_cam0, used.P0),
        ("/cam1/camera_info", used.R_rect1_cam1, used.P1),
    ):
        R_msg, P_msg = infos[topic]
        assert np.array_equal(R_msg, R), topic
        assert np.array_equal(P_msg, P), topic
    # alpha 0.5 is not the default rectification: the test would notice a fixed alpha
    assert not np.array_equal(infos["/cam0/camera_info"][1], default.P0)


@pytest.mark.parametrize("alpha", [0.0, 1.0])
def test_stereo_camera_infos_follow_alpha(alpha: float) -> None:
    from eurocslam.camera import rectify_stereo
    from eurocslam.dataset.calib import default_rig
    from eurocslam.io.ros2_calib import stereo_camera_infos

    rig = default_rig()
    i0, i1 = stereo_camera_infos(rig, alpha)
    rect = rectify_stereo(rig, alpha)
    assert np.array_equal(i0.P, rect.P0) and np.array_equal(i1.P, rect.P1)
    assert np.array_equal(i0.R, rect.R_rect0_cam0) and np.array_equal(i1.R, rect.R_rect1_cam1)
