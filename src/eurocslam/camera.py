"""The rectified stereo camera model, shared by the frontend, the backend and the MCAP output.

`rectify_stereo(rig, alpha)` is the one place the rig is rectified (`cv2.stereoRectify`, zero
disparity at infinity): it rotates both cameras to a common orientation (`rect0`, `rect1`) with
one pinhole matrix; rect1 sits at +baseline along rect0's x axis. The frontend rectifies its
images with it and the CameraInfo messages publish its R and P, so both always agree.
A rig that is rectified already (`is_rectified`: KITTI, any pre-rectified pair) is not
rectified again: `passthrough` is set, R is the identity, P is the calibration's own pinhole and
the geometry equals the calibration exactly; the frontend then uses the images as they are.
A rig whose camera models OpenCV's pinhole functions do not cover (a fisheye: `equidistant`) is
rectified through its models (`rectify_by_model`): the same rotations as `cv2.stereoRectify`
(Bouguet's: each camera turned half way, then both onto the baseline) and a pinhole of a chosen
horizontal field of view (`fov_deg`, `frontend.rectify_fov_deg`), capped at the widest whose every
pixel both cameras see (as alpha 0 does for a pinhole rig); the wider, the more of the fisheye's
periphery is kept and the fewer pixels per degree remain at the centre.

`RectifiedStereo` is the geometry the rest of the system works in: stereo measurements
(uL, uR, v) are rectified pixel coordinates, `triangulate_rect` / `project_rect` map them to and
from points in rect0, and the backend uses `T_body_rect0` as its camera extrinsic.
`bucket_select` spreads keypoints over an image grid (feature extraction and the backend's
choice of landmarks both use it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.calib import CameraCalib, StereoRig
from eurocslam.geometry import F64, make_T


@dataclass(frozen=True)
class RectifiedStereo:
    """Rectified stereo geometry: identical pinhole intrinsics for both cameras."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float  # metres, rect1 = rect0 translated by +baseline along x
    width: int
    height: int
    T_body_rect0: F64  # 4x4: rectified cam0 frame -> body (IMU) frame


@dataclass(frozen=True)
class StereoRectification:
    """The result of rectifying a rig with `alpha` (0: only valid pixels, 1: all pixels).

    `R_rect0_cam0` / `R_rect1_cam1` rotate raw camera rays into the rectified frames (ROS's
    CameraInfo R); `P0` / `P1` are the 3x4 projections of the rectified cameras (CameraInfo P;
    P1[0, 3] = -fx * baseline)."""

    alpha: float
    R_rect0_cam0: F64
    R_rect1_cam1: F64
    P0: F64
    P1: F64
    geometry: RectifiedStereo
    passthrough: bool = False  # the rig is rectified already: images are used as they are
    # rectified through the camera models (a fisheye): the rectified pinhole's horizontal field of
    # view [deg], and the widest both cameras allow (the requested one is capped at it)
    fov_deg: float | None = None
    fov_limit_deg: float | None = None


# a rotation or an off-axis translation below this (relative to the baseline) is rounding
RECTIFIED_TOL = 1e-9


def is_rectified(rig: StereoRig) -> bool:
    """The rig is a rectified stereo pair already: identical pinhole intrinsics and resolution,
    no distortion, the same orientation, cam1 beside cam0 along +x only. (A fisheye without
    distortion coefficients is still a fisheye: not a pinhole.)"""
    c0, c1 = rig.cam0, rig.cam1
    if not (c0.model.perspective and c1.model.perspective):
        return False
    if any(d != 0.0 for d in (*c0.distortion, *c1.distortion)):
        return False
    if (c0.fx, c0.fy, c0.cx, c0.cy, c0.resolution) != (c1.fx, c1.fy, c1.cx, c1.cy, c1.resolution):
        return False
    T = rig.T_cam1_cam0
    b = -float(T[0, 3])
    return (
        b > 0.0
        and bool(np.all(np.abs(T[:3, :3] - np.eye(3)) <= RECTIFIED_TOL))
        and abs(float(T[1, 3])) <= RECTIFIED_TOL * b
        and abs(float(T[2, 3])) <= RECTIFIED_TOL * b
    )


