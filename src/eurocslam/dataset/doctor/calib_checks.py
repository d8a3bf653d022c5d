"""Plausibility checks of a calibration, shared by `eurocslam doctor` and the loaders.

Each check returns `CalibIssue`s: `error` for values that cannot be a calibration (the loaders
refuse them: `raise_errors`), `warning` for values that are possible but implausible for a
stereo-inertial rig (the doctor reports them). The loaders in `dataset/calib.py` only read and
build calibrations; what is plausible is decided here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.dataset.rig import CameraCalib, ImuCalib, StereoRig
from eurocslam.errors import CalibrationError
from eurocslam.geometry import F64, inv_T


@dataclass(frozen=True)
class CalibIssue:
    """A problem with a calibration value. `error`: cannot be a calibration; `warning`: possible
    but implausible for a stereo-inertial rig."""

    severity: str  # "error" | "warning"
    key: str
    message: str


def raise_errors(issues: list[CalibIssue], path: Path | str) -> None:
    for i in issues:
        if i.severity == "error":
            raise CalibrationError(f"{path}: key '{i.key}': {i.message}")


def check_transform(T: F64, key: str = "T_BS") -> list[CalibIssue]:
    """A rigid transform: bottom row [0 0 0 1], rotation orthonormal with determinant +1."""
    out: list[CalibIssue] = []
    T = np.asarray(T, dtype=np.float64)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        out.append(CalibIssue("error", key, f"bottom row must be [0, 0, 0, 1], is {T[3].tolist()}"))
    R = T[:3, :3]
    dev = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if det < 0:
        out.append(CalibIssue("error", key, f"rotation has determinant {det:.4f} (a reflection)"))
    elif dev > 1e-2:
        out.append(
            CalibIssue("error", key, f"rotation is not orthonormal (|R^T R - I| = {dev:.2g})")
        )
    elif dev > 1e-4:
        out.append(
            CalibIssue(
                "warning", key, f"rotation is only roughly orthonormal (|R^T R - I| = {dev:.2g})"
            )
        )
    if float(np.linalg.norm(T[:3, 3])) > 10.0:
        out.append(
            CalibIssue(
                "warning",
                key,
                f"translation {np.linalg.norm(T[:3, 3]):.2f} m is implausible "
                "for a sensor on one rig (units mm instead of m?)",
            )
        )
    return out


def radial_fold_radius(k: tuple[float, ...], r_max: float) -> float | None:
    """Smallest normalised radius <= r_max where radial distortion stops growing (folds back),
    or None. `k` holds k1, k2[, p1, p2, k3] in OpenCV order."""
    k1 = k[0] if len(k) > 0 else 0.0
    k2 = k[1] if len(k) > 1 else 0.0
    k3 = k[4] if len(k) > 4 else 0.0
    r = np.linspace(0.0, r_max, 512)
    r2 = r * r
    deriv = 1 + 3 * k1 * r2 + 5 * k2 * r2 * r2 + 7 * k3 * r2 * r2 * r2
    bad = np.nonzero(deriv <= 0)[0]
    return float(r[bad[0]]) if bad.size else None


def check_camera(cam: CameraCalib) -> list[CalibIssue]:
    """Intrinsics and extrinsics sanity (errors: impossible values; warnings: implausible ones)."""
    out = check_transform(cam.T_body_cam)
    w, h = cam.width, cam.height
    if w <= 0 or h <= 0:
        out.append(CalibIssue("error", "resolution", f"must be positive, is [{w}, {h}]"))
        return out
    if cam.rate_hz <= 0:
        out.append(CalibIssue("error", "rate_hz", f"must be positive, is {cam.rate_hz:g}"))
    elif cam.rate_hz > 1000:
        out.append(
            CalibIssue("warning", "rate_hz", f"{cam.rate_hz:g} Hz is implausible for a camera")
        )
    if cam.fx <= 0 or cam.fy <= 0:
        out.append(
            CalibIssue(
                "error", "intrinsics", f"focal lengths must be positive, are {cam.fx:g}, {cam.fy:g}"
            )
        )
        return out
    if not (0 <= cam.cx <= w and 0 <= cam.cy <= h):
        out.append(
            CalibIssue(
                "error",
                "intrinsics",
                f"principal point ({cam.cx:g}, {cam.cy:g}) lies outside the {w}x{h} image",
            )
        )
    elif abs(cam.cx - w / 2) > 0.2 * w or abs(cam.cy - h / 2) > 0.2 * h:
        out.append(
            CalibIssue(
                "warning",
                "intrinsics",
                f"principal point ({cam.cx:g}, {cam.cy:g}) is far "
                f"from the image centre ({w / 2:g}, {h / 2:g})",
            )
        )
    if not 0.8 <= cam.fx / cam.fy <= 1.25:
        out.append(
            CalibIssue(
                "warning", "intrinsics", f"fx/fy = {cam.fx / cam.fy:.3f}: pixels far from square"
            )
        )
    try:
        model = cam.model
    except ValueError as e:  # a model the coefficients do not fit
        out.append(CalibIssue("error", "distortion_coefficients", str(e)))
        return out
    if model.perspective:
        out += _perspective_issues(cam)
    else:
        out += _fisheye_issues(cam)
    return out


def _perspective_issues(cam: CameraCalib) -> list[CalibIssue]:
    """Field of view and radial-tangential coefficients of a pinhole camera."""
    out: list[CalibIssue] = []
    w, h = cam.width, cam.height
    fov = float(np.degrees(2 * np.arctan(w / (2 * cam.fx))))
    if not 10.0 <= fov <= 170.0:
        out.append(
            CalibIssue(
                "warning",
                "intrinsics",
                f"fx = {cam.fx:g} gives a {fov:.1f} deg horizontal field of view: implausible",
            )
        )
    d = cam.distortion
    if cam.distortion_model != "none" and d:
        if abs(d[0]) > 1.5 or (len(d) > 1 and abs(d[1]) > 5.0):
            out.append(
                CalibIssue(
                    "warning",
                    "distortion_coefficients",
                    f"radial terms k1={d[0]:g}, "
                    f"k2={d[1] if len(d) > 1 else 0:g} are implausibly large",
                )
            )
        if len(d) > 3 and max(abs(d[2]), abs(d[3])) > 0.05:
            out.append(
                CalibIssue(
                    "warning",
                    "distortion_coefficients",
                    f"tangential terms p1={d[2]:g}, p2={d[3]:g} are implausibly large",
                )
            )
        corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=np.float64)
        xn = (corners[:, 0] - cam.cx) / cam.fx
        yn = (corners[:, 1] - cam.cy) / cam.fy
        r_max = float(np.sqrt(xn * xn + yn * yn).max())
        fold = radial_fold_radius(d, r_max)
        if fold is not None:
            out.append(
                CalibIssue(
                    "warning",
                    "distortion_coefficients",
                    f"radial distortion folds back at "
                    f"normalised radius {fold:.2f}, inside the image (corners reach {r_max:.2f})",
                )
            )
    return out


def _fisheye_issues(cam: CameraCalib) -> list[CalibIssue]:
    """Field of view and coefficients of a fisheye (equidistant) camera: its polynomial must
    keep growing out to the image's corners (`model.max_angle`)."""
    out: list[CalibIssue] = []
    w, h, m = cam.width, cam.height, cam.model
    edges = np.array([[0.0, cam.cy], [w - 1.0, cam.cy]])
    fov = float(np.degrees(np.nansum(m.angle_of(edges))))
    if not 60.0 <= fov <= 270.0:
        out.append(
            CalibIssue(
                "warning",
                "intrinsics",
                f"fx = {cam.fx:g} gives a {fov:.1f} deg horizontal field of view: implausible "
                f"for a {cam.distortion_model} fisheye",
            )
        )
    big = [f"k{i + 1}={k:g}" for i, k in enumerate(cam.distortion) if abs(k) > 1.0]
    if big:
        out.append(
            CalibIssue(
                "warning",
                "distortion_coefficients",
                f"{', '.join(big)} implausibly large for an equidistant (Kannala-Brandt) lens",
            )
        )
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=np.float64)
    if not m.valid(corners).all():
        out.append(
            CalibIssue(
                "warning",
                "distortion_coefficients",
                f"equidistant distortion folds back at {np.degrees(m.max_angle):.1f} deg from "
                "the optical axis, inside the image (the corners have no ray)",
            )
        )
    return out


