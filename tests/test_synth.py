"""Synthetic sequences: geometry, IMU and format correctness of `eurocslam.synth`.

The built-in checks the issue asks for: stereo triangulation reproduces the rendered depth, the
noise-free IMU integrates back to the ground truth, a known 3D point is drawn where
`cv2.projectPoints` puts it in both cameras, `doctor` passes, seeds are deterministic.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from eurocslam.dataset import open_sequence
from eurocslam.geometry import inv_T, quat_wxyz_to_rot, rot_to_quat_wxyz
from eurocslam.synth import Marker, Scene, SynthSpec, synthesize
from eurocslam.synth.spline import fit_spline, so3_exp_batch, so3_log_batch

GRAVITY = np.array([0.0, 0.0, -9.81])


@pytest.fixture(scope="module")
def ideal_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 2 s built-in sequence with every realism switch off."""
    out = tmp_path_factory.mktemp("synth") / "ideal"
    return synthesize(SynthSpec.tiny(seed=2).ideal(), out, progress=False)


REAL_SPEC = SynthSpec(duration_s=0.5, seed=5)  # every realism switch at its default


@pytest.fixture(scope="module")
def real_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "real"
    return synthesize(REAL_SPEC, out, progress=False, workers=1)


@pytest.fixture(scope="module")
def ideal_scene() -> Scene:
    return Scene.build(SynthSpec.tiny(seed=4).ideal())


def _tree_digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


# ---- spline ---------------------------------------------------------------------------------
def test_spline_derivatives_match_finite_differences() -> None:
    t = np.arange(0.0, 6.0, 0.005)
    p = np.stack([np.sin(t), np.cos(0.7 * t), 0.2 * t], 1)
    rv = np.stack([0.4 * np.sin(t), 0.3 * np.cos(1.3 * t), 1.5 * t], 1)
    sp = fit_spline(t, p, rot_to_quat_wxyz(so3_exp_batch(rv)), knot_dt=0.05)
    tt = np.linspace(0.5, 5.5, 40)
    s, h = sp.evaluate(tt), 1e-5
    s1, s0 = sp.evaluate(tt + h), sp.evaluate(tt - h)
    np.testing.assert_allclose((s1.p - s0.p) / (2 * h), s.v, atol=1e-6)
    np.testing.assert_allclose((s1.v - s0.v) / (2 * h), s.a, atol=1e-4)
    w_fd = so3_log_batch(np.swapaxes(s0.R, 1, 2) @ s1.R) / (2 * h)
    np.testing.assert_allclose(w_fd, s.w_body, atol=1e-6)
    # and it passes through the poses it was fitted to
    assert np.abs(s.p - np.stack([np.sin(tt), np.cos(0.7 * tt), 0.2 * tt], 1)).max() < 1e-4
    R_true = so3_exp_batch(np.stack([0.4 * np.sin(tt), 0.3 * np.cos(1.3 * tt), 1.5 * tt], 1))
    assert np.abs(so3_log_batch(np.swapaxes(s.R, 1, 2) @ R_true)).max() < 1e-4


# ---- IMU ------------------------------------------------------------------------------------
def _integrate(R0, v0, p0, t_ns, gyro, accel):  # type: ignore[no-untyped-def]
    """Midpoint (second-order) strapdown integration of IMU samples."""
    R, v, p = R0.copy(), v0.copy(), p0.copy()
    for k in range(len(t_ns) - 1):
        dt = (t_ns[k + 1] - t_ns[k]) * 1e-9
        R1 = R @ so3_exp_batch(((gyro[k] + gyro[k + 1]) / 2 * dt)[None])[0]
        a0 = R @ accel[k] + GRAVITY
        a1 = R1 @ accel[k + 1] + GRAVITY
        v1 = v + (a0 + a1) / 2 * dt
        p = p + (v + v1) / 2 * dt
        R, v = R1, v1
    return R, v, p


