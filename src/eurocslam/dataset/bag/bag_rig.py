"""A stereo rig from what a robot's bag carries: the cameras' `sensor_msgs/CameraInfo` and the
static transform tree (`/tf_static`), with the frames named by the messages' `header.frame_id`.

- **Body** = the IMU frame (the frame of the IMU messages; for separate streams the gyro's),
  or cam0's frame when the bag has no IMU. Each camera is placed in it through the tf tree
  (chains such as `camera_imu_optical_frame <- camera_gyro_frame <- camera_link ->
  camera_infra1_frame -> camera_infra1_optical_frame` are composed).
- **Raw streams**: K and D (`camera_info.py`) in the camera's own frame; cam1 is placed by the
  tf tree, or, when its frame is not in it (or is cam0's), by the CameraInfo R/P pair
  (`T_cam0_cam1 = R0^T * [I | (B, 0, 0)] * R1`, B = (Tx0 - Tx1) / fx').
- **Rectified streams** (both; realsense `image_rect_raw`, `image_proc`'s `image_rect`): each
  camera is P's pinhole in its rectified frame (`R` applied), cam1 exactly B to the right of cam0
  (so the frontend uses the images as they are, `camera.is_rectified`). B comes from P
  (`P[0, 3]` of the right camera), else from the tf tree (realsense-ros before 2.2.16 left
  `P[0, 3]` at 0); a P whose sign says "left camera" while the tf tree puts it on the right
  (a known realsense-ros quirk) is read by its magnitude. Where P and the tf tree disagree by
  more than 2 % of the baseline, 0.5 degrees or an off-axis 5 %, a note says so and P is used.

Everything that disagrees or cannot be a calibration is a one-line `CalibrationError` naming the
topic (CameraInfo) or `/tf_static`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eurocslam.camera_models import canonical_model_name
from eurocslam.dataset.bag.camera_info import (
    CameraInfo,
    check_camera_info,
    is_rectified,
    rectified_pinhole,
    stereo_baseline_from_P,
)
from eurocslam.dataset.bag.tf_tree import TfTree
from eurocslam.dataset.calib_yaml import camera_yaml_text, imu_yaml_text
from eurocslam.dataset.doctor.calib_checks import check_camera, check_stereo
from eurocslam.dataset.rig import CameraCalib, ImuCalib, StereoRig
from eurocslam.errors import CalibrationError
from eurocslam.geometry import F64, inv_T, make_T, rotation_angle

BASELINE_TOL = 0.02  # P vs tf: relative baseline difference noted above this
ANGLE_TOL_DEG = 0.5
OFF_AXIS_TOL = 0.05


@dataclass(frozen=True)
class BagCamera:
    """What the bag says about one camera."""

    role: str  # cam0 | cam1
    image_topic: str
    frame_id: str  # header.frame_id of its image messages ("" if unset)
    image_size: tuple[int, int] | None  # width, height of its first image
    rate_hz: float  # measured
    info: CameraInfo


def _translate_x(b: float) -> F64:
    return make_T(np.eye(3), np.array([b, 0.0, 0.0]))


def _rot(R: F64) -> F64:
    return make_T(np.asarray(R, dtype=np.float64), np.zeros(3))


def _checked(cam: BagCamera) -> CameraInfo:
    info = check_camera_info(cam.info)
    if cam.image_size is not None and cam.image_size != (info.width, info.height):
        w, h = cam.image_size
        raise CalibrationError(
            f"{info.topic}: CameraInfo says {info.width}x{info.height} but the images on "
            f"{cam.image_topic} are {w}x{h}"
        )
    return info


def _frame(cam: BagCamera, info: CameraInfo, notes: list[str]) -> str:
    frame = cam.frame_id or info.frame_id
    if not frame:
        raise CalibrationError(
            f"{cam.image_topic}: the images and {info.topic} have no header.frame_id, so the "
            "camera cannot be found in /tf_static"
        )
    if cam.frame_id and info.frame_id and cam.frame_id != info.frame_id:
        notes.append(
            f"{info.topic}: frame_id '{info.frame_id}' differs from its images' "
            f"'{cam.frame_id}'; the images' frame is used"
        )
    return frame


def _calib(cam: BagCamera, info: CameraInfo, T_body_cam: F64, rectified: bool) -> CameraCalib:
    if rectified:
        fx, fy, cx, cy = rectified_pinhole(info)
        dist: tuple[float, ...] = ()
        model = "none"
    else:
        fx, fy, cx, cy = (float(info.K[0, 0]), float(info.K[1, 1]), float(info.K[0, 2]),
                          float(info.K[1, 2]))  # fmt: skip
        dist = info.D
        model = canonical_model_name(info.model) or info.model
    c = CameraCalib(
        name=cam.role,
        T_body_cam=T_body_cam,
        rate_hz=cam.rate_hz,
        width=info.width,
        height=info.height,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        distortion=dist,
        distortion_model=model,
    )
    for issue in check_camera(c):
        if issue.severity == "error":
            raise CalibrationError(f"{info.topic}: {issue.key}: {issue.message}")
    return c


def _rectified_baseline(
    i0: CameraInfo, i1: CameraInfo, T_rect0_rect1_tf: F64 | None, notes: list[str]
) -> float:
    """The baseline of a rectified pair: P's, else the tf tree's (see the module docstring)."""
    b_p = stereo_baseline_from_P(i0, i1)
    b_tf = float(T_rect0_rect1_tf[0, 3]) if T_rect0_rect1_tf is not None else None
    if b_p == 0.0:
        if b_tf is None:
            raise CalibrationError(
                f"{i1.topic}: P[0, 3] is 0 (no baseline) and /tf_static does not relate the two "
                "cameras' frames: the stereo baseline is unknown"
            )
        notes.append(f"{i1.topic}: P[0, 3] is 0; stereo baseline {b_tf:.4f} m from /tf_static")
        b = b_tf
    elif b_p < 0 and b_tf is not None and b_tf > 0 and abs(-b_p - b_tf) <= BASELINE_TOL * b_tf:
        notes.append(
            f"{i1.topic}: P[0, 3] = {i1.Tx:g} has the sign of a camera on the left, /tf_static "
            f"puts it {b_tf:.4f} m to the right: baseline {-b_p:.4f} m (a realsense-ros quirk)"
        )
        b = -b_p
    else:
        b = b_p
    if b <= 0:
        raise CalibrationError(
            f"{i1.topic}: stereo baseline {b:.4f} m: this camera is not to the right of "
            f"{i0.topic}'s (swap them with --topic left=... --topic right=...)"
        )
    if T_rect0_rect1_tf is not None and b_tf is not None:
        t = T_rect0_rect1_tf[:3, 3]
        angle = float(np.degrees(rotation_angle(T_rect0_rect1_tf[:3, :3])))
        off = float(np.hypot(t[1], t[2]))
        if abs(b_tf - b) > BASELINE_TOL * b or angle > ANGLE_TOL_DEG or off > OFF_AXIS_TOL * b:
            notes.append(
                f"{i1.topic}: /tf_static puts this camera at ({t[0]:.4f}, {t[1]:.4f}, "
                f"{t[2]:.4f}) m, {angle:.2f} deg from the left one; its P says a baseline of "
                f"{b:.4f} m along x: the rectified images follow P, so P is used"
            )
    return b


def rig_from_camera_infos(
    cam0: BagCamera,
    cam1: BagCamera,
    tf: TfTree,
    imu_frame: str | None,
    imu: ImuCalib | None,
    notes: list[str],
) -> StereoRig:
    """The rig of a bag from its CameraInfo and tf tree (module docstring). `imu_frame`: the
    frame of the IMU messages (the body); None for a stereo-only bag. `imu`: the IMU
    calibration to attach (identity extrinsic, its noise figures from outside the bag)."""
    i0, i1 = _checked(cam0), _checked(cam1)
    f0, f1 = _frame(cam0, i0, notes), _frame(cam1, i1, notes)
    rect0, rect1 = is_rectified(i0, cam0.image_topic), is_rectified(i1, cam1.image_topic)
    body = imu_frame if imu_frame is not None else f0
    T_body_f0 = tf.lookup(body, f0, f"body = IMU frame to {cam0.role}") if body != f0 else np.eye(4)
    T_f0_cam0 = _rot(i0.R.T) if rect0 else np.eye(4)
    T_body_cam0 = T_body_f0 @ T_f0_cam0
    T_f0_f1 = tf.lookup(f0, f1) if f1 != f0 and tf.connected(f0, f1) else None
    if imu_frame is not None and T_f0_f1 is None and f1 != f0 and f1 in tf.frames:
        # cam1's frame is in the tree but not connected to cam0's: name the broken link
        tf.lookup(body, f1, f"body = IMU frame to {cam1.role}")
    if rect0 and rect1:
        T_rect0_rect1_tf = None
        if T_f0_f1 is not None:
            T_rect0_rect1_tf = inv_T(T_f0_cam0) @ T_f0_f1 @ _rot(i1.R.T)
        b = _rectified_baseline(i0, i1, T_rect0_rect1_tf, notes)
        T_body_cam1 = T_body_cam0 @ _translate_x(b)
        if (rectified_pinhole(i0), i0.width, i0.height) != (rectified_pinhole(i1), i1.width,
                                                               i1.height):  # fmt: skip
            notes.append(
                f"{i0.topic} and {i1.topic}: rectified images with different pinholes "
                "(P); the frontend rectifies them again"
            )
    else:
        if rect0 != rect1:
            raw = i1 if rect0 else i0
            notes.append(
                f"{raw.topic}: only one camera's images are rectified; the frontend rectifies "
                "the pair again"
            )
        if T_f0_f1 is not None:
            T_cam0_cam1 = inv_T(T_f0_cam0) @ T_f0_f1 @ (_rot(i1.R.T) if rect1 else np.eye(4))
            how = "/tf_static"
        else:
            b = stereo_baseline_from_P(i0, i1)
            if b == 0.0:
                raise CalibrationError(
                    f"{i1.topic}: cannot place {cam1.role} relative to {cam0.role}: its frame "
                    f"'{f1}' is not related to '{f0}' in /tf_static and P[0, 3] is 0"
                )
            # T_cam0_cam1 = T_cam0_rect0 * T_rect0_rect1 * T_rect1_cam1 (rectified cams: R only)
            T_cam0_cam1 = (
                (np.eye(4) if rect0 else _rot(i0.R.T))
                @ _translate_x(b)
                @ (np.eye(4) if rect1 else _rot(i1.R))
            )
            how = "the CameraInfo R/P pair"
        T_body_cam1 = T_body_cam0 @ T_cam0_cam1
        notes.append(f"{cam1.role} placed relative to {cam0.role} by {how}")
    c0 = _calib(cam0, i0, T_body_cam0, rect0)
    c1 = _calib(cam1, i1, T_body_cam1, rect1)
    texts = {"cam0": camera_yaml_text(c0, f"cam0 from {i0.topic}"),
             "cam1": camera_yaml_text(c1, f"cam1 from {i1.topic}")}  # fmt: skip
    if imu is not None:
        texts["imu0"] = imu_yaml_text(imu)
    rig = StereoRig(c0, c1, imu, tuple(sorted(texts.items())))
    for issue in check_stereo(rig):
        if issue.severity == "error":
            raise CalibrationError(f"{i0.topic} + {i1.topic}: {issue.key}: {issue.message}")
    return rig
