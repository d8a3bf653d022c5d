"""Pinhole + radial-tangential distortion: EuRoC's cameras, OpenCV's default model, ROS
`plumb_bob`, Kalibr `pinhole-radtan`. Coefficients k1, k2, p1, p2[, k3] in OpenCV's order.

The distortion acts on the normalised coordinates (x, y) = (X/Z, Y/Z):
r2 = x^2 + y^2, radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3,
x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2), y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y.
Unprojection inverts it by Newton's method (the analytic 2x2 Jacobian), to 1e-12."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from eurocslam.camera_models.base import CameraModel, pixels2
from eurocslam.camera_models.pinhole import (
    divide_jacobian,
    normalised_to_bearing,
    perspective_divide,
)
from eurocslam.geometry import F64

NEWTON_ITERATIONS = 30
NEWTON_TOL = 1e-12  # normalised units (~5e-10 px at EuRoC's focal length)


@dataclass(frozen=True)
class PinholeRadTan(CameraModel):
    name: ClassVar[str] = "radial-tangential"
    ros_name: ClassVar[str] = "plumb_bob"
    coeff_counts: ClassVar[tuple[int, ...]] = (4, 5)
    perspective: ClassVar[bool] = True

    def _k(self) -> tuple[float, float, float, float, float]:
        c = self.coeffs
        return c[0], c[1], c[2], c[3], (c[4] if len(c) > 4 else 0.0)

    def ros_coeffs(self) -> F64:
        d = np.zeros(5)
        d[: len(self.coeffs)] = self.coeffs
        return d

    def distort(self, x: F64, y: F64) -> tuple[F64, F64, F64]:
        """Distorted normalised coordinates (x_d, y_d) and d(x_d, y_d)/d(x, y) (N, 2, 2)."""
        k1, k2, p1, p2, k3 = self._k()
        r2 = x * x + y * y
        rad = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
        drad = k1 + 2 * k2 * r2 + 3 * k3 * r2 * r2  # d radial / d r2
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        J = np.empty((x.shape[0], 2, 2))
        J[:, 0, 0] = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
        J[:, 0, 1] = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
        J[:, 1, 0] = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
        J[:, 1, 1] = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
        return xd, yd, J

    @functools.cached_property
    def _fold_radius(self) -> float:
        """Normalised radius where the radial distortion stops growing (inf: it never does)."""
        k1, k2, _, _, k3 = self._k()
        theta = np.linspace(0.0, np.pi / 2, 4097)[:-1]
        r2 = np.tan(theta) ** 2
        bad = np.nonzero(1 + 3 * k1 * r2 + 5 * k2 * r2 * r2 + 7 * k3 * r2**3 <= 0)[0]
        return float(np.sqrt(r2[bad[0]])) if bad.size else float("inf")

    @property
    def max_angle(self) -> float:
        return float(np.arctan(self._fold_radius))

    def _in_domain(self, x: F64, y: F64) -> NDArray[np.bool_]:
        return np.asarray(x * x + y * y <= self._fold_radius**2, dtype=bool)

    def project(self, p_cam: F64) -> F64:
        x, y, _ = perspective_divide(p_cam)
        xd, yd, _ = self.distort(x, y)
        ok = self._in_domain(x, y)
        return np.column_stack(
            [
                np.where(ok, self.fx * xd + self.cx, np.nan),
                np.where(ok, self.fy * yd + self.cy, np.nan),
            ]
        )

    def project_jacobian(self, p_cam: F64) -> tuple[F64, F64]:
        x, y, inv_z = perspective_divide(p_cam)
        xd, yd, Jd = self.distort(x, y)
        J = Jd @ divide_jacobian(x, y, inv_z)
        J[:, 0] *= self.fx
        J[:, 1] *= self.fy
        ok = self._in_domain(x, y)
        uv = np.column_stack([self.fx * xd + self.cx, self.fy * yd + self.cy])
        uv[~ok] = np.nan
        J[~ok] = np.nan
        return uv, J

    def undistort(self, xd: F64, yd: F64) -> tuple[F64, F64]:
        """Normalised coordinates of distorted ones (Newton); NaN where it does not converge
        or lands beyond the fold."""
        x, y = xd.copy(), yd.copy()
        for _ in range(NEWTON_ITERATIONS):
            fx_, fy_, J = self.distort(x, y)
            ex, ey = fx_ - xd, fy_ - yd
            if not (~((np.abs(ex) <= NEWTON_TOL) & (np.abs(ey) <= NEWTON_TOL))).any():
                break
            det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                x = x - (J[:, 1, 1] * ex - J[:, 0, 1] * ey) / det
                y = y - (-J[:, 1, 0] * ex + J[:, 0, 0] * ey) / det
        fx_, fy_, _ = self.distort(x, y)
        bad = ~(np.abs(fx_ - xd) <= 1e-9) | ~(np.abs(fy_ - yd) <= 1e-9) | ~self._in_domain(x, y)
        x[bad] = np.nan
        y[bad] = np.nan
        return x, y

    def unproject(self, uv: F64) -> F64:
        q = pixels2(uv)
        x, y = self.undistort((q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy)
        return normalised_to_bearing(x, y)
