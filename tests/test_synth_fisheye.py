"""`synth --rig tumvi`: a TUM-VI-like stereo fisheye rendered ray by ray through the equidistant
model (beyond 90 degrees too), written as a TUM-VI folder as distributed, and a replica's motion
re-expressed so the fisheye's cam0 flies where EuRoC's does, in the same world."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eurocslam.dataset import open_sequence
from eurocslam.dataset.asl import AslSequence
from eurocslam.dataset.calib import default_rig
from eurocslam.dataset.calib_sources import tumvi_rig
from eurocslam.geometry import inv_T
from eurocslam.synth import SynthSpec, synthesize
from eurocslam.synth import render as render_mod
from eurocslam.synth.sequence import Scene
from eurocslam.synth.spec import Marker


@pytest.fixture(scope="module")
def tumvi_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("tumvi") / "tiny_tumvi"
    return synthesize(SynthSpec.tiny(seed=3, rig="tumvi"), out, workers=1)


def _marker_scene(direction_cam: np.ndarray, dist: float = 1.0) -> tuple[Scene, np.ndarray]:
    """A tiny TUM-VI scene with a marker `dist` m from cam0 along `direction_cam`."""
    base = Scene.build(SynthSpec.tiny(seed=6, rig="tumvi").ideal())
    T_wc0 = base.T_world_body(float(base.t_s(base.cam_t_ns[0]))) @ base.rig.cam0.T_body_cam
    d_w = T_wc0[:3, :3] @ (direction_cam / np.linalg.norm(direction_cam))
    center = T_wc0[:3, 3] + dist * d_w
    axis = int(np.argmax(np.abs(d_w)))  # the plate faces the camera
    side = 0 if d_w[axis] > 0 else 1
    marker = Marker(center=tuple(center), axis=axis, side=side, size=0.16, disc_radius=0.03)
    return Scene.build(SynthSpec.tiny(seed=6, rig="tumvi", marker=marker).ideal()), center


@pytest.mark.parametrize(
    "deg",
    [20.0, 95.0],  # in front, and behind the image plane (a fisheye sees it)
)
def test_known_point_projects_where_it_is_drawn(deg: float) -> None:
    t = np.radians(deg)
    direction = np.array([np.sin(t) / np.sqrt(2), np.sin(t) / np.sqrt(2), np.cos(t)])
    sc, center = _marker_scene(direction)
    disc_face = (
        6 + 6 * (sc.world.box_lo.shape[0] - 1) + 2 * sc.spec.marker.axis + sc.spec.marker.side
    )  # type: ignore[union-attr]
    T_wb = sc.T_world_body(float(sc.t_s(sc.cam_t_ns[0])))
    img, out = sc.image(0, 0, want_depth=True)
    mask = out.face == disc_face
    assert mask.sum() > 30, "marker not visible"
    w = np.clip(img.astype(np.float64) - 20.0, 0, None) * mask
    vv, uu = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    centroid = np.array([(w * uu).sum(), (w * vv).sum()]) / w.sum()
    T_cw = inv_T(T_wb @ sc.rig.cam0.T_body_cam)
    proj = sc.rig.cam0.model.project((T_cw[:3, :3] @ center + T_cw[:3, 3])[None])[0]
    # the disc's centroid is its centre's projection (a fisheye bends a disc: ~0.5 px at 95 deg)
    assert np.linalg.norm(proj - centroid) < (0.3 if deg < 90 else 0.8), (proj, centroid)


def test_cone_bounds_cover_every_pixel_a_box_is_seen_in(monkeypatch: pytest.MonkeyPatch) -> None:
    """The rim-of-the-cone bounding boxes lose no pixel: the render equals one that slab-tests
    every obstacle over the whole image."""
    sc = Scene.build(SynthSpec.tiny(seed=4, rig="tumvi").ideal())
    fast = [sc.radiance(k, cam)[0] for k in (0, 20, 40) for cam in (0, 1)]

    def whole(self, R_cw, o_w, lo, hi):  # type: ignore[no-untyped-def]
        return 0, self.calib.height, 0, self.calib.width

    monkeypatch.setattr(render_mod.CameraModel, "pixel_bbox", whole)
    slow = [sc.radiance(k, cam)[0] for k in (0, 20, 40) for cam in (0, 1)]
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a, b)


def test_written_as_a_tumvi_folder(tumvi_seq: Path) -> None:
    from eurocslam.dataset.doctor.asl_checks import diagnose

    assert sorted(p.name for p in (tumvi_seq / "dso").iterdir()) == [
        "camchain.yaml",
        "imu_config.yaml",
    ]
    assert sorted(p.name for p in (tumvi_seq / "mav0").iterdir()) == [
        "cam0",
        "cam1",
        "imu0",
        "mocap0",
    ]
    assert not list(tumvi_seq.rglob("sensor.yaml"))
    seq = open_sequence(tumvi_seq, quiet=True)
    assert isinstance(seq, AslSequence)
    assert seq.rig.cam0.distortion_model == "equidistant" and seq.rig.cam0.resolution == (512, 512)
    assert seq.rig.imu is not None and seq.rig.imu.gyro_noise_density == 0.00016
    frames = list(seq.frames())
    assert len(frames) == 41 and frames[0].left is not None
    assert frames[0].left.shape == (512, 512)
    assert np.all(np.diff(seq.frame_times) == 50_000_000)  # 20 Hz
    assert np.all(np.diff(seq.imu.t_ns) == 5_000_000)  # 200 Hz
    gt = seq.groundtruth
    assert gt is not None and gt.v is None and len(gt) == len(seq.imu)
    report = diagnose(tumvi_seq, full=True)
    assert report.exit_code == 0, [f.message for f in report.findings]


def test_euroc_specs_keep_their_identity() -> None:
    """A cached EuRoC replica's spec has no `rig` key: caches stay valid."""
    assert "rig" not in SynthSpec(seed=1).to_json()
    assert SynthSpec(seed=1, rig="tumvi").to_json()["rig"] == "tumvi"


