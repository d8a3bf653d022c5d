"""Camera models behind one interface (`CameraModel`: project, unproject with Jacobian, valid
image region): the plain pinhole, pinhole + radial-tangential, pinhole + equidistant
(Kannala-Brandt 4), pinhole + rational polynomial (ROS `rational_polynomial`, 8 coefficients).
`CameraCalib.model` builds the one its `distortion_model` names.

Adding a model (double sphere, extended unified, ...) is one module deriving `CameraModel` and
one entry in `MODELS`; `ALIASES` maps other tools' names for the same model onto ours."""

from __future__ import annotations

from eurocslam.camera_models.base import CameraModel, tangent_basis
from eurocslam.camera_models.equidistant import PinholeEquidistant
from eurocslam.camera_models.pinhole import Pinhole
from eurocslam.camera_models.radtan import PinholeRadTan
from eurocslam.camera_models.rational import PinholeRational

MODELS: dict[str, type[CameraModel]] = {
    m.name: m for m in (Pinhole, PinholeRadTan, PinholeEquidistant, PinholeRational)
}
# other tools' names (Kalibr, ROS CameraInfo, OpenCV, ORB-SLAM3) -> ours
ALIASES: dict[str, str] = {
    "radtan": "radial-tangential",
    "plumb_bob": "radial-tangential",
    "pinhole-radtan": "radial-tangential",
    "equi": "equidistant",
    "fisheye": "equidistant",
    "pinhole-equi": "equidistant",
    "kannala-brandt": "equidistant",
    "kannala_brandt": "equidistant",
    "kb4": "equidistant",
    "rational": "rational_polynomial",
    "rational-polynomial": "rational_polynomial",
}


def canonical_model_name(name: str) -> str | None:
    """Our name of a distortion model (`MODELS` key) for any known spelling, else None."""
    key = name.strip().lower()
    key = ALIASES.get(key, key)
    return key if key in MODELS else None


def make_camera_model(
    name: str, fx: float, fy: float, cx: float, cy: float, coeffs: tuple[float, ...]
) -> CameraModel:
    """The model `name` (any spelling `canonical_model_name` knows). ValueError for an unknown
    model or a wrong number of coefficients (the loaders turn it into a CalibrationError that
    names the file and key)."""
    canon = canonical_model_name(name)
    if canon is None:
        known = ", ".join(sorted(MODELS))
        raise ValueError(f"distortion model '{name}' unknown (known: {known})")
    return MODELS[canon](float(fx), float(fy), float(cx), float(cy), tuple(map(float, coeffs)))


__all__ = [
    "ALIASES",
    "MODELS",
    "CameraModel",
    "Pinhole",
    "PinholeEquidistant",
    "PinholeRadTan",
    "PinholeRational",
    "canonical_model_name",
    "make_camera_model",
    "tangent_basis",
]
