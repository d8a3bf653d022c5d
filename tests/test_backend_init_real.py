"""Static initialisation on real EuRoC data: V1_01 micro (the drone stands still)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eurocslam.backend.initializer import choose_mode, static_init, static_window, stillness
from eurocslam.config import InitConfig
from eurocslam.dataset import open_sequence
from eurocslam.geometry import quat_wxyz_to_rot


def test_static_init_matches_groundtruth(v101_micro: Path) -> None:
    seq = open_sequence(v101_micro)
    assert seq.groundtruth is not None and seq.groundtruth.bg is not None
    t_first = int(seq.frame_times[0])
    cfg = InitConfig()
    t0, t1 = static_window(t_first, cfg)
    assert stillness(seq.imu, t0, t1, 9.81, cfg).still
    assert choose_mode(seq.imu, t_first, cfg, 9.81) == "static"
    init = static_init(seq.imu, t_first, cfg)
    gt = seq.groundtruth
    i = int(np.argmin(np.abs(gt.t_ns - t_first)))
    R_gt = quat_wxyz_to_rot(gt.q_wxyz[i])
    # roll and pitch: the world's up direction seen from the body
    up_est = init.T_world_body[:3, :3].T @ [0.0, 0.0, 1.0]
    up_gt = R_gt.T @ [0.0, 0.0, 1.0]
    tilt_err_deg = np.degrees(np.arccos(np.clip(up_est @ up_gt, -1.0, 1.0)))
    assert tilt_err_deg < 1.0, f"roll/pitch error {tilt_err_deg:.2f} deg"
    assert up_est[0] > 0.9  # the EuRoC IMU x axis points up
    np.testing.assert_allclose(init.bg, gt.bg[i], atol=0.005)
