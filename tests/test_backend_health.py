"""Health checks: every way a state can be garbage is caught, with a reason."""

from __future__ import annotations

import numpy as np

from eurocslam.backend.health import Health
from eurocslam.backend.types import NavEstimate
from eurocslam.config import HealthConfig
from eurocslam.geometry import make_T, so3_exp

CFG = HealthConfig()
VIO = Health(CFG, inertial=True)
VO = Health(CFG, inertial=False)


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
    assert VIO.state(_nav()).ok
    assert VO.state(_nav()).ok


def test_bad_states_are_caught_with_a_reason() -> None:
    T = make_T(np.eye(3), np.array([np.nan, 0, 0]))
    assert "non-finite" in VIO.state(_nav(T_world_body=T)).reason
    assert "non-finite" in VO.state(_nav(T_world_body=T)).reason
    assert "velocity" in VIO.state(_nav(v_world=np.array([80.0, 0, 0]))).reason
    assert "gyro bias" in VIO.state(_nav(bg=np.array([0.0, 1.0, 0.0]))).reason
    assert "accel bias" in VIO.state(_nav(ba=np.array([0.0, 0.0, 3.0]))).reason
    bad_R = make_T(np.eye(3) * 1.1, np.zeros(3))
    assert not VIO.state(_nav(T_world_body=bad_R)).ok
    assert not VO.state(_nav(T_world_body=bad_R)).ok
    # visual-only: velocity and biases are not physical states there
    assert VO.state(_nav(v_world=np.array([20.0, 0, 0]))).ok
    assert VO.state(_nav(bg=np.array([0.0, 1.0, 0.0]))).ok


def test_motion_and_lost_limits() -> None:
    a = make_T(np.eye(3), np.zeros(3))
    near = make_T(np.eye(3), np.array([0.05, 0, 0]))
    far = make_T(np.eye(3), np.array([3.0, 0, 0]))
    # stereo-inertial: against the IMU's prediction
    assert VIO.motion(a, a, 0.05, near).ok
    jump = VIO.motion(a, near, 0.05, far)
    assert not jump.ok and "from the IMU's prediction" in jump.reason
    # visual-only: a speed bound from the last tracked pose (a car covers a metre per frame
    # at 10 Hz; 3 m in 50 ms is not a car)
    car = make_T(np.eye(3), np.array([1.1, 0, 0]))
    assert VO.motion(a, a, 0.1, car).ok
    fast = VO.motion(a, a, 0.05, far)
    assert not fast.ok and "60 m/s" in fast.reason
    assert VO.motion(a, a, 0.5, far).ok  # after a short loss, further is plausible
    assert VIO.lost(1.0, imu_ok=True).ok
    assert "no visual tracking" in VIO.lost(CFG.max_lost_s + 0.1, imu_ok=True).reason
    # blind during an IMU dropout, or visual-only: much shorter
    assert "IMU dropout" in VIO.lost(0.5, imu_ok=False).reason
    assert "visual-only" in VO.lost(0.5, imu_ok=True).reason
    assert VO.lost(0.1, imu_ok=True).ok
