"""Frontend on real EuRoC images (V1_01 micro: 95 stereo frames, drone standing still)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from eurocslam.dataset import open_sequence
from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor
from eurocslam.frontend.stream import FeatureStream
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.frontend.types import MapCorrection, TrackingState
from eurocslam.geometry import inv_T, make_T, rotation_angle, so3_exp
from frontend_helpers import Frontend


@pytest.fixture(scope="module")
def v101_frames(v101_micro: Path) -> tuple[object, list[StereoFrame]]:
    seq = open_sequence(v101_micro)
    return seq, list(seq.frames())


def _vertical_offset(left: np.ndarray, right: np.ndarray, uL: float, uR: float, v: float) -> float:
    """Sub-pixel vertical shift of the right image patch against the left one (template match
    in a +-3 px window both ways, parabola fit), independent of keypoint quantisation."""
    h = 10
    s = 3
    x0, y0, x1 = round(uL), round(v), round(uR)
    tpl = left[y0 - h : y0 + h + 1, x0 - h : x0 + h + 1]
    win = right[y0 - h - s : y0 + h + s + 1, x1 - h - s : x1 + h + s + 1]
    if tpl.shape != (2 * h + 1, 2 * h + 1) or win.shape != (2 * (h + s) + 1, 2 * (h + s) + 1):
        return np.nan
    r = cv2.matchTemplate(win, tpl, cv2.TM_CCOEFF_NORMED)
    iy, ix = np.unravel_index(int(np.argmax(r)), r.shape)
    if not (0 < iy < r.shape[0] - 1) or r[iy, ix] < 0.8:
        return np.nan
    a, b, c = r[iy - 1, ix], r[iy, ix], r[iy + 1, ix]
    return float(iy - s + 0.5 * (a - c) / (a - 2 * b + c))


def test_rectified_stereo_matches_on_real_images(v101_frames) -> None:
    seq, frames = v101_frames
    fe = Extractor.for_rig(seq.rig, FrontendConfig())
    rect = fe.rectifier
    offsets: list[float] = []
    for fr in frames[::20]:
        ff = fe.extract(fr)
        assert ff.problem is None
        ok = ff.stereo.valid
        assert ok.sum() >= 300, "too few stereo matches on a textured room"
        uL, v = ff.left.uv[ok, 0], ff.left.uv[ok, 1]
        uR = ff.stereo.uR[ok]
        disparity = uL - uR
        assert np.all(disparity > 0)
        # keypoint rows of the matched pairs agree
        vR = ff.right.uv[ff.stereo.right_index[ok], 1]
        assert np.median(np.abs(v - vR)) < 1.0
        # depths plausible for the Vicon room (a few metres)
        d = ff.stereo.depth[ok]
        lo, hi = np.percentile(d, [1, 99])
        assert lo >= 0.3 and hi <= 10.0
        # rectification itself: image patches line up vertically to sub-pixel
        L = rect.rectify_left(fr.left)
        R = rect.rectify_right(fr.right)
        for k in range(0, ok.sum(), 4):
            offsets.append(_vertical_offset(L, R, uL[k], uR[k], v[k]))
    off = np.array(offsets)
    off = off[np.isfinite(off)]
    assert off.size > 200
    assert np.median(np.abs(off)) < 1.0
    assert abs(np.median(off)) < 0.5  # no systematic row shift between the rectified images


def test_static_visual_odometry_stays_put(v101_micro: Path) -> None:
    """`run --no-imu` (frontend + GTSAM sliding-window BA, no IMU factors) on the 95 real
    frames of a drone standing still: a pose for every complete frame, < 1 cm in total."""
    from eurocslam.config import RunConfig
    from eurocslam.pipeline.slam import SlamPipeline

    seq = open_sequence(v101_micro)
    res = SlamPipeline(seq, RunConfig(mode="visual-only")).run()
    s = res.summary
    assert s.mode == "visual-only"
    assert s.frames == 99 and s.frames_with_pose >= 95  # cam1 lacks the last 4 images
    assert s.state_frames.get("TRACKING", 0) >= 94
    assert len(s.timings_ms["backend"]) >= 5  # keyframes went through the local BA
    for P in (res.online.T_world_body(), res.final.T_world_body()):
        dev = np.linalg.norm(P[:, :3, 3] - P[0, :3, 3], axis=1)
        assert dev.max() < 0.01, f"static drone moved {dev.max() * 100:.2f} cm"
        rot = max(np.degrees(rotation_angle(P[0, :3, :3].T @ T[:3, :3])) for T in P)
        assert rot < 0.5


def test_landmark_ids_persist_and_observations_are_unique(v101_frames) -> None:
    seq, frames = v101_frames
    fe = Frontend(seq.rig, FrontendConfig())
    states, ids_seen = [], []
    for fr in frames:
        res = fe.process(fr)
        states.append(res.state)
        ids_seen.append(res.landmark_ids)
        assert np.unique(res.landmark_ids).size == res.landmark_ids.size
        if res.landmark_ids.size:
            assert np.all((res.stereo_uv[:, 0] >= 0) & (res.stereo_uv[:, 0] < 752))
    assert states[0] == TrackingState.INIT
    assert all(s == TrackingState.OK for s in states[1:])
    # the same landmarks are tracked all along: ids persist across frames
    assert np.intersect1d(ids_seen[1], ids_seen[-1]).size >= 100


def test_degraded_frames_are_reported_and_tracking_recovers(v101_frames, mh01_first5) -> None:
    seq, frames = v101_frames
    other = list(open_sequence(mh01_first5).frames())  # another place (the machine hall)
    blank = np.full_like(frames[0].left, 128)
    white = np.full_like(frames[0].left, 255)
    stream: list[StereoFrame] = []
    for i, fr in enumerate(frames[:40]):
        if i == 8:
            fr = replace(fr, left=None)
        elif i == 9:
            fr = replace(fr, right=blank)
        elif i == 10:
            fr = replace(fr, left=white, right=white)
        elif 20 <= i < 24:  # a different place entirely: tracking must fail, not invent poses
            o = other[i - 20]
            fr = replace(fr, left=o.left, right=o.right)
        stream.append(fr)
    fe = Frontend(seq.rig, FrontendConfig())
    results = [fe.process(fr) for fr in stream]
    states = [r.state for r in results]
    assert states[8] == states[9] == states[10] == TrackingState.NO_IMAGE
    assert all(r.T_world_body is None for r in results[8:11])
    assert states[11] == TrackingState.OK  # tracking resumes after missing/blank frames
    # foreign view: lost, then a new map on it after `reinit_after_lost_frames`, then lost
    # again when the room comes back, and a new map on the room
    assert states[20:26] == [
        TrackingState.LOST,
        TrackingState.INIT,
        TrackingState.OK,
        TrackingState.OK,
        TrackingState.LOST,
        TrackingState.INIT,
    ]
    assert all(r.T_world_body is None for r in results if r.state == TrackingState.LOST)
    assert all(s == TrackingState.OK for s in states[26:])
    # re-initialised maps start at the best available pose (the constant-velocity prediction
    # from the last tracked one), no jump to the origin: V1_01's drone stands still here
    assert np.linalg.norm(results[21].T_world_body[:3, 3] - results[19].T_world_body[:3, 3]) < 0.01
    # (the machine-hall frames move, so the room's new map starts where they left off) and
    # the room's new map is tracked steadily
    assert np.linalg.norm(results[-1].T_world_body[:3, 3] - results[25].T_world_body[:3, 3]) < 0.01
    # landmark ids are int64 and never reused, even across re-initialisations
    new_ids = [r.landmark_ids for r in results if r.state == TrackingState.INIT]
    assert len(new_ids) == 3 and all(x.dtype == np.int64 and x.size > 50 for x in new_ids)
    assert new_ids[0].max() < new_ids[1].min() and new_ids[1].max() < new_ids[2].min()


def test_prefetch_stream_matches_inline_processing(v101_frames) -> None:
    seq, frames = v101_frames
    cfg = FrontendConfig(prefetch=True)
    a = FeatureStream(Extractor.for_rig(seq.rig, cfg))
    tracker = StereoTracker(a.extractor.rectifier, cfg)
    b = Frontend(seq.rig, FrontendConfig(prefetch=False))
    ra = [tracker.track(ff) for _, ff in a(frames[:15])]
    rb = [b.process(fr) for fr in frames[:15]]
    for x, y in zip(ra, rb, strict=True):
        assert x.state == y.state
        np.testing.assert_array_equal(x.landmark_ids, y.landmark_ids)
        np.testing.assert_allclose(x.T_world_body, y.T_world_body, atol=1e-9)


def test_backend_correction_moves_the_local_map(v101_frames) -> None:
    """A `MapCorrection` moving the pose and the whole map by a rigid transform: the next frame
    is tracked in the moved frame (the frontend stays consistent with the backend)."""
    seq, frames = v101_frames
    fe = Frontend(seq.rig, FrontendConfig())
    for fr in frames[:10]:
        res = fe.process(fr)
    T_shift = make_T(so3_exp(np.array([0.0, 0.0, 0.3])), np.array([1.0, -2.0, 0.5]))
    tr = fe.tracker
    ids = tr.map.ids.copy()
    xyz = tr.landmark_positions(ids)
    moved = xyz @ T_shift[:3, :3].T + T_shift[:3, 3]
    tr.apply(MapCorrection(T_shift @ res.T_world_body, T_new_old=T_shift))
    np.testing.assert_allclose(tr.landmark_positions(ids), moved, atol=1e-12)
    nxt = fe.process(frames[10])
    assert nxt.state == TrackingState.OK
    err = inv_T(T_shift @ res.T_world_body) @ nxt.T_world_body
    assert np.linalg.norm(err[:3, 3]) < 0.005
    # landmark positions by id: ids unknown to the map and non-finite positions are ignored
    new = np.array([np.zeros(3), moved[0] + 0.001, np.full(3, np.nan)])
    tr.apply(MapCorrection(nxt.T_world_body, None, np.array([10**12, ids[0], ids[1]]), new))
    np.testing.assert_allclose(tr.landmark_positions(ids[:2]), [moved[0] + 0.001, moved[1]])
    assert np.isnan(tr.landmark_positions(np.array([10**12]))).all()
