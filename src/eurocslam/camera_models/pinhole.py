"""The plain pinhole (no distortion): an already rectified camera (KITTI, a `_rect` topic).

EuRoC's sensor.yaml and Kalibr name it `none`; ROS publishes it as `plumb_bob` with D = 0."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from eurocslam.camera_models.base import CameraModel, pixels2, points3
from eurocslam.geometry import F64


def perspective_divide(p_cam: F64) -> tuple[F64, F64, F64]:
    """x/z, y/z and 1/z of points (N, 3); NaN for points not in front (z <= 0)."""
    p = points3(p_cam)
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = np.where(z > 0, 1.0 / z, np.nan)
    return p[:, 0] * inv_z, p[:, 1] * inv_z, inv_z


def divide_jacobian(x: F64, y: F64, inv_z: F64) -> F64:
    """d(x/z, y/z)/d(p): (N, 2, 3)."""
    J = np.zeros((x.shape[0], 2, 3))
    J[:, 0, 0] = inv_z
    J[:, 0, 2] = -x * inv_z
    J[:, 1, 1] = inv_z
    J[:, 1, 2] = -y * inv_z
    return J


def normalised_to_bearing(x: F64, y: F64) -> F64:
    """Unit vectors along (x, y, 1)."""
    b = np.column_stack([x, y, np.ones_like(x)])
    return np.asarray(b / np.linalg.norm(b, axis=1, keepdims=True), dtype=np.float64)


@dataclass(frozen=True)
class Pinhole(CameraModel):
    """u = fx x/z + cx, v = fy y/z + cy."""

    name: ClassVar[str] = "none"
    ros_name: ClassVar[str] = "plumb_bob"
    coeff_counts: ClassVar[tuple[int, ...]] = (0, 4, 5)  # zeros, as KITTI's sensor.yaml writes
    perspective: ClassVar[bool] = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if any(c != 0.0 for c in self.coeffs):
            raise ValueError(f"distortion model 'none' takes no coefficients, got {self.coeffs}")

    def ros_coeffs(self) -> F64:
        return np.zeros(5)

    @property
    def max_angle(self) -> float:
        return float(np.pi / 2)

    def project(self, p_cam: F64) -> F64:
        x, y, _ = perspective_divide(p_cam)
        return np.column_stack([self.fx * x + self.cx, self.fy * y + self.cy])

    def project_jacobian(self, p_cam: F64) -> tuple[F64, F64]:
        x, y, inv_z = perspective_divide(p_cam)
        J = divide_jacobian(x, y, inv_z)
        J[:, 0] *= self.fx
        J[:, 1] *= self.fy
        return np.column_stack([self.fx * x + self.cx, self.fy * y + self.cy]), J

    def unproject(self, uv: F64) -> F64:
        q = pixels2(uv)
        return normalised_to_bearing((q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy)
