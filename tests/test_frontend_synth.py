"""Frontend and visual odometry on rendered sequences with exact ground truth (synth)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eurocslam.camera import triangulate_rect
from eurocslam.config import RunConfig
from eurocslam.dataset import open_sequence
from eurocslam.dataset.types import StereoFrame
from eurocslam.eval.align import align
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor
from eurocslam.pipeline.slam import SlamPipeline
from eurocslam.synth import Scene, SynthSpec, synthesize
from frontend_helpers import Frontend


@pytest.fixture(scope="module")
def tiny_scene() -> Scene:
    return Scene.build(SynthSpec.tiny(seed=1))


@pytest.fixture(scope="module")
def tiny_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return synthesize(SynthSpec.tiny(seed=1), tmp_path_factory.mktemp("synth") / "tiny")


def test_triangulated_points_agree_with_rendered_depth(tiny_scene: Scene) -> None:
    """Stereo-matched keypoints triangulate to the depth the renderer drew at that pixel."""
    fe = Extractor.for_rig(tiny_scene.rig, FrontendConfig())
    g = fe.geometry
    rel_all = []
    for k in (0, 39):
        left, out = tiny_scene.image(k, 0, want_depth=True)
        right, _ = tiny_scene.image(k, 1)
        ff = fe.extract(StereoFrame(int(tiny_scene.cam_t_ns[k]), left, right))
        ok = ff.stereo.valid
        assert ok.sum() >= 300
        p_rect0 = triangulate_rect(ff.left.uv[ok, 0], ff.stereo.uR[ok], ff.left.uv[ok, 1], g)
        p_cam0 = p_rect0 @ fe.rectifier.R_rect0_cam0  # rect0 -> cam0 (R^T p)
        raw = np.rint(fe.rectifier.rect0_to_raw(ff.left.uv[ok])).astype(int)
        inside = (raw[:, 0] >= 0) & (raw[:, 0] < g.width) & (raw[:, 1] >= 0)
        inside &= raw[:, 1] < g.height
        z_true = out.depth[raw[inside, 1], raw[inside, 0]]
        rel_all.append(np.abs(p_cam0[inside, 2] - z_true) / z_true)
    rel = np.concatenate(rel_all)
    # measured: median 0.2 %, 90th percentile 0.6 % (depth edges give the tail)
    assert np.median(rel) < 0.01
    assert np.percentile(rel, 90) < 0.03


def _vo_ate(seq_path: Path) -> tuple[float, object, float]:
    """`run --no-imu` (frontend + GTSAM sliding-window BA): (final ATE, summary, path length)."""
    seq = open_sequence(seq_path)
    res = SlamPipeline(seq, RunConfig(mode="visual-only")).run()
    gt = seq.groundtruth
    assert gt is not None
    idx = np.searchsorted(gt.t_ns, res.final.t_ns)
    assert np.array_equal(gt.t_ns[idx], res.final.t_ns)  # rendered frames sit on GT stamps
    p_ref = gt.p[idx]
    p_est = res.final.p
    a = align("se3", p_ref, p_est)
    err = np.linalg.norm(p_est @ a.R.T + a.t - p_ref, axis=1)
    path = float(np.linalg.norm(np.diff(p_ref, axis=0), axis=1).sum())
    return float(np.sqrt(np.mean(err**2))), res.summary, path


def test_visual_odometry_ate_on_a_rendered_flight(tiny_sequence: Path) -> None:
    """`run --no-imu` on the 2 s built-in flight (41 frames, 1.2 m of motion): SE(3) ATE.

    Bound 2 cm: measured 4.1 mm here (full-length semi-real replicas: benchmarks/RESULTS.md);
    a fivefold margin for platform and OpenCV-version differences, still five times tighter than
    the 0.10 m accuracy target.
    """
    rmse, s, path = _vo_ate(tiny_sequence)
    assert s.mode == "visual-only"
    assert s.frames == 41 and s.frames_with_pose == 41
    assert s.state_frames == {"TRACKING": 41}
    assert len(s.timings_ms["backend"]) >= 3  # keyframes went through the local BA
    assert rmse < 0.02, f"VO ATE {rmse * 1000:.1f} mm"
    assert path > 0.5  # the camera really moved


def test_archived_landmarks_are_re_found_where_they_were(tiny_sequence: Path) -> None:
    """Map reuse on the 2 s flight, with landmarks archived after 2 unseen frames: re-found
    landmarks come back under ids made earlier, and are the same points. Every stereo sighting
    is put in the true world with the true body pose (odometry drift drops out) and compared
    with the landmark's first sighting across the viewing ray (where stereo is precise; along
    it, depth noise is centimetres), in pixels. Measured: median 0.9 px, 95th percentile 2.7
    (continuously tracked landmarks: 0.5 and 2.0; a stricter descriptor, radius or ratio test
    does not shrink it: viewpoint and octave changes over the gap, not wrong matches)."""
    seq = open_sequence(tiny_sequence)
    gt = seq.groundtruth
    assert gt is not None
    T_gt = dict(zip(gt.t_ns.tolist(), gt.T_world_body(), strict=True))
    fe = Frontend(seq.rig, FrontendConfig(landmark_max_unseen_s=0.1))
    g = fe.extractor.geometry
    first: dict[int, np.ndarray] = {}  # id -> first sighting, true world
    tracked_px, reused_px = [], []
    for frame in seq.frames():
        next_id = fe.tracker.map.next_id
        r = fe.process(frame)
        ids, uv = r.landmark_ids, r.stereo_uv
        reused = np.zeros(ids.size, bool)
        reused[r.n_tracked : r.n_tracked + r.n_reused] = True
        assert np.all(ids[reused] < next_id)
        T_true = T_gt[frame.t_ns] @ g.T_body_rect0
        p = triangulate_rect(uv[:, 0], uv[:, 1], uv[:, 2], g) @ T_true[:3, :3].T + T_true[:3, 3]
        seen = np.array([int(i) in first for i in ids], bool) & np.isfinite(p).all(axis=1)
        if seen.any():
            was = np.array([first[int(i)] for i in ids[seen]])
            rng = np.linalg.norm(p[seen] - T_true[:3, 3], axis=1, keepdims=True)
            ray = (p[seen] - T_true[:3, 3]) / rng
            d = was - p[seen]
            across = np.linalg.norm(d - np.sum(d * ray, axis=1, keepdims=True) * ray, axis=1)
            px = g.fx * across / rng[:, 0]
            reused_px.append(px[reused[seen]])
            tracked_px.append(px[~reused[seen] & (ids[seen] < next_id)])
        for i, q in zip(ids.tolist(), p, strict=True):
            if i not in first and np.isfinite(q).all():
                first[i] = q
    re, tr = np.concatenate(reused_px), np.concatenate(tracked_px)
    assert re.size > 50, re.size
    q_re, q_tr = np.percentile(re, [50, 95]), np.percentile(tr, [50, 95])
    assert q_re[0] < 1.5 and q_re[1] < 4.0, (q_re, q_tr)


def test_the_reuse_window_is_at_least_its_pixel_floor(tiny_sequence: Path) -> None:
    """Map reuse's search window is the larger of an angle (x fx) and `reuse_radius_min_px`:
    with the angle made negligible (0.01 deg: 0.08 px here) almost nothing is re-found; the
    floor at the pixels the default angle gives this rig brings every re-found landmark back
    (what a short-focal fisheye gets from the floor)."""
    seq = open_sequence(tiny_sequence)
    frames = list(seq.frames())
    fx = Frontend(seq.rig).extractor.geometry.fx
    default_px = fx * np.radians(FrontendConfig().reuse_radius_deg)

    def n_reused(**reuse: float) -> int:
        fe = Frontend(seq.rig, FrontendConfig(landmark_max_unseen_s=0.1, **reuse))  # type: ignore[arg-type]
        return sum(fe.process(f).n_reused for f in frames)

    full = n_reused()
    assert full > 50
    assert n_reused(reuse_radius_deg=0.01) < 0.1 * full
    assert n_reused(reuse_radius_deg=0.01, reuse_radius_min_px=default_px) == full


def test_a_pose_below_the_callers_bar_leaves_the_tracker_as_it_was(tiny_sequence: Path) -> None:
    """A frame tracked without a prior whose inliers stay under the caller's `min_inliers` is
    LOST, and nothing of it stays in the tracker: no landmarks, no pose, no motion. (On a
    rendered blackout, a 1.5 m wrong recovery refused by the pipeline had already made a
    keyframe's landmarks at its pose, and the next frame tracked on those.)"""
    seq = open_sequence(tiny_sequence)
    frames = list(seq.frames())
    fe = Frontend(seq.rig)
    for frame in frames[:10]:
        fe.process(frame)
    tr = fe.tracker
    ff = fe.extractor.extract(frames[20])
    ids_before, T_before = tr.map.ids[: len(tr.map)].copy(), tr.last_T_world_body.copy()
    refused = tr.track(ff, None, min_inliers=10**6)
    assert refused.T_world_body is None and refused.track_path == "lost"
    np.testing.assert_array_equal(tr.map.ids[: len(tr.map)], ids_before)
    np.testing.assert_array_equal(tr.last_T_world_body, T_before)
    accepted = tr.track(ff, None)  # the same frame under the default bar
    assert accepted.T_world_body is not None and accepted.n_tracked >= 50
    assert accepted.is_keyframe and len(tr.map) > ids_before.size


@pytest.mark.slow
@pytest.mark.parametrize("name", ["V2_03_difficult", "MH_04_difficult"])
def test_visual_odometry_on_semi_real_replicas(
    name: str, euroc_dir: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """20 s semi-real replicas (the real motion of EuRoC's hardest sequences, centred crop):
    a pose for every frame, ATE within the 0.10 m accuracy target."""
    gt = euroc_dir / "groundtruth" / f"{name}.csv"
    t = np.loadtxt(gt, delimiter=",", comments="#", usecols=0)
    mid = (t[-1] - t[0]) * 1e-9 / 2
    path = synthesize(
        SynthSpec(trajectory=gt, start_s=mid - 10.0, end_s=mid + 10.0),
        tmp_path_factory.mktemp("replica") / name,
    )
    rmse, s, _ = _vo_ate(path)
    assert s.coverage == 1.0, s.lines()
    assert rmse < 0.10, f"{name}: VO ATE {rmse:.3f} m"
