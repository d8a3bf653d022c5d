"""The tracker's own motion model: constant body-frame twist, scaled by the time since the last
pose. It predicts the next pose when the caller gives none (visual-only)."""

from __future__ import annotations

import numpy as np

from eurocslam.geometry import F64, inv_T, make_T, rigid, so3_exp, so3_log
from eurocslam.timebase import ns_to_s


class VelocityModel:
    """Constant body-frame twist, scaled by the time since the last pose."""

    def __init__(self, max_v: float, max_w: float) -> None:
        self.t_ns: int | None = None
        self.T: F64 | None = None
        self.v = np.zeros(3)  # m/s, body frame
        self.w = np.zeros(3)  # rad/s, body frame
        self.max_v, self.max_w = max_v, max_w

    def update(self, t_ns: int, T_world_body: F64) -> None:
        if self.T is not None and self.t_ns is not None and t_ns > self.t_ns:
            dt = ns_to_s(t_ns - self.t_ns)
            d = inv_T(self.T) @ T_world_body
            v = d[:3, 3] / dt
            w = so3_log(d[:3, :3]) / dt
            if np.linalg.norm(v) <= self.max_v and np.linalg.norm(w) <= self.max_w:
                self.v, self.w = v, w
            else:
                self.v, self.w = np.zeros(3), np.zeros(3)
        self.t_ns, self.T = t_ns, rigid(T_world_body)

    def shift(self, T_new_old: F64) -> None:
        """Apply a world correction (the backend moved the last pose)."""
        if self.T is not None:
            self.T = rigid(T_new_old @ self.T)

    def reset_motion(self) -> None:
        self.v, self.w = np.zeros(3), np.zeros(3)

    def predict(self, t_ns: int) -> F64 | None:
        if self.T is None or self.t_ns is None:
            return None
        dt = max(0.0, ns_to_s(t_ns - self.t_ns))
        return rigid(self.T @ make_T(so3_exp(self.w * dt), self.v * dt))
