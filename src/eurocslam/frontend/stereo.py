"""Rectifying stereo images, and raw <-> rectified point mapping.

The rectification itself (R, P of both cameras and the `RectifiedStereo` geometry) comes from
`eurocslam.camera.rectify_stereo`, the same function the CameraInfo messages use. Remap tables
are computed once. A rig that is rectified already (`rectification.passthrough`) is not
remapped: its images are used as they are and points map to themselves. Pinhole cameras use
OpenCV's pinhole functions (`cv2.initUndistortRectifyMap`, iterated `cv2.undistortPoints`);
other models (a fisheye) their own `project` / `unproject` (`CameraCalib.model`).
"""

from __future__ import annotations

from typing import cast

import cv2
import numpy as np

from eurocslam.camera import rect_to_raw, rectify_stereo
from eurocslam.dataset.calib import CameraCalib, StereoRig
from eurocslam.dataset.types import U8
from eurocslam.frontend.config import FrontendConfig
from eurocslam.geometry import F64

# The keypoint noise a rectification's stretch adds, per rectified pixel of stretch beyond one,
# relative to the noise of a keypoint at pyramid scale 1 (`StereoRectifier.keypoint_sigma`):
# measured 0.49-0.64 (u and v, two worlds of the MH_03 TUM-VI replica, residuals of tracked
# keypoints against landmarks triangulated from ground-truth poses); 1/sqrt(3)
RESAMPLING_SIGMA = 3.0**-0.5


class StereoRectifier:
    """Rectifies stereo pairs of one rig. Thread-safe after construction (read-only maps)."""

    def __init__(
        self,
        rig: StereoRig,
        alpha: float = 0.0,
        fov_deg: float | None = None,
        rect_size: str = "image",
    ) -> None:
        c0, c1 = rig.cam0, rig.cam1
        self.rig = rig
        self.rectification = rect = rectify_stereo(rig, alpha, fov_deg, rect_size)
        size = (rect.geometry.width, rect.geometry.height)  # the rectified images' size
        self._by_model = not (c0.model.perspective and c1.model.perspective)
        self.R_rect0_cam0: F64 = rect.R_rect0_cam0
        self.R_rect1_cam1: F64 = rect.R_rect1_cam1
        self.P0: F64 = rect.P0
        self.P1: F64 = rect.P1
        self.geometry = rect.geometry
        self.passthrough = rect.passthrough
        self._map0: tuple[np.ndarray, np.ndarray] | None = None
        self._map1: tuple[np.ndarray, np.ndarray] | None = None
        # rectified pixels per raw pixel over rect0 (None: about one everywhere, a pinhole rig)
        self._stretch: F64 | None = None
        if self._by_model:
            self._map0 = model_rectify_map(c0, rect.R_rect0_cam0, rect.P0, size)
            self._map1 = model_rectify_map(c1, rect.R_rect1_cam1, rect.P1, size)
            self._stretch = rect_stretch(c0, rect.R_rect0_cam0, rect.P0, size)
        elif not self.passthrough:
            self._map0 = cv2.initUndistortRectifyMap(
                c0.K, c0.D, rect.R_rect0_cam0, rect.P0, size, cv2.CV_16SC2
            )
            self._map1 = cv2.initUndistortRectifyMap(
                c1.K, c1.D, rect.R_rect1_cam1, rect.P1, size, cv2.CV_16SC2
            )
        self._size = size

    @classmethod
    def for_config(cls, rig: StereoRig, config: FrontendConfig) -> StereoRectifier:
        """The rig rectified as the frontend's configuration asks (`rectify_*`)."""
        return cls(rig, config.rectify_alpha, config.rectify_fov_deg, config.rectify_size)

    @property
    def size(self) -> tuple[int, int]:
        return self._size

    def sigma_scale(self, uv_rect: F64) -> F64:
        """How many rectified pixels one raw pixel spans at each rectified cam0 point, at least
        1 (the resampling stretch: a fisheye rectified to a pinhole stretches its raw pixels
        over 1.3-3 rectified ones, TUM-VI at 90-120 degrees); 1 for a pinhole rig, whose
        rectification resamples about one to one. `keypoint_sigma` turns it into a sigma."""
        uv = np.asarray(uv_rect, dtype=np.float64).reshape(-1, 2)
        if self._stretch is None:
            return np.ones(len(uv))
        h, w = self._stretch.shape
        col = np.clip(np.rint(uv[:, 0]).astype(np.intp), 0, w - 1)
        row = np.clip(np.rint(uv[:, 1]).astype(np.intp), 0, h - 1)
        return np.asarray(np.maximum(self._stretch[row, col], 1.0), dtype=np.float64)

    def keypoint_sigma(self, octave_sigma: F64, uv_rect: F64) -> F64:
        """The pixel sigma (in units of `backend.stereo_sigma_px`) of rectified cam0 keypoints
        detected at pyramid scales `octave_sigma`: sqrt(octave^2 + RESAMPLING_SIGMA^2 (s^2 - 1))
        with s the resampling stretch (`sigma_scale`). A keypoint is located in the rectified
        image it was detected on, to a fraction of a pixel of its pyramid level (the octave
        scale, as on a pinhole rig), not of the raw pixel: the stretch only adds its part in
        quadrature. The octave scale alone where s = 1, so a pinhole rig's sigmas are the octave
        scales exactly (EuRoC unchanged). RESULTS.md "Fisheye rigs": on the TUM-VI rig the
        error of tracked keypoints against ground-truth poses is 0.32-0.33 x octave rectified
        pixels wherever s < 1.15 and grows by 1.37x (not the 2x of octave x s) at s = 2."""
        o = np.asarray(octave_sigma, dtype=np.float64)
        if self._stretch is None:
            return o
        s = self.sigma_scale(uv_rect)
        return cast(F64, np.sqrt(o * o + RESAMPLING_SIGMA**2 * (s * s - 1.0)))

    def rectify_left(self, img: U8) -> U8:
        if self._map0 is None:  # rectified already
            return img
        return np.asarray(cv2.remap(img, self._map0[0], self._map0[1], cv2.INTER_LINEAR))

    def rectify_right(self, img: U8) -> U8:
        if self._map1 is None:
            return img
        return np.asarray(cv2.remap(img, self._map1[0], self._map1[1], cv2.INTER_LINEAR))

    def raw_to_rect0(self, uv_raw: F64) -> F64:
        """Raw (distorted) cam0 pixels (N, 2) -> rectified rect0 pixels (N, 2)."""
        c0 = self.rig.cam0
        pts = np.asarray(uv_raw, dtype=np.float64).reshape(-1, 1, 2)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        if self.passthrough:
            return cast(F64, pts.reshape(-1, 2).copy())
        if self._by_model:
            return raw_to_rect(pts.reshape(-1, 2), c0, self.R_rect0_cam0, self.P0)
        out = undistort_points(pts, c0.K, c0.D, self.R_rect0_cam0, self.P0)
        return np.asarray(out.reshape(-1, 2), dtype=np.float64)

    def rect0_to_raw(self, uv_rect: F64) -> F64:
        """Rectified rect0 pixels (N, 2) -> raw (distorted) cam0 pixels (N, 2)."""
        uv = np.asarray(uv_rect, dtype=np.float64).reshape(-1, 2)
        if uv.shape[0] == 0:
            return np.zeros((0, 2))
        if self.passthrough:
            return cast(F64, uv.copy())
        if self._by_model:
            return rect_to_raw(uv, self.P0, self.R_rect0_cam0, self.rig.cam0)
        g = self.geometry
        rays_rect = np.column_stack(
            [(uv[:, 0] - g.cx) / g.fx, (uv[:, 1] - g.cy) / g.fy, np.ones(len(uv))]
        )
        rays_cam0 = rays_rect @ self.R_rect0_cam0  # R^T applied to row vectors
        c0 = self.rig.cam0
        out, _ = cv2.projectPoints(rays_cam0, np.zeros(3), np.zeros(3), c0.K, c0.D)
        return np.asarray(out.reshape(-1, 2), dtype=np.float64)