def check_imu(imu: ImuCalib) -> list[CalibIssue]:
    out = check_transform(imu.T_body_imu)
    if imu.rate_hz <= 0:
        out.append(CalibIssue("error", "rate_hz", f"must be positive, is {imu.rate_hz:g}"))
    elif not 20 <= imu.rate_hz <= 10000:
        out.append(
            CalibIssue("warning", "rate_hz", f"{imu.rate_hz:g} Hz is implausible for an IMU")
        )
    plausible = {
        "gyroscope_noise_density": (imu.gyro_noise_density, 1e-6, 1e-1),
        "gyroscope_random_walk": (imu.gyro_random_walk, 1e-8, 1e-1),
        "accelerometer_noise_density": (imu.accel_noise_density, 1e-5, 1.0),
        "accelerometer_random_walk": (imu.accel_random_walk, 1e-7, 1.0),
    }
    for key, (v, lo, hi) in plausible.items():
        if v < 0:
            out.append(CalibIssue("error", key, f"must not be negative, is {v:g}"))
        elif v == 0:
            out.append(
                CalibIssue("warning", key, "is zero: the estimator would trust the IMU blindly")
            )
        elif not lo <= v <= hi:
            out.append(
                CalibIssue("warning", key, f"{v:g} is outside the plausible range [{lo:g}, {hi:g}]")
            )
    return out


