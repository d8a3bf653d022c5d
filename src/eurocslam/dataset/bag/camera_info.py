"""`sensor_msgs/CameraInfo` as calibration (REP-104): reading a message (ROS 1 spells its
fields `D K R P`, ROS 2 `d k r p`), checking it, and the camera it describes.

Supported distortion models: those of `eurocslam.camera_models` by their ROS names, with the
number of coefficients ROS gives them: `plumb_bob` (5: k1 k2 t1 t2 k3), `rational_polynomial`
(8: k1 k2 t1 t2 k3 k4 k5 k6; depthai's 14 with the last six zero are read as 8), `equidistant`
(4: k1..k4, Kannala-Brandt); and no distortion (an empty `D`, or `D` all zeros, under any model
name). Any other model, or another number of coefficients, is a one-line error naming the topic.

A camera is *rectified* when its image topic says so (`image_rect`, `image_rect_raw`,
`image_rect_color`: a driver rectified it, realsense's infra streams) or when its CameraInfo is
a distortion-free pinhole (D zero, R = I, P's left 3x3 = K). A rectified image is seen through P
(its left 3x3 are the rectified pinhole) in the frame R rotates the camera into; a raw image
through K and D in the camera's own frame.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from eurocslam.camera_models import MODELS, canonical_model_name
from eurocslam.errors import CalibrationError
from eurocslam.geometry import F64

CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"


def ros_models() -> dict[str, tuple[str, int]]:
    """ROS distortion model -> (our model name, the number of coefficients ROS gives it)."""
    out = {}
    for name, cls in MODELS.items():
        if name == "none":
            continue
        zero = cls(1.0, 1.0, 0.0, 0.0, (0.0,) * min(n for n in cls.coeff_counts if n))
        out[cls.ros_name] = (name, int(zero.ros_coeffs().size))
    return out


_RECT_TOPIC = re.compile(r"(^|/)image_rect(_raw|_color|_mono)?(/|$)")


@dataclass(frozen=True)
class CameraInfo:
    """The calibration part of one CameraInfo message."""

    topic: str
    frame_id: str
    width: int
    height: int
    distortion_model: str
    D: tuple[float, ...]
    K: F64  # 3x3
    R: F64  # 3x3: rotates the camera's rays into the rectified frame
    P: F64  # 3x4: projection of the rectified camera; P[0, 3] = -fx' * baseline on the right

    @property
    def distortion_free(self) -> bool:
        """A plain pinhole: no coefficients, or all zero under a perspective model (a
        zero-coefficient equidistant lens is still a fisheye)."""
        canon = canonical_model_name(self.distortion_model)
        return not any(self.D) and (canon is None or MODELS[canon].perspective)

    @property
    def model(self) -> str:
        """`none`, or the ROS model of the (checked) coefficients."""
        return "none" if not self.D else self.distortion_model

    @property
    def Tx(self) -> float:
        return float(self.P[0, 3])

    @property
    def Ty(self) -> float:
        return float(self.P[1, 3])


def _field(msg: object, name: str) -> object:
    """A CameraInfo array field under its ROS 2 (lower case) or ROS 1 (upper case) name."""
    for n in (name.lower(), name.upper()):
        if hasattr(msg, n):
            return getattr(msg, n)
    raise CalibrationError(f"CameraInfo message without field {name}")


def _matrix(values: object, shape: tuple[int, int], name: str, topic: str) -> F64:
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if a.size != shape[0] * shape[1]:
        raise CalibrationError(f"{topic}: CameraInfo {name} has {a.size} values")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{topic}: CameraInfo {name} holds a non-finite value")
    return a.reshape(shape)


def camera_info_from_msg(msg: object, topic: str) -> CameraInfo:
    """A `CameraInfo` from a decoded message (ROS 1 or ROS 2), not yet checked."""
    D = np.asarray(_field(msg, "D"), dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(D)):
        raise CalibrationError(f"{topic}: CameraInfo D holds a non-finite value")
    info = CameraInfo(
        topic=topic,
        frame_id=str(msg.header.frame_id).strip().lstrip("/"),  # type: ignore[attr-defined]
        width=int(msg.width),  # type: ignore[attr-defined]
        height=int(msg.height),  # type: ignore[attr-defined]
        distortion_model=str(msg.distortion_model).strip(),  # type: ignore[attr-defined]
        D=tuple(float(v) for v in D),
        K=_matrix(_field(msg, "K"), (3, 3), "K", topic),
        R=_matrix(_field(msg, "R"), (3, 3), "R", topic),
        P=_matrix(_field(msg, "P"), (3, 4), "P", topic),
    )
    binning = (int(getattr(msg, "binning_x", 0)), int(getattr(msg, "binning_y", 0)))
    if max(binning) > 1:
        raise CalibrationError(
            f"{topic}: CameraInfo binning {binning[0]}x{binning[1]} is not supported "
            "(calibrate the binned images)"
        )
    roi = getattr(msg, "roi", None)
    if roi is not None and int(roi.width) and int(roi.height):
        full = (int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height)) == (
            0, 0, info.width, info.height
        )  # fmt: skip
        if not full:
            raise CalibrationError(
                f"{topic}: CameraInfo roi {int(roi.width)}x{int(roi.height)}+"
                f"{int(roi.x_offset)}+{int(roi.y_offset)} is not supported (full images only)"
            )
    return info


def check_camera_info(info: CameraInfo) -> CameraInfo:
    """The message if it can be a calibration, with its coefficients normalised to the model's
    count; else a one-line `CalibrationError` naming the topic."""
    t = info.topic
    if info.width <= 0 or info.height <= 0:
        raise CalibrationError(f"{t}: CameraInfo size is {info.width}x{info.height}")
    if not np.any(info.K):
        raise CalibrationError(f"{t}: CameraInfo K is all zeros (the camera is not calibrated)")
    fx, fy = float(info.K[0, 0]), float(info.K[1, 1])
    if fx <= 0 or fy <= 0:
        raise CalibrationError(f"{t}: CameraInfo K has focal lengths {fx:g}, {fy:g}")
    if not np.allclose(info.K[2], [0.0, 0.0, 1.0]) or info.K[1, 0] != 0.0:
        raise CalibrationError(f"{t}: CameraInfo K is not a camera matrix: {info.K.tolist()}")
    R = info.R
    if not np.any(R):
        R = np.eye(3)  # an unset R: a monocular camera (REP-104 allows zeros)
    elif float(np.abs(R.T @ R - np.eye(3)).max()) > 1e-4 or np.linalg.det(R) < 0:
        raise CalibrationError(f"{t}: CameraInfo R is not a rotation: {R.tolist()}")
    model = info.distortion_model
    D = info.D
    models = ros_models()
    if D and not any(D) and models.get(model, ("", 0))[0] != "equidistant":
        D = ()  # zeros under a pinhole model (or any name): no distortion
    if D:
        if model not in models:
            known = ", ".join(f"{m} ({n} coefficients)" for m, (_, n) in sorted(models.items()))
            raise CalibrationError(
                f"{t}: distortion model '{model}' is not supported (supported: {known}, or no "
                "distortion)"
            )
        n = models[model][1]
        if len(D) > n and model == "rational_polynomial" and not any(D[n:]):
            D = D[:n]  # depthai's 14 coefficients, the thin-prism and tilt terms zero
        if len(D) != n:
            raise CalibrationError(
                f"{t}: distortion model '{model}' needs {n} coefficients, has {len(D)}"
            )
    P = info.P
    return CameraInfo(t, info.frame_id, info.width, info.height, model, D, info.K, R, P)


def is_rectified_topic(image_topic: str) -> bool:
    """An image topic a driver rectified (`.../image_rect`, `image_rect_raw`, ...)."""
    return bool(_RECT_TOPIC.search(image_topic))


def is_rectified(info: CameraInfo, image_topic: str) -> bool:
    """The images of `image_topic` are rectified (see the module docstring)."""
    if is_rectified_topic(image_topic):
        return True
    return (
        info.distortion_free
        and bool(np.allclose(info.R, np.eye(3), atol=1e-12))
        and bool(np.allclose(info.P[:, :3], info.K, rtol=0.0, atol=1e-9))
    )


def rectified_pinhole(info: CameraInfo) -> tuple[float, float, float, float]:
    """fx, fy, cx, cy of the rectified image (P's left 3x3); an error naming the topic when P
    holds no camera."""
    P = info.P
    fx, fy, cx, cy = float(P[0, 0]), float(P[1, 1]), float(P[0, 2]), float(P[1, 2])
    if fx <= 0 or fy <= 0:
        raise CalibrationError(
            f"{info.topic}: CameraInfo P has focal lengths {fx:g}, {fy:g} but the images are "
            "rectified (P describes them)"
        )
    return fx, fy, cx, cy


def stereo_baseline_from_P(left: CameraInfo, right: CameraInfo) -> float:
    """Baseline [m] of a rectified pair from the P matrices: `(Tx_left - Tx_right) / fx'`
    (positive when the right camera is on the right; 0 when neither P carries one)."""
    fx = float(right.P[0, 0])
    if fx <= 0:
        return 0.0
    return (left.Tx - right.Tx) / fx