def test_replica_motion_puts_the_fisheye_where_eurocs_cam0_flies(euroc_dir: Path) -> None:
    gt = euroc_dir / "groundtruth" / "V1_02_medium.csv"
    spec = SynthSpec(trajectory=gt, start_s=10.0, duration_s=3.0, seed=0)
    eu = Scene.build(spec)
    tv = Scene.build(SynthSpec(trajectory=gt, start_s=10.0, duration_s=3.0, seed=0, rig="tumvi"))
    assert eu.world.digest() == tv.world.digest()  # one world for both rigs
    np.testing.assert_array_equal(eu.cam_t_ns, tv.cam_t_ns)
    assert tv.rig.cam0.distortion_model == "equidistant"
    for t_ns in eu.cam_t_ns[::10]:
        a = eu.T_world_body(float(eu.t_s(t_ns))) @ default_rig().cam0.T_body_cam
        b = tv.T_world_body(float(tv.t_s(t_ns))) @ tumvi_rig().cam0.T_body_cam
        assert np.linalg.norm(a[:3, 3] - b[:3, 3]) < 2e-3
        dR = a[:3, :3].T @ b[:3, :3]
        assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 0.2


def test_run_eval_and_convert_a_tumvi_folder(tumvi_seq: Path, tmp_path: Path) -> None:
    """`run` and `eval` take the TUM-VI folder with no flags; run.mcap's CameraInfo is the
    fisheye's (equidistant, k1..k4, the rectification the run used) and its tf the rig's;
    `convert` carries the calibration over (attachments) to a reader that gets the same rig."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from eurocslam.cli import main
    from eurocslam.eval.evaluate import EvalConfig, evaluate
    from eurocslam.eval.loaders import load_groundtruth
    from eurocslam.io.ros2_calib import stereo_camera_infos
    from eurocslam.trajectory_io import read_tum

    out = tmp_path / "run"
    assert main(["run", str(tumvi_seq), "-o", str(out), "--no-progress"]) == 0
    online = read_tum(out / "trajectory_online.tum")
    assert len(online) == 41  # a pose for every frame
    gt = load_groundtruth(tumvi_seq)
    assert gt.source.endswith("mocap0/data.csv")
    ate = evaluate(gt.traj, read_tum(out / "trajectory_final.tum"), EvalConfig(align="se3"))
    assert ate.ate_trans.rmse < 0.01
    rig = open_sequence(tumvi_seq, quiet=True).rig
    topics = ("/cam0/camera_info", "/cam1/camera_info")
    want = dict(zip(topics, stereo_camera_infos(rig), strict=True))
    seen: dict[str, object] = {}
    frames: dict[str, np.ndarray] = {}
    with open(out / "run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, _, msg in reader.iter_decoded_messages(topics=[*want, "/tf_static"]):
            if ch.topic == "/tf_static":
                for t in msg.transforms:
                    tr = t.transform.translation
                    frames[t.child_frame_id] = np.array([tr.x, tr.y, tr.z])
            else:
                seen.setdefault(ch.topic, msg)
    for topic, info in want.items():
        msg = seen[topic]
        assert msg.distortion_model == "equidistant"  # type: ignore[attr-defined]
        np.testing.assert_array_equal(msg.d, info.D)  # type: ignore[attr-defined]
        np.testing.assert_array_equal(np.reshape(msg.p, (3, 4)), info.P)  # type: ignore[attr-defined]
    np.testing.assert_allclose(frames["cam1"], rig.cam1.T_body_cam[:3, 3])
    mcap = tmp_path / "tumvi.mcap"
    assert main(["convert", str(tumvi_seq), "-o", str(mcap)]) == 0
    back = open_sequence(mcap, quiet=True).rig
    for a, b in ((back.cam0, rig.cam0), (back.cam1, rig.cam1)):
        assert a.distortion_model == "equidistant" and a.distortion == b.distortion
        np.testing.assert_array_equal(a.T_body_cam, b.T_body_cam)


def test_run_with_focal_sized_rectification(tumvi_seq: Path, tmp_path: Path) -> None:
    """`frontend.rectify_size: focal` (rectified images larger than the raw ones) runs through
    the extraction workers, whose shared buffers hold raw images."""
    import yaml

    from eurocslam.cli import main
    from eurocslam.trajectory_io import read_tum

    cfg = tmp_path / "focal.yaml"
    cfg.write_text(
        yaml.safe_dump({"frontend": {"rectify_fov_deg": 120.0, "rectify_size": "focal"}})
    )
    out = tmp_path / "run"
    args = ["run", str(tumvi_seq), "-o", str(out), "--no-progress", "--no-mcap"]
    assert main([*args, "--config", str(cfg)]) == 0
    assert len(read_tum(out / "trajectory_online.tum")) == 41