def _passthrough(rig: StereoRig, alpha: float) -> StereoRectification:
    """The rectification of an already rectified rig: identity rotations, the calibration's
    pinhole, its baseline (`-T_cam1_cam0[0, 3]`), exactly."""
    c0 = rig.cam0
    b = -float(rig.T_cam1_cam0[0, 3])
    P0 = np.array([[c0.fx, 0.0, c0.cx, 0.0], [0.0, c0.fy, c0.cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
    P1 = P0.copy()
    P1[0, 3] = -c0.fx * b
    geometry = RectifiedStereo(
        fx=c0.fx,
        fy=c0.fy,
        cx=c0.cx,
        cy=c0.cy,
        baseline=b,
        width=c0.width,
        height=c0.height,
        T_body_rect0=np.array(c0.T_body_cam, dtype=np.float64),
    )
    return StereoRectification(float(alpha), np.eye(3), np.eye(3), P0, P1, geometry, True)


# the rectified pinhole's horizontal field of view for a rig rectified through its camera models
# (a fisheye): benchmarks/RESULTS.md, "Fisheye rigs", measures the choice
DEFAULT_RECTIFY_FOV_DEG = 120.0


def rectify_stereo(
    rig: StereoRig, alpha: float = 0.0, fov_deg: float | None = None, size: str = "image"
) -> StereoRectification:
    """Rectify the stereo pair of `rig` (zero disparity at infinity): with `cv2.stereoRectify`
    and `alpha` for pinhole cameras, through the camera models to a pinhole of `fov_deg` degrees
    (default `DEFAULT_RECTIFY_FOV_DEG`; 0: `centre_keeping_fov_deg`) and `rectified_size(size)`
    for others (a fisheye); a rig
    that `is_rectified` already is passed through (`alpha`, `fov_deg`, `size` then change
    nothing)."""
    if is_rectified(rig):
        return _passthrough(rig, alpha)
    if not (rig.cam0.model.perspective and rig.cam1.model.perspective):
        fov = DEFAULT_RECTIFY_FOV_DEG if fov_deg is None else fov_deg
        if fov == 0.0:
            fov = centre_keeping_fov_deg(rig)
        return rectify_by_model(rig, fov, alpha, size)
    c0, c1 = rig.cam0, rig.cam1
    T_cam1_cam0 = rig.T_cam1_cam0
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(
        c0.K,
        c0.D,
        c1.K,
        c1.D,
        (c0.width, c0.height),
        T_cam1_cam0[:3, :3].copy(),
        T_cam1_cam0[:3, 3].reshape(3, 1).copy(),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=alpha,
    )
    # float64 already (asarray returns the same arrays); typed for the checker
    R1, R2 = np.asarray(r1, dtype=np.float64), np.asarray(r2, dtype=np.float64)
    P1, P2 = np.asarray(p1, dtype=np.float64), np.asarray(p2, dtype=np.float64)
    geometry = RectifiedStereo(
        fx=float(P1[0, 0]),
        fy=float(P1[1, 1]),
        cx=float(P1[0, 2]),
        cy=float(P1[1, 2]),
        baseline=float(-P2[0, 3] / P2[0, 0]),
        width=c0.width,
        height=c0.height,
        T_body_rect0=c0.T_body_cam @ make_T(R1.T, np.zeros(3)),
    )
    return StereoRectification(float(alpha), R1, R2, P1, P2, geometry)


def centre_keeping_fov_deg(rig: StereoRig) -> float:
    """The horizontal field of view [deg] at which a pinhole as wide as cam0's image has cam0's
    own focal length: the rectified image then neither magnifies nor shrinks the fisheye's
    centre (TUM-VI: 106.6 degrees). `rectify_fov_deg: 0` asks for it."""
    c0 = rig.cam0
    return float(np.degrees(2.0 * np.arctan(c0.width / (2.0 * c0.fx))))


def rectifying_rotations(T_cam1_cam0: F64) -> tuple[F64, F64]:
    """`R_rect0_cam0`, `R_rect1_cam1`: Bouguet's rectification, as `cv2.stereoRectify` computes
    it (each camera turned half the relative rotation, then both onto the baseline)."""
    R = np.asarray(T_cam1_cam0[:3, :3], dtype=np.float64)
    t = np.asarray(T_cam1_cam0[:3, 3], dtype=np.float64)
    om, _ = cv2.Rodrigues(R)
    r_r, _ = cv2.Rodrigues(-0.5 * om)
    tt = r_r @ t
    idx = 0 if abs(tt[0]) > abs(tt[1]) else 1
    uu = np.zeros(3)
    uu[idx] = 1.0 if tt[idx] > 0 else -1.0
    ww = np.cross(tt, uu)
    nw = float(np.linalg.norm(ww))
    if nw > 0.0:
        ww *= np.arccos(abs(tt[idx]) / np.linalg.norm(tt)) / nw
    wR, _ = cv2.Rodrigues(ww)
    return np.asarray(wR @ r_r.T, dtype=np.float64), np.asarray(wR @ r_r, dtype=np.float64)


def fov_pinhole(fov_deg: float, width: int, height: int) -> F64:
    """3x4 P of a pinhole whose `width` pixels span `fov_deg` degrees, centred on the image."""
    f = (width / 2.0) / np.tan(np.radians(fov_deg) / 2.0)
    return np.array(
        [[f, 0.0, (width - 1) / 2.0, 0.0], [0.0, f, (height - 1) / 2.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    )


def rect_border(width: int, height: int) -> F64:
    """Every pixel on the border of a width x height image (N, 2)."""
    u = np.arange(width, dtype=np.float64)
    v = np.arange(height, dtype=np.float64)
    return np.vstack(
        [
            np.column_stack([u, np.zeros_like(u)]),
            np.column_stack([u, np.full_like(u, height - 1.0)]),
            np.column_stack([np.zeros_like(v), v]),
            np.column_stack([np.full_like(v, width - 1.0), v]),
        ]
    )


def rect_to_raw(uv_rect: F64, P: F64, R_rect_cam: F64, cam: CameraCalib) -> F64:
    """Raw pixels (N, 2) of a rectified camera's pixels (NaN where the camera has no ray)."""
    uv = np.asarray(uv_rect, dtype=np.float64).reshape(-1, 2)
    rays = np.column_stack(
        [(uv[:, 0] - P[0, 2]) / P[0, 0], (uv[:, 1] - P[1, 2]) / P[1, 1], np.ones(len(uv))]
    )
    return cam.model.project(rays @ R_rect_cam)  # R^T applied to row vectors


def _sees_whole_border(rig: StereoRig, fov_deg: float, R0: F64, R1: F64) -> bool:
    """Every border pixel of both rectified images (cam0's size) has a raw pixel inside its
    camera's image."""
    w, h = rig.cam0.width, rig.cam0.height
    P = fov_pinhole(fov_deg, w, h)
    border = rect_border(w, h)
    for cam, R in ((rig.cam0, R0), (rig.cam1, R1)):
        raw = rect_to_raw(border, P, R, cam)
        inside = (
            np.isfinite(raw).all(axis=1)
            & (raw[:, 0] >= 0.0)
            & (raw[:, 0] <= cam.width - 1.0)
            & (raw[:, 1] >= 0.0)
            & (raw[:, 1] <= cam.height - 1.0)
        )
        if not inside.all():
            return False
    return True


def widest_fov_deg(rig: StereoRig, R0: F64, R1: F64) -> float:
    """The widest horizontal field of view [deg] (to 0.01 deg) whose rectified images both
    cameras see entirely (bisection; the pinhole's field of view stays below 180)."""
    lo, hi = 1.0, 179.0
    if not _sees_whole_border(rig, lo, R0, R1):
        return lo
    while hi - lo > 0.01:
        mid = 0.5 * (lo + hi)
        if _sees_whole_border(rig, mid, R0, R1):
            lo = mid
        else:
            hi = mid
    return lo


# how big the rectified image of a rig rectified through its models is (`rectified_size`)
RECTIFY_SIZES = ("image", "focal")


def rectified_size(rig: StereoRig, fov_deg: float, size: str) -> tuple[int, int]:
    """The rectified image's width and height: "image", cam0's raw image size (the focal length
    then follows from the field of view); "focal", the size at which the rectified pinhole keeps
    cam0's own focal length (its centre's resolution), growing with the field of view."""
    c0 = rig.cam0
    if size == "image":
        return c0.width, c0.height
    if size != "focal":
        raise ValueError(f"rectified size '{size}' unknown (known: {', '.join(RECTIFY_SIZES)})")
    w = round(2.0 * c0.fx * np.tan(np.radians(fov_deg) / 2.0))
    return w, round(w * c0.height / c0.width)


def rectify_by_model(
    rig: StereoRig, fov_deg: float, alpha: float = 0.0, size: str = "image"
) -> StereoRectification:
    """Rectify through the camera models: Bouguet's rotations, a pinhole of `fov_deg` degrees
    (capped at `widest_fov_deg`) for both rectified cameras, of `rectified_size(size)`."""
    c0 = rig.cam0
    T = rig.T_cam1_cam0
    R0, R1 = rectifying_rotations(T)
    limit = widest_fov_deg(rig, R0, R1)
    fov = min(float(fov_deg), limit)
    width, height = rectified_size(rig, fov, size)
    P0 = fov_pinhole(fov, width, height)
    t_rect = R1 @ T[:3, 3]  # cam0's origin in rect1: along -x by the baseline
    b = float(np.linalg.norm(t_rect))
    P1 = P0.copy()
    P1[0, 3] = -P0[0, 0] * b
    geometry = RectifiedStereo(
        fx=float(P0[0, 0]),
        fy=float(P0[1, 1]),
        cx=float(P0[0, 2]),
        cy=float(P0[1, 2]),
        baseline=b,
        width=width,
        height=height,
        T_body_rect0=c0.T_body_cam @ make_T(R0.T, np.zeros(3)),
    )
    return StereoRectification(float(alpha), R0, R1, P0, P1, geometry, False, fov, limit)


def triangulate_rect(uL: F64, uR: F64, v: F64, geom: RectifiedStereo) -> F64:
    """Points (N, 3) in the rect0 frame from rectified stereo measurements."""
    d = np.asarray(uL, dtype=np.float64) - np.asarray(uR, dtype=np.float64)
    z = geom.fx * geom.baseline / d
    x = (np.asarray(uL) - geom.cx) * z / geom.fx
    y = (np.asarray(v) - geom.cy) * z / geom.fy
    return np.column_stack([x, y, z])


def project_rect(p_rect0: F64, geom: RectifiedStereo) -> F64:
    """Stereo measurements (N, 3) = (uL, uR, v) of points (N, 3) in the rect0 frame."""
    p = np.asarray(p_rect0, dtype=np.float64)
    inv_z = 1.0 / p[:, 2]
    uL = geom.fx * p[:, 0] * inv_z + geom.cx
    uR = geom.fx * (p[:, 0] - geom.baseline) * inv_z + geom.cx
    v = geom.fy * p[:, 1] * inv_z + geom.cy
    return np.column_stack([uL, uR, v])


def bucket_select(
    uv: F64, response: F64, n: int, width: int, height: int, cols: int, rows: int
) -> NDArray[np.intp]:
    """Indices of at most `n` keypoints spread over a cols x rows grid, strongest first per cell."""
    if uv.shape[0] <= n:
        return np.argsort(-response, kind="stable")
    cx = np.clip((uv[:, 0] * cols / width).astype(np.int64), 0, cols - 1)
    cy = np.clip((uv[:, 1] * rows / height).astype(np.int64), 0, rows - 1)
    cell = cy * cols + cx
    # sort by cell, then by descending response; rank inside the cell
    order = np.lexsort((-response, cell))
    cell_sorted = cell[order]
    first = np.searchsorted(cell_sorted, cell_sorted, side="left")
    rank = np.arange(order.size) - first
    # round-robin: rank 0 of every cell (strongest first), then rank 1, ...
    pick = np.lexsort((-response[order], rank))
    return order[pick[:n]]