def check_stereo(rig: StereoRig) -> list[CalibIssue]:
    """Baseline, parallel optical axes, cam1 to the right of cam0, equal resolutions."""
    return check_stereo_pair(rig.cam0, rig.cam1)


def check_stereo_pair(cam0: CameraCalib, cam1: CameraCalib) -> list[CalibIssue]:
    """`check_stereo` for two cameras without an IMU."""
    out: list[CalibIssue] = []
    T = inv_T(cam1.T_body_cam) @ cam0.T_body_cam  # T_cam1_cam0
    b = float(np.linalg.norm(T[:3, 3]))
    if b < 1e-3:
        out.append(
            CalibIssue(
                "error",
                "T_BS",
                f"stereo baseline is {b * 1000:.2f} mm: cam0 and cam1 sit at the same place",
            )
        )
        return out
    if not 0.02 <= b <= 1.0:
        out.append(
            CalibIssue(
                "warning", "T_BS", f"stereo baseline {b:.3f} m is outside the plausible 0.02-1 m"
            )
        )
    z0_in_1 = T[:3, :3] @ np.array([0.0, 0.0, 1.0])
    angle = float(np.degrees(np.arccos(np.clip(z0_in_1[2], -1.0, 1.0))))
    if angle > 10.0:
        out.append(
            CalibIssue(
                "warning",
                "T_BS",
                f"optical axes of cam0 and cam1 differ by {angle:.1f} "
                "deg: cameras not roughly parallel",
            )
        )
    t_cam0_cam1 = -(T[:3, :3].T @ T[:3, 3])  # cam1's origin in cam0
    if abs(t_cam0_cam1[0]) < 0.7 * b:
        out.append(
            CalibIssue(
                "warning",
                "T_BS",
                "cam1 is not beside cam0 along cam0's x axis: not a horizontal stereo pair",
            )
        )
    elif t_cam0_cam1[0] < 0:
        out.append(
            CalibIssue(
                "warning",
                "T_BS",
                "cam1 is left of cam0 (EuRoC's cam1 is the right camera): are the folders swapped?",
            )
        )
    if cam0.resolution != cam1.resolution:
        out.append(
            CalibIssue(
                "warning",
                "resolution",
                f"cam0 is {cam0.width}x{cam0.height}, cam1 is {cam1.width}x{cam1.height}",
            )
        )
    return out
