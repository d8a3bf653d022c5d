"""Health checks: every way a state can be garbage is caught, with a reason."""

from __future__ import annotations

import numpy as np

from eurocslam.backend.estimator import NavEstimate
from eurocslam.backend.health import check_lost, check_state, check_step
from eurocslam.config import HealthConfig
from eurocslam.geometry import make_T, so3_exp

CFG = HealthConfig()


def _nav(**kw: object) -> NavEstimate:
    base = dict(
        t_ns=0,
        T_world_body=make_T(so3_exp(np.array([0.1, 0.2, 0.3])), np.ones(3)),
        v_world=np.array([0.5, 0.0, 0.1]),
        bg=np.full(3, 0.01),
        ba=np.full(3, 0.05),
    )
    base.update(kw)
    return NavEstimate(**base)  # type: ignore[arg-type]


def test_good_state_passes() -> None:
    assert check_state(_nav(), CFG).ok


def test_bad_states_are_caught_with_a_reason() -> None:
    T = make_T(np.eye(3), np.array([np.nan, 0, 0]))
    assert "non-finite" in check_state(_nav(T_world_body=T), CFG).reason
    assert "velocity" in check_state(_nav(v_world=np.array([20.0, 0, 0])), CFG).reason
    assert "gyro bias" in check_state(_nav(bg=np.array([0.0, 1.0, 0.0])), CFG).reason
    assert "accel bias" in check_state(_nav(ba=np.array([0.0, 0.0, 3.0])), CFG).reason
    bad_R = make_T(np.eye(3) * 1.1, np.zeros(3))
    assert not check_state(_nav(T_world_body=bad_R), CFG).ok
    # visual-only: velocity and biases are not physical states there
    assert check_state(_nav(v_world=np.array([20.0, 0, 0])), CFG, use_imu=False).ok


def test_step_and_lost_limits() -> None:
    a = make_T(np.eye(3), np.zeros(3))
    assert check_step(a, make_T(np.eye(3), np.array([0.05, 0, 0])), CFG).ok
    assert not check_step(a, make_T(np.eye(3), np.array([3.0, 0, 0])), CFG).ok
    assert check_lost(1.0, imu_ok=True, use_imu=True, cfg=CFG).ok
    assert not check_lost(CFG.max_lost_s + 0.1, imu_ok=True, use_imu=True, cfg=CFG).ok
    # blind during an IMU dropout, or visual-only: much shorter
    assert not check_lost(0.5, imu_ok=False, use_imu=True, cfg=CFG).ok
    assert not check_lost(0.5, imu_ok=True, use_imu=False, cfg=CFG).ok
    assert check_lost(0.1, imu_ok=True, use_imu=False, cfg=CFG).ok