def undistort_points(pts: F64, K: F64, D: F64, R: F64, P: F64) -> F64:
    """`cv2.undistortPoints` iterated to convergence (its default 5 iterations leave up to
    0.2 px in EuRoC's image corners)."""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9)
    return np.asarray(cv2.undistortPoints(pts, K, D, R=R, P=P, criteria=crit), dtype=np.float64)


def model_rectify_map(
    cam: CameraCalib, R_rect_cam: F64, P: F64, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """`cv2.remap` tables (CV_16SC2, as `cv2.initUndistortRectifyMap` gives) from a rectified
    camera's pixels to its raw pixels, through `cam.model`; pixels without a ray read outside
    the image (black)."""
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    raw = rect_to_raw(np.column_stack([u.ravel(), v.ravel()]), P, R_rect_cam, cam)
    raw = np.where(np.isfinite(raw), raw, -1.0)
    mx = raw[:, 0].reshape(h, w).astype(np.float32)
    my = raw[:, 1].reshape(h, w).astype(np.float32)
    m1, m2 = cv2.convertMaps(mx, my, cv2.CV_16SC2)
    return np.asarray(m1), np.asarray(m2)


def raw_to_rect(uv_raw: F64, cam: CameraCalib, R_rect_cam: F64, P: F64) -> F64:
    """Rectified pixels (N, 2) of raw pixels, through `cam.model` (NaN for a ray the rectified
    pinhole cannot see: behind its image plane)."""
    rays = cam.model.unproject(uv_raw) @ R_rect_cam.T
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = np.where(rays[:, 2] > 0, 1.0 / rays[:, 2], np.nan)
    return np.column_stack(
        [P[0, 0] * rays[:, 0] * inv_z + P[0, 2], P[1, 1] * rays[:, 1] * inv_z + P[1, 2]]
    )


def rect_stretch(cam: CameraCalib, R_rect_cam: F64, P: F64, size: tuple[int, int]) -> F64:
    """(h, w) map of rectified pixels per raw pixel (the square root of the area ratio) over a
    rectified camera's image, from the model's projection Jacobian."""
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays_rect = np.column_stack(
        [(u.ravel() - P[0, 2]) / P[0, 0], (v.ravel() - P[1, 2]) / P[1, 1], np.ones(u.size)]
    )
    _, J = cam.model.project_jacobian(rays_rect @ R_rect_cam)  # d raw / d ray_cam (N, 2, 3)
    # d ray_cam / d (u, v) = R^T [[1/fx, 0], [0, 1/fy], [0, 0]]
    D = R_rect_cam.T[:, :2] / np.array([P[0, 0], P[1, 1]])
    A = J @ D  # d raw / d rect (N, 2, 2)
    det = np.abs(A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        stretch = 1.0 / np.sqrt(det)
    return np.asarray(np.nan_to_num(stretch, nan=1.0, posinf=1.0).reshape(h, w), dtype=np.float64)