def test_noise_free_imu_integrates_back_to_groundtruth(ideal_seq: Path) -> None:
    seq = open_sequence(ideal_seq)
    gt, imu = seq.groundtruth, seq.imu
    assert gt is not None
    np.testing.assert_array_equal(gt.t_ns, imu.t_ns)
    i0 = 100  # 0.5 s in, then 1 s (200 samples)
    i1 = i0 + 200
    R0 = quat_wxyz_to_rot(gt.q_wxyz[i0])
    R, v, p = _integrate(
        R0,
        gt.v[i0],
        gt.p[i0],
        imu.t_ns[i0 : i1 + 1],
        imu.gyro[i0 : i1 + 1],
        imu.accel[i0 : i1 + 1],
    )
    moved = np.linalg.norm(gt.p[i1] - gt.p[i0])
    assert moved > 0.2, "the test needs motion"
    assert np.linalg.norm(p - gt.p[i1]) < 0.01
    assert np.linalg.norm(v - gt.v[i1]) < 0.02
    ang = np.degrees(np.linalg.norm(so3_log_batch((R.T @ quat_wxyz_to_rot(gt.q_wxyz[i1]))[None])))
    assert ang < 0.05
    # ideal: zero biases written
    assert gt.bg is not None and gt.ba is not None
    assert np.all(gt.bg == 0) and np.all(gt.ba == 0)


def test_consistency_measure_of_a_noise_free_sequence(ideal_seq: Path) -> None:
    from eurocslam.synth.consistency import main, sequence_mismatch

    m = sequence_mismatch(ideal_seq, windows_s=(0.05, 0.2, 1.0))
    assert max(m.gyro_deg) < 1e-3
    assert max(m.dv_mps) < 1e-3
    assert main([]) == 2


def _sequence_copy(seq: Path, out: Path, imu_fn=None, gt_fn=None) -> Path:  # type: ignore[no-untyped-def]
    """The IMU and ground-truth CSVs of `seq` under out/mav0, each (t_ns, values) optionally
    changed by imu_fn / gt_fn."""
    from eurocslam.dataset.asl import read_numeric_csv

    for sub, ncols, fn in (("imu0", 7, imu_fn), ("state_groundtruth_estimate0", 17, gt_fn)):
        tab = read_numeric_csv(seq / "mav0" / sub / "data.csv", ncols)
        t, v = (tab.t_ns, tab.values) if fn is None else fn(tab.t_ns.copy(), tab.values.copy())
        (out / "mav0" / sub).mkdir(parents=True)
        rows = "".join(
            f"{ti}," + ",".join(f"{x:.17g}" for x in vi) + "\n" for ti, vi in zip(t, v, strict=True)
        )
        (out / "mav0" / sub / "data.csv").write_text("#t\n" + rows)
    return out


def test_consistency_measure_sees_a_bias_offset(ideal_seq: Path, tmp_path: Path) -> None:
    """Positive control: 1e-3 rad/s more gyro bias than the ground truth says gives about
    degrees(1e-3 w) over a window of w s, 0.02 m/s^2 more accel bias about 0.02 w m/s."""
    from eurocslam.synth.consistency import sequence_mismatch

    def offset(t, v):  # type: ignore[no-untyped-def]
        v[:, 0:3] += [0.0, 1e-3, 0.0]
        v[:, 3:6] += [0.0, 0.0, 0.02]
        return t, v

    seq = _sequence_copy(ideal_seq, tmp_path / "biased", imu_fn=offset)
    wins = (0.05, 0.2, 1.0)
    m = sequence_mismatch(seq, windows_s=wins)
    np.testing.assert_allclose(m.gyro_deg, np.degrees(1e-3 * np.array(wins)), rtol=0.03)
    np.testing.assert_allclose(m.dv_mps, 0.02 * np.array(wins), rtol=0.03)


