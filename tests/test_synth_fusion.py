"""fusion.py: worlds at any tilt, input validation, errors naming the file; integrate_gyro."""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from eurocslam.errors import DatasetError
from eurocslam.geometry import rot_to_quat_wxyz
from eurocslam.synth.fusion import fuse_imu_groundtruth
from eurocslam.synth.imu import ideal_imu
from eurocslam.synth.kinematics import integrate_gyro
from eurocslam.synth.spline import so3_exp_batch, so3_log_batch
from eurocslam.synth.trajectory import (
    GroundTruthInput,
    builtin_motion,
    motion_from_groundtruth,
)


@lru_cache(maxsize=1)
def _flight() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """4 s of the built-in flight: IMU stamps (200 Hz), ideal gyro/accel, true R, p; the 20 Hz
    ground-truth rows (indices)."""
    m = builtin_motion(4.0, 3)
    t_ns = m.t0_ns + 5_000_000 * np.arange(801, dtype=np.int64)
    t = (t_ns - m.t0_ns) * 1e-9
    gyro, accel = ideal_imu(m.spline, t)
    st = m.spline.evaluate(t)
    return t_ns, gyro, accel, st.R, st.p, np.arange(0, t.size, 10)


def _fuse(t_ns, gyro, accel, gt_t, gt_R, gt_p):  # type: ignore[no-untyped-def]
    zero = np.zeros_like(gyro)
    return fuse_imu_groundtruth(t_ns, gyro, accel, zero, zero, gt_t, gt_R, gt_p)


@pytest.mark.parametrize("deg", [0.0, 100.0, 180.0, -179.99])
def test_fusion_turns_any_world_onto_gravity(deg: float) -> None:
    """A ground truth in a world turned about x (180 deg: z down) ends with gravity along -z
    and the true motion (up to a turn about z); arcsin only managed up to 90 deg."""
    t_ns, gyro, accel, R, p, i = _flight()
    flip = so3_exp_batch(np.radians([[deg, 0.0, 0.0]]))[0]
    f = _fuse(t_ns, gyro, accel, t_ns[i], flip @ R[i], p[i] @ flip.T)
    M = f.world_R @ flip  # true world -> fused world
    np.testing.assert_allclose(M.T @ M, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(M @ [0.0, 0.0, -1.0], [0.0, 0.0, -1.0], atol=1e-6)
    rot = np.degrees(np.linalg.norm(so3_log_batch(np.swapaxes(f.R, 1, 2) @ M @ R), axis=1))
    assert rot.max() < 0.01
    assert np.abs(f.p - p @ M.T).max() < 1e-4
    assert f.gravity == pytest.approx(9.81, abs=1e-4)


def _gap(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    keep = (i < 200) | (i > 360)  # no poses between 0.95 and 1.85 s
    return t, g, a, t[i[keep]], R[i[keep]], p[i[keep]]


def _late_gt(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    return t, g, a, t[i[5:]], R[i[5:]], p[i[5:]]  # IMU 0.25 s before the first pose


def _early_gt(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    return t, g, a, t[i[:-3]], R[i[:-3]], p[i[:-3]]  # IMU 0.15 s after the last


def _repeated_imu_stamp(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    t = t.copy()
    t[100] = t[99]
    return t, g, a, t[i], R[i], p[i]


def _reversed_gt(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    j = i.copy()
    j[[3, 4]] = j[[4, 3]]
    return t, g, a, t[j], R[j], p[j]


def _nan_accel(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    a = a.copy()
    a[17, 1] = np.nan
    return t, g, a, t[i], R[i], p[i]


def _inf_gt_position(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    gp = p[i].copy()
    gp[4, 2] = np.inf
    return t, g, a, t[i], R[i], gp


def _nan_gt_rotation(t, g, a, R, p, i):  # type: ignore[no-untyped-def]
    gR = R[i].copy()
    gR[6, 0, 0] = np.nan
    return t, g, a, t[i], gR, p[i]


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (_gap, r"gap of 0\.90 s in the ground truth at 0\.95 s"),
        (_late_gt, r"IMU rows run 0\.250 s before the ground truth"),
        (_early_gt, r"IMU rows run 0\.150 s after the ground truth"),
        (_repeated_imu_stamp, r"IMU timestamps must strictly increase \(row 100"),
        (_reversed_gt, r"ground-truth timestamps must strictly increase \(row 4"),
        (_nan_accel, r"IMU accel: not finite at row 17"),
        (_inf_gt_position, r"ground-truth position: not finite at row 4"),
        (_nan_gt_rotation, r"ground-truth orientation: not finite at row 6"),
    ],
)
def test_fusion_rejects_bad_inputs(make, match: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(DatasetError, match=match):
        _fuse(*make(*_flight()))


def _groundtruth_input(path: Path, keep: np.ndarray) -> GroundTruthInput:
    t_ns, _, _, R, p, i = _flight()
    j = i[keep]
    zero = np.zeros((j.size, 3))
    return GroundTruthInput(path, t_ns[j], p[j], rot_to_quat_wxyz(R[j]), zero, zero)


def test_fusion_errors_name_the_groundtruth_file(tmp_path: Path) -> None:
    """trajectory.py adds the ground truth's path to the fusion's errors: a gap outside the crop
    (which the crop's own check does not see, but the fusion spans the whole file) and a NaN
    IMU row."""
    t_ns, gyro, accel, _, _, i = _flight()
    path = tmp_path / "gt.csv"
    gt = _groundtruth_input(path, (i < 500) | (i > 640))  # none in 2.45-3.25 s
    with pytest.raises(
        DatasetError, match=rf"^{re.escape(str(path))} with the given IMU rows: gap of 0\.80 s"
    ):
        motion_from_groundtruth(gt, start_s=0.0, end_s=2.0, imu=(t_ns, gyro, accel))
    gt = _groundtruth_input(path, np.ones(i.size, bool))
    gyro = gyro.copy()
    gyro[300, 0] = np.nan
    with pytest.raises(
        DatasetError, match=rf"^{re.escape(str(path))} with the given IMU rows: IMU gyro: not fin"
    ):
        motion_from_groundtruth(gt, start_s=0.0, end_s=2.0, imu=(t_ns, gyro, accel))


def test_integrate_gyro_constant_rate() -> None:
    """A constant rate (minus a constant or per-sample bias) integrates to exp(w t), exactly
    orthonormal, over uneven intervals."""
    rng = np.random.default_rng(1)
    t_ns = np.cumsum(rng.integers(4_000_000, 6_000_000, 400)).astype(np.int64)
    w = np.array([0.3, -1.2, 0.7])
    bg = np.array([0.01, 0.02, -0.03])
    gyro = np.broadcast_to(w + bg, (t_ns.size, 3))
    t = (t_ns - t_ns[0]) * 1e-9
    want = so3_exp_batch(t[:, None] * w)
    for b in (bg, np.broadcast_to(bg, gyro.shape)):
        P = integrate_gyro(t_ns, gyro, b)
        np.testing.assert_allclose(P, want, atol=1e-12)
        np.testing.assert_allclose(
            np.swapaxes(P, 1, 2) @ P, np.broadcast_to(np.eye(3), P.shape), atol=1e-14
        )
