"""Pinhole + the rational polynomial model: ROS `rational_polynomial`, OpenCV's
`CALIB_RATIONAL_MODEL` (8 coefficients k1, k2, p1, p2, k3, k4, k5, k6 in OpenCV's order), what
wide-angle ROS drivers (depthai, some stereo calibrations) publish in their CameraInfo.

As radial-tangential with the radial factor a ratio:
radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3). Zero coefficients give
the plain pinhole, so OpenCV's pinhole functions (undistort, stereoRectify) take it as it is."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from eurocslam.camera_models.radtan import PinholeRadTan
from eurocslam.geometry import F64


@dataclass(frozen=True)
class PinholeRational(PinholeRadTan):
    name: ClassVar[str] = "rational_polynomial"
    ros_name: ClassVar[str] = "rational_polynomial"
    coeff_counts: ClassVar[tuple[int, ...]] = (8,)
    perspective: ClassVar[bool] = True

    def ros_coeffs(self) -> F64:
        return np.array(self.coeffs, dtype=np.float64)

    def _radial(self, r2: F64) -> tuple[F64, F64]:
        """The radial factor and its derivative d radial / d r2."""
        k1, k2, _, _, k3, k4, k5, k6 = self.coeffs
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
        with np.errstate(divide="ignore", invalid="ignore"):
            return num / den, (dnum * den - num * dden) / (den * den)

    def distort(self, x: F64, y: F64) -> tuple[F64, F64, F64]:
        _, _, p1, p2 = self.coeffs[:4]
        r2 = x * x + y * y
        rad, drad = self._radial(r2)
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
        """Normalised radius where r * radial stops growing or the denominator reaches zero
        (inf: neither happens before 90 degrees)."""
        theta = np.linspace(0.0, np.pi / 2, 4097)[:-1]
        r2 = np.tan(theta) ** 2
        k4, k5, k6 = self.coeffs[5:]
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        rad, drad = self._radial(r2)
        bad = np.nonzero((den <= 0) | ~(rad + 2 * r2 * drad > 0))[0]
        return float(np.sqrt(r2[bad[0]])) if bad.size else float("inf")
