"""Pinhole + equidistant distortion, i.e. Kannala-Brandt with 4 coefficients: TUM-VI's and
UZH-FPV's fisheyes, Kalibr `pinhole-equi`, OpenCV `cv2.fisheye`, ROS `equidistant`.

A ray at angle theta from the optical axis lands at the normalised radius
theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8), in the ray's azimuth:
(x_d, y_d) = theta_d (X, Y) / sqrt(X^2 + Y^2), u = fx x_d + cx. It is defined beyond 90 degrees
(behind the camera's image plane), up to `max_angle`, where theta_d stops growing (at most 180).
Unprojection solves theta_d(theta) by Newton's method, as cv2.fisheye.undistortPoints does."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from eurocslam.camera_models.base import CameraModel, pixels2, points3
from eurocslam.geometry import F64

NEWTON_ITERATIONS = 30
NEWTON_TOL = 1e-13  # rad
SMALL_RADIUS = 1e-9  # r / |p| below this: the optical axis (the limit x/z, y/z)


@dataclass(frozen=True)
class PinholeEquidistant(CameraModel):
    name: ClassVar[str] = "equidistant"
    ros_name: ClassVar[str] = "equidistant"
    coeff_counts: ClassVar[tuple[int, ...]] = (4,)
    perspective: ClassVar[bool] = False

    def theta_d(self, theta: F64) -> tuple[F64, F64]:
        """theta_d(theta) and its derivative."""
        k1, k2, k3, k4 = self.coeffs
        t2 = theta * theta
        poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        return theta * poly, dpoly

    @functools.cached_property
    def _max_angle(self) -> float:
        theta = np.linspace(0.0, np.pi, 4097)
        _, d = self.theta_d(theta)
        bad = np.nonzero(d <= 0)[0]
        return float(theta[bad[0] - 1]) if bad.size else float(np.pi)

    @property
    def max_angle(self) -> float:
        return self._max_angle

    @functools.cached_property
    def max_theta_d(self) -> float:
        """The normalised radius at `max_angle`: farther pixels have no ray."""
        return float(self.theta_d(np.array([self._max_angle]))[0][0])

    def project(self, p_cam: F64) -> F64:
        return self.project_jacobian(p_cam, jacobian=False)[0]

    def project_jacobian(self, p_cam: F64, jacobian: bool = True) -> tuple[F64, F64]:
        p = points3(p_cam)
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        r2 = x * x + y * y
        rho2 = r2 + z * z
        r = np.sqrt(r2)
        theta = np.arctan2(r, z)
        td, dtd = self.theta_d(theta)
        axis = r <= SMALL_RADIUS * np.sqrt(rho2)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(axis, 1.0 / z, td / r)  # theta_d / r (-> 1/z on the axis)
        xd, yd = s * x, s * y
        uv = np.column_stack([self.fx * xd + self.cx, self.fy * yd + self.cy])
        out = ~(theta <= self._max_angle) | (rho2 == 0)
        uv[out] = np.nan
        if not jacobian:
            return uv, np.zeros((0, 2, 3))
        J = np.zeros((p.shape[0], 2, 3))
        with np.errstate(divide="ignore", invalid="ignore"):
            a = dtd * z / (r2 * rho2)  # g' z / (r^2 rho^2)
            b = td / (r2 * r)  # g / r^3
            J[:, 0, 0] = a * x * x + b * y * y
            J[:, 0, 1] = (a - b) * x * y
            J[:, 0, 2] = -dtd * x / rho2
            J[:, 1, 0] = (a - b) * x * y
            J[:, 1, 1] = a * y * y + b * x * x
            J[:, 1, 2] = -dtd * y / rho2
        if axis.any():  # the pinhole's limit: d(x/z, y/z)/dp
            iz = 1.0 / z[axis]
            J[axis] = 0.0
            J[axis, 0, 0] = iz
            J[axis, 1, 1] = iz
            J[axis, 0, 2] = -x[axis] * iz * iz
            J[axis, 1, 2] = -y[axis] * iz * iz
        J[:, 0] *= self.fx
        J[:, 1] *= self.fy
        J[out] = np.nan
        return uv, J

    def unproject(self, uv: F64) -> F64:
        q = pixels2(uv)
        mx, my = (q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy
        td = np.sqrt(mx * mx + my * my)
        inside = td <= self.max_theta_d
        theta = np.minimum(td, self._max_angle)
        for _ in range(NEWTON_ITERATIONS):
            f, df = self.theta_d(theta)
            step = (f - td) / df
            theta = np.clip(theta - step, 0.0, self._max_angle)
            if not (np.abs(step[inside]) > NEWTON_TOL).any():
                break
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(td > 0, np.sin(theta) / td, 1.0)
        b = np.column_stack([s * mx, s * my, np.cos(theta)])
        b[~inside] = np.nan
        return b