def test_consistency_tool_errors(
    ideal_seq: Path, v101_micro: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A ground truth not at the IMU's stamps (every 10th, none, a real 20 Hz one) is refused by
    name, not measured on what stamps match; a window longer than the sequence prints "-"; CLI
    errors are one line."""
    from eurocslam.errors import DatasetError
    from eurocslam.synth.consistency import main, sequence_mismatch

    sparse = _sequence_copy(ideal_seq, tmp_path / "sparse", gt_fn=lambda t, v: (t[::10], v[::10]))
    gt_csv = sparse / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    with pytest.raises(DatasetError, match=rf"^{gt_csv}: ground truth at 41 of the 401 IMU"):
        sequence_mismatch(sparse)
    shifted = _sequence_copy(ideal_seq, tmp_path / "shifted", gt_fn=lambda t, v: (t + 1, v))
    with pytest.raises(DatasetError, match="ground truth at 0 of the 400 IMU stamps"):
        sequence_mismatch(shifted)
    with pytest.raises(DatasetError, match="ground truth at 2317 of the 28941 IMU stamps"):
        sequence_mismatch(v101_micro)
    capsys.readouterr()
    for bad in (tmp_path / "nonexistent", sparse):
        assert main([str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("consistency: error: ") and len(err.splitlines()) == 1, err
    # the built-in sequence is 2 s: no 5 s window
    assert main([str(ideal_seq)]) == 0
    row = capsys.readouterr().out.splitlines()[-1].split()
    assert row[1:] == [*row[1:4], "-", "|", *row[6:9], "-"]
    assert all(float(x) < 1e-3 for x in row[1:4] + row[6:9])


def test_imu_noise_and_biases_follow_the_calibration() -> None:
    from eurocslam.dataset.calib import default_rig
    from eurocslam.synth.imu import ideal_imu, simulate_imu
    from eurocslam.synth.trajectory import builtin_motion

    rig = default_rig()
    m = builtin_motion(30.0, 1)
    t_ns = m.t0_ns + 5_000_000 * np.arange(6000, dtype=np.int64)
    s = simulate_imu(m.spline, m.t0_ns, t_ns, rig.imu, 1, noise=True, bias=True)
    g0, a0 = ideal_imu(m.spline, (t_ns - m.t0_ns) * 1e-9)
    white_g = s.gyro - s.bg - g0
    white_a = s.accel - s.ba - a0
    dt = 1 / rig.imu.rate_hz
    assert np.std(white_g) == pytest.approx(rig.imu.gyro_noise_density / np.sqrt(dt), rel=0.05)
    assert np.std(white_a) == pytest.approx(rig.imu.accel_noise_density / np.sqrt(dt), rel=0.05)
    steps = np.diff(s.ba, axis=0)
    assert np.std(steps) == pytest.approx(rig.imu.accel_random_walk * np.sqrt(dt), rel=0.05)
    assert np.all(np.abs(s.bg[0]) > 0)  # initial bias drawn


# ---- images ---------------------------------------------------------------------------------
def test_stereo_triangulation_reproduces_rendered_depth(ideal_scene: Scene) -> None:
    sc = ideal_scene
    rig = sc.rig
    left, out0 = sc.image(10, 0, want_depth=True)
    right, _ = sc.image(10, 1)
    depth = out0.depth
    orb = cv2.ORB_create(nfeatures=1500)
    kps = orb.detect(left, None)
    assert len(kps) > 500
    pts0 = np.array([np.round(k.pt) for k in kps], dtype=np.float32)
    # correspondences: LK from the left keypoint into the right image, seeded with the
    # disparity the depth map predicts at infinity (0) and refined over pyramid levels
    pts1, st, _err = cv2.calcOpticalFlowPyrLK(
        left,
        right,
        pts0.reshape(-1, 1, 2),
        None,
        winSize=(21, 21),
        maxLevel=4,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-4),
    )
    back, st2, _ = cv2.calcOpticalFlowPyrLK(right, left, pts1, None, winSize=(21, 21), maxLevel=4)
    ok = (st.ravel() == 1) & (st2.ravel() == 1)
    ok &= np.linalg.norm(back.reshape(-1, 2) - pts0, axis=1) < 0.1
    p0, p1 = pts0[ok], pts1.reshape(-1, 2)[ok]
    n0 = cv2.undistortPoints(p0.reshape(-1, 1, 2), rig.cam0.K, rig.cam0.D).reshape(-1, 2)
    n1 = cv2.undistortPoints(p1.reshape(-1, 1, 2), rig.cam1.K, rig.cam1.D).reshape(-1, 2)
    T10 = rig.T_cam1_cam0
    P0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = T10[:3, :]
    X = cv2.triangulatePoints(P0, P1, n0.T.astype(np.float64), n1.T.astype(np.float64))
    z = X[2] / X[3]
    # epipolar consistency (rejects the few wrong LK matches) and a positive depth
    x1 = T10[:3, :3] @ (X[:3] / X[3]) + T10[:3, 3:4]
    reproj = np.linalg.norm(x1[:2] / x1[2] - n1.T, axis=0) * rig.cam1.fx
    good = (z > 0.1) & (reproj < 0.5)
    assert good.sum() > 200
    d_true = depth[p0[good, 1].astype(int), p0[good, 0].astype(int)]
    rel = (z[good] - d_true) / d_true
    assert abs(float(np.median(rel))) < 0.01
    assert float(np.median(np.abs(rel))) < 0.01


def test_known_point_projects_where_it_is_drawn() -> None:
    base = Scene.build(SynthSpec.tiny(seed=6).ideal())
    T_wb = base.T_world_body(float(base.t_s(base.cam_t_ns[0])))
    T_wc0 = T_wb @ base.rig.cam0.T_body_cam
    view = T_wc0[:3, 2]
    axis = int(np.argmax(np.abs(view)))
    side = 0 if view[axis] > 0 else 1
    # 1.2 m ahead of cam0 and a little off its axis
    center = T_wc0[:3, 3] + 1.2 * view + 0.1 * T_wc0[:3, 0]
    marker = Marker(center=tuple(center), axis=axis, side=side, size=0.2, disc_radius=0.04)
    sc = Scene.build(SynthSpec.tiny(seed=6, marker=marker).ideal())
    disc_face = 6 + 6 * (sc.world.box_lo.shape[0] - 1) + 2 * axis + side
    for cam, calib in ((0, sc.rig.cam0), (1, sc.rig.cam1)):
        img, out = sc.image(0, cam, want_depth=True)
        mask = out.face == disc_face
        assert mask.sum() > 200, f"cam{cam}: marker not visible"
        w = np.clip(img.astype(np.float64) - 20.0, 0, None) * mask
        vv, uu = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
        centroid = np.array([(w * uu).sum(), (w * vv).sum()]) / w.sum()
        T_cw = inv_T(T_wb @ calib.T_body_cam)
        rvec, _ = cv2.Rodrigues(T_cw[:3, :3])
        proj, _ = cv2.projectPoints(center[None], rvec, T_cw[:3, 3], calib.K, calib.D)
        assert np.linalg.norm(proj.reshape(2) - centroid) < 0.3, f"cam{cam}"


# ---- the written folder ---------------------------------------------------------------------
def test_written_sequence_reads_back_and_passes_doctor(ideal_seq: Path) -> None:
    from eurocslam.dataset.doctor.asl_checks import diagnose

    seq = open_sequence(ideal_seq)
    assert seq.skips.total == 0
    frames = list(seq.frames())
    assert len(frames) == 41
    assert frames[0].left is not None and frames[0].left.shape == (480, 752)
    assert frames[0].left.dtype == np.uint8
    t_cam = seq.frame_times
    assert np.all(np.diff(t_cam) == 50_000_000)
    assert np.all(np.isin(t_cam, seq.imu.t_ns)), "cameras must share IMU stamps"
    assert np.all(np.diff(seq.imu.t_ns) == 5_000_000)
    assert t_cam[0] > 1_000_000_000_000_000_000  # a realistic epoch, not 0
    report = diagnose(ideal_seq, full=True)
    assert report.exit_code == 0, [f.message for f in report.findings]


def test_realistic_sequence_passes_doctor(real_seq: Path) -> None:
    from eurocslam.dataset.doctor.asl_checks import diagnose

    report = diagnose(real_seq, full=True)
    assert report.exit_code == 0, [f.message for f in report.findings]
    seq = open_sequence(real_seq)
    assert seq.groundtruth is not None and seq.groundtruth.bg is not None
    assert np.all(np.abs(seq.groundtruth.bg[0]) > 0)  # the biases actually used are written


def test_same_seed_same_bytes_any_worker_count(real_seq: Path, tmp_path: Path) -> None:
    again = synthesize(REAL_SPEC, tmp_path / "again", progress=False, workers=2)
    assert _tree_digest(real_seq / "mav0") == _tree_digest(again / "mav0")
    # another seed: other IMU noise and other images on the same clock
    a = Scene.build(REAL_SPEC)
    b = Scene.build(replace(REAL_SPEC, seed=REAL_SPEC.seed + 1))
    np.testing.assert_array_equal(a.cam_t_ns, b.cam_t_ns)
    assert not np.array_equal(a.imu.gyro, b.imu.gyro)
    assert not np.array_equal(a.image(0, 0)[0], b.image(0, 0)[0])


def test_refuses_to_overwrite_without_force(tmp_path: Path) -> None:
    from eurocslam.errors import OutputError

    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    with pytest.raises(OutputError, match="not empty"):
        synthesize(SynthSpec(duration_s=0.3), other, progress=False)
    with pytest.raises(OutputError, match="refusing"):
        synthesize(SynthSpec(duration_s=0.3), other, progress=False, overwrite=True)
    assert (other / "notes.txt").read_text() == "keep me"


# ---- semi-real replicas ---------------------------------------------------------------------
def test_replica_follows_real_groundtruth(euroc_dir: Path) -> None:
    from eurocslam.synth.trajectory import motion_from_groundtruth, read_groundtruth_file

    for name in ("V1_02_medium.csv", "MH_01_easy.txt"):
        gt = read_groundtruth_file(euroc_dir / "groundtruth" / name)
        m = motion_from_groundtruth(gt, start_s=20.0, end_s=40.0)
        assert m.fit_rms_m < 0.01, name
        assert m.fit_rms_deg < 0.5, name
        assert m.t0_ns >= gt.t_ns[0]  # on the file's own clock
        st = m.spline.evaluate(np.arange(0.0, m.t_end_s, 0.005))
        # accelerations are motion, not differentiated Vicon/Leica noise
        assert float(np.sqrt(np.mean(np.sum(st.a**2, axis=1)))) < 3.0, name
        assert float(np.max(np.linalg.norm(st.w_body, axis=1))) < 4.0, name


def _window_mismatch(t_ns, gyro, accel, bg, ba, st, n):  # type: ignore[no-untyped-def]
    """consistency.imu_mismatch over one window of n IMU intervals (constant biases bg, ba):
    (median angle [deg], median |delta-v| error [m/s])."""
    from eurocslam.synth.consistency import imu_mismatch

    assert np.all(bg == bg[0]) and np.all(ba == ba[0])
    win = n * float(np.median(np.diff(t_ns))) * 1e-9
    m = imu_mismatch(t_ns, gyro, accel, bg[0], ba[0], st.R, st.v, windows_s=(win,))
    return m.gyro_deg[0], m.dv_mps[0]


def test_imu_groundtruth_fusion_recovers_the_motion() -> None:
    """fusion.py: the true motion's IMU plus a ground truth with orientation and position noise,
    in a world 0.3 deg off gravity: the fused poses are the true motion (gravity-aligned again),
    closer than the ground truth, and the IMU integrates onto them."""
    from eurocslam.synth.fusion import fuse_imu_groundtruth
    from eurocslam.synth.imu import ideal_imu
    from eurocslam.synth.trajectory import builtin_motion

    m = builtin_motion(12.0, 3)
    t_ns = m.t0_ns + 5_000_000 * np.arange(2401, dtype=np.int64)
    t = (t_ns - m.t0_ns) * 1e-9
    gyro, accel = ideal_imu(m.spline, t)
    st = m.spline.evaluate(t)
    rng = np.random.default_rng(7)
    tilt = so3_exp_batch(np.radians([[0.3, -0.2, 0.0]]))[0]  # the ground truth's world
    i = np.arange(0, t.size, 10)  # 20 Hz
    noise = so3_exp_batch(rng.normal(0.0, np.radians(0.1), (i.size, 3)))
    gt_R = tilt @ st.R[i] @ noise
    gt_p = st.p[i] @ tilt.T + rng.normal(0.0, 0.002, (i.size, 3))
    zero = np.zeros_like(gyro)
    f = fuse_imu_groundtruth(t_ns, gyro, accel, zero, zero, t_ns[i], gt_R, gt_p)
    back = np.degrees(np.linalg.norm(so3_log_batch((f.world_R @ tilt)[None])))
    assert back < 0.02  # the world turned back onto gravity (it was 0.36 deg off)
    assert f.gravity == pytest.approx(9.81, abs=1e-3)
    rot_err = np.degrees(np.linalg.norm(so3_log_batch(np.swapaxes(f.R, 1, 2) @ st.R), axis=1))
    pos_err = np.linalg.norm(f.p - st.p, axis=1)
    assert np.sqrt(np.mean(rot_err**2)) < 0.04  # the ground truth's: 0.17 deg
    assert np.sqrt(np.mean(pos_err**2)) < 0.5 * f.pos_dev_m  # the ground truth's: 3.5 mm
    assert f.rot_dev_deg == pytest.approx(0.17, abs=0.03)
    assert f.pos_dev_m == pytest.approx(0.0035, abs=0.0007)
    # the gyro integrates onto the fused rotation, the accelerometer onto the fused positions
    v = np.gradient(f.p, 0.005, axis=0)
    st_f = type(st)(t, f.p, v, st.a, f.R, st.w_body)
    ang, dv = _window_mismatch(t_ns, gyro, accel, zero, zero, st_f, 40)
    assert ang < 0.01 and dv < 0.003  # the ground truth: 0.14 deg (its noise) over any window


def test_real_imu_replica_is_consistent(euroc_dir: Path, v101_micro: Path) -> None:
    """V1_01: the real gyro (minus a constant bias) integrates onto the replica's rotation over
    0.05 and 0.2 s (a keyframe interval) better than a simulated IMU does (0.003, 0.007 deg; a
    spline through the ground truth alone: 0.069, 0.067 deg); the accelerometer's delta-v error
    over 0.2 s halves (17.5 -> 7.5 mm/s; what is left is its own bias wander)."""
    spec = SynthSpec(
        trajectory=euroc_dir / "groundtruth" / "V1_01_easy.csv",
        imu=v101_micro / "mav0" / "imu0" / "data.csv",
        start_s=30.0,
        end_s=33.0,
    )
    sc = Scene.build(spec)
    imu = sc.imu
    assert imu.real
    assert np.all(np.isin(sc.cam_t_ns, imu.t_ns))
    # the biases taken off: the ground truth's columns' means, constant
    assert np.all(np.abs(imu.bg[0]) > 0) and np.all(imu.bg == imu.bg[0])
    # the ground truth's world is 0.2 deg off the accelerometer's gravity: turned back
    assert sc.motion.world_R is not None
    turn = np.degrees(np.linalg.norm(so3_log_batch(sc.motion.world_R[None])))
    assert 0.1 < turn < 0.3
    assert sc.motion.fit_rms_m < 0.004 and sc.motion.fit_rms_deg < 0.4  # still the real motion
    st = sc.motion.spline.evaluate(sc.t_s(imu.t_ns))
    turned = np.degrees(np.linalg.norm(so3_log_batch((st.R[0].T @ st.R[200])[None])))
    assert turned > 5.0
    ang, dv = _window_mismatch(imu.t_ns, imu.gyro, imu.accel, imu.bg, imu.ba, st, 40)
    assert ang < 0.006
    assert dv < 0.011
    ang, _ = _window_mismatch(imu.t_ns, imu.gyro, imu.accel, imu.bg, imu.ba, st, 10)
    assert ang < 0.002


# ---- CLI ------------------------------------------------------------------------------------
def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from eurocslam.cli import main

    assert main(["synth", str(tmp_path / "a"), "--trajectory", str(tmp_path / "no.csv")]) == 2
    assert "no.csv" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "b"), "--imu", str(tmp_path / "imu.csv")]) == 2
    assert "--imu needs --trajectory" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("#t,x\n1,2,3\n")
    assert main(["synth", str(tmp_path / "c"), "--trajectory", str(bad)]) == 2
    assert "bad.csv" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "d"), "--duration", "-1"]) == 2


def test_cli_writes_a_sequence(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from eurocslam.cli import main

    assert main(["synth", str(tmp_path / "s"), "--duration", "0.4", "--seed", "1"]) == 0
    text = capsys.readouterr().out
    assert "wrote" in text and "eurocslam doctor" in text
    assert len(list((tmp_path / "s/mav0/cam1/data").glob("*.png"))) == 9


def test_large_rooms_get_coarser_texels_not_stretched_textures() -> None:
    from eurocslam.synth.world import MAX_TEX, build_world

    path = np.array([[0.0, 0.0, 1.0], [30.0, 4.0, 1.5]])
    w = build_world(path, 0)
    assert w.texels_per_m < 200.0
    assert int(w.tex_w.max()) <= MAX_TEX and int(w.tex_h.max()) <= MAX_TEX
    # every face's texture covers the face at the world's single texel density
    ext = np.stack([w.room_hi - w.room_lo, *(w.box_hi - w.box_lo)])
    for f in range(w.n_faces):
        obj, axis = divmod(f, 6)[0], w.face_axis[f]
        sa, ta = [a for a in range(3) if a != axis]
        assert w.tex_w[f] >= ext[obj, sa] * w.texels_per_m - 1e-6
        assert w.tex_h[f] >= ext[obj, ta] * w.texels_per_m - 1e-6


def test_demo_synthesises_once_then_reuses_the_cache(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from eurocslam.cli import main

    argv = [
        "demo",
        "--duration",
        "0.4",
        "--cache",
        str(tmp_path / "cache"),
        "--out",
        str(tmp_path / "out"),
        "--steps",
        "doctor",
    ]
    assert main(argv) == 0
    first = capsys.readouterr().out
    assert "made in" in first and "$ eurocslam doctor" in first
    assert main(argv) == 0
    assert "reused from the cache" in capsys.readouterr().out
    assert len(list((tmp_path / "cache").iterdir())) == 1
    assert main([*argv[:-1], "nonsense"]) == 2


def _write_asl_gt(path: Path, t_ns: np.ndarray, bg: np.ndarray) -> None:
    n = t_ns.size
    p = np.stack([np.linspace(0, 1, n), np.zeros(n), np.ones(n)], 1)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    rows = np.hstack(
        [p, q, np.zeros((n, 3)), np.tile(bg, (n, 1)), np.tile([0.1, 0.2, 0.3], (n, 1))]
    )
    body = "\n".join(
        f"{t}," + ",".join(f"{x:.6f}" for x in r) for t, r in zip(t_ns, rows, strict=True)
    )
    path.write_text(
        "#timestamp,px,py,pz,qw,qx,qy,qz,vx,vy,vz,bwx,bwy,bwz,bax,bay,baz\n" + body + "\n"
    )


def test_groundtruth_biases_and_gaps(tmp_path: Path) -> None:
    from eurocslam.errors import DatasetError
    from eurocslam.synth.trajectory import motion_from_groundtruth, read_groundtruth_file

    t = 1_403_000_000_000_000_000 + 5_000_000 * np.arange(600, dtype=np.int64)
    good = tmp_path / "gt.csv"
    _write_asl_gt(good, t, np.array([0.01, -0.02, 0.03]))
    gt = read_groundtruth_file(good)
    assert gt.bg is not None and gt.ba is not None
    np.testing.assert_allclose(gt.bg[0], [0.01, -0.02, 0.03])
    np.testing.assert_allclose(gt.ba[0], [0.1, 0.2, 0.3])
    m = motion_from_groundtruth(gt)
    assert m.t0_ns == t[0] and m.bias_source is not None
    gap = tmp_path / "gap.csv"
    _write_asl_gt(gap, np.concatenate([t[:300], t[300:] + 2_000_000_000]), np.zeros(3))
    with pytest.raises(DatasetError, match=r"gap.csv: gap of 2\.0"):
        motion_from_groundtruth(read_groundtruth_file(gap))
    # the crop around the gap is fine
    motion_from_groundtruth(read_groundtruth_file(gap), start_s=0.0, end_s=1.4)


def test_imu_must_be_the_body_frame(tmp_path: Path) -> None:
    from eurocslam.dataset.calib import default_rig
    from eurocslam.errors import DatasetError

    texts = dict(default_rig().yaml_texts)
    for name, text in texts.items():
        (tmp_path / name).mkdir()
        if name == "imu0":
            text = text.replace("data: [1.0, 0.0, 0.0, 0.0,", "data: [1.0, 0.0, 0.0, 0.05,")
        (tmp_path / name / "sensor.yaml").write_text(text)
    with pytest.raises(DatasetError, match="T_BS must be the identity"):
        Scene.build(SynthSpec(duration_s=0.5, calib=tmp_path))
