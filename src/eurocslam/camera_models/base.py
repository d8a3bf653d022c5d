"""The camera model interface: how a camera maps 3D points to pixels and pixels to rays.

A model holds the intrinsics (`fx, fy, cx, cy`, pixel centres at integer coordinates as in
OpenCV) and its distortion coefficients. Every method is vectorised over N points:

- `project(p)`: points (N, 3) in the camera frame -> pixels (N, 2); NaN for a point outside the
  model's domain (behind a pinhole camera, beyond `max_angle` from the optical axis);
- `project_jacobian(p)`: the pixels and d(pixel)/d(point) (N, 2, 3);
- `unproject(uv)`: pixels (N, 2) -> unit bearing vectors (N, 3); NaN outside the valid region;
- `unproject_jacobian(uv)`: the bearings and d(bearing)/d(pixel) (N, 3, 2), tangent to the unit
  sphere (derived here from the projection's Jacobian, so a model need not write its own);
- the valid image region: `max_angle` (the largest angle from the optical axis the model maps
  one to one), `valid(uv)` and `valid_mask(width, height)`.

A model is one module: a frozen dataclass deriving `CameraModel`, named by `name` (the
`distortion_model` of EuRoC's sensor.yaml), `ros_name` (sensor_msgs/CameraInfo's), the numbers of
coefficients it takes and whether zero coefficients make it the plain pinhole (`perspective`:
then OpenCV's pinhole functions apply to it). `camera_models/__init__.py` lists the models.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64


def points3(p: F64) -> F64:
    """(N, 3) float64 view of points."""
    return np.asarray(p, dtype=np.float64).reshape(-1, 3)


def pixels2(uv: F64) -> F64:
    """(N, 2) float64 view of pixels."""
    return np.asarray(uv, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class CameraModel(ABC):
    """Intrinsics plus distortion of one camera (see the module docstring)."""

    fx: float
    fy: float
    cx: float
    cy: float
    coeffs: tuple[float, ...] = ()

    name: ClassVar[str]  # distortion_model in EuRoC's sensor.yaml ("radial-tangential", ...)
    ros_name: ClassVar[str]  # sensor_msgs/CameraInfo distortion_model ("plumb_bob", ...)
    coeff_counts: ClassVar[tuple[int, ...]]  # accepted numbers of distortion coefficients
    perspective: ClassVar[bool]  # zero coefficients give the plain pinhole

    def __post_init__(self) -> None:
        if len(self.coeffs) not in self.coeff_counts:
            counts = " or ".join(str(n) for n in self.coeff_counts)
            raise ValueError(
                f"distortion model '{self.name}' takes {counts} coefficients, "
                f"got {len(self.coeffs)}"
            )

    @property
    def K(self) -> F64:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def ros_coeffs(self) -> F64:
        """The coefficients as sensor_msgs/CameraInfo's D for `ros_name`."""
        return np.array(self.coeffs, dtype=np.float64)

    # ---- the model --------------------------------------------------------------------------
    @abstractmethod
    def project(self, p_cam: F64) -> F64:
        """Pixels (N, 2) of points (N, 3) in the camera frame; NaN outside the domain."""

    @abstractmethod
    def project_jacobian(self, p_cam: F64) -> tuple[F64, F64]:
        """Pixels (N, 2) and their Jacobian d(uv)/d(p) (N, 2, 3); NaN outside the domain."""

    @abstractmethod
    def unproject(self, uv: F64) -> F64:
        """Unit bearing vectors (N, 3) of pixels (N, 2); NaN outside the valid region."""

    @property
    @abstractmethod
    def max_angle(self) -> float:
        """The largest angle [rad] from the optical axis that the model maps one to one."""

    # ---- derived ----------------------------------------------------------------------------
    def unproject_jacobian(self, uv: F64) -> tuple[F64, F64]:
        """Bearings (N, 3) and d(bearing)/d(uv) (N, 3, 2).

        The projection maps the bearing b back to uv, so J_proj(b) @ J_unproj = I; the bearing
        stays on the unit sphere, so b . J_unproj = 0. With T a basis of the tangent plane at b,
        J_unproj = T (J_proj T)^-1 satisfies both."""
        b = self.unproject(uv)
        _, Jp = self.project_jacobian(np.nan_to_num(b, nan=0.0) + np.isnan(b) * [0, 0, 1.0])
        T = tangent_basis(b)  # (N, 3, 2)
        A = Jp @ T  # (N, 2, 2)
        J = T @ np.linalg.inv(A)
        J[np.isnan(b[:, 0])] = np.nan
        return b, J

    def angle_of(self, uv: F64) -> F64:
        """The angle [rad] of each pixel's ray from the optical axis (NaN outside)."""
        b = self.unproject(uv)
        return np.asarray(np.arccos(np.clip(b[:, 2], -1.0, 1.0)), dtype=np.float64)

    def valid(self, uv: F64) -> NDArray[np.bool_]:
        """Pixels whose ray the model gives (within `max_angle`, the unprojection converged)."""
        b = self.unproject(uv)
        return np.asarray(np.isfinite(b).all(axis=1), dtype=bool)

    def valid_mask(self, width: int, height: int) -> NDArray[np.bool_]:
        """(height, width) mask of the pixels `valid` over a whole image."""
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        return self.valid(np.column_stack([u.ravel(), v.ravel()])).reshape(height, width)


def tangent_basis(b: F64) -> F64:
    """(N, 3, 2): two orthonormal vectors perpendicular to each unit vector b (N, 3)."""
    b = np.nan_to_num(points3(b), nan=0.0)
    # a helper axis not parallel to b: x, unless b is mostly along x
    helper = np.zeros_like(b)
    along_x = np.abs(b[:, 0]) > 0.9
    helper[~along_x, 0] = 1.0
    helper[along_x, 1] = 1.0
    t1 = np.cross(b, helper)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
    t2 = np.cross(b, t1)
    return np.stack([t1, t2], axis=2)
