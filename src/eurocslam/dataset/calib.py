"""Calibration: EuRoC `sensor.yaml` files -> typed camera, IMU and stereo-rig descriptions.

EuRoC's `sensor.yaml` files begin with an OpenCV-style `%YAML:1.0` directive that PyYAML
rejects; `load_sensor_yaml` strips it. A camera's `T_BS` is `T_body_cam`.

A rig without an IMU (a stereo-only sequence: an ASL folder without `imu0/`, KITTI) has
`imu = None`; it runs visual-only.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from eurocslam.camera_models import MODELS, canonical_model_name
from eurocslam.dataset.doctor.calib_checks import (
    check_camera,
    check_imu,
    check_stereo,
    raise_errors,
)

# the rig's types, re-exported: the rest of the code imports them from here
from eurocslam.dataset.rig import CameraCalib, ImuCalib, StereoRig
from eurocslam.errors import CalibrationError
from eurocslam.geometry import F64
from eurocslam.textfile import read_text

__all__ = [
    "CameraCalib",
    "ImuCalib",
    "StereoRig",
    "calib_folder",
    "camera_from_yaml",
    "default_rig",
    "float_list",
    "imu_from_yaml",
    "load_rig",
    "load_sensor_yaml",
    "load_sensor_yaml_text",
    "read_yaml_text",
    "require_key",
    "rig_from_texts",
]


class _SensorYamlLoader(yaml.SafeLoader):
    """SafeLoader that also reads OpenCV FileStorage matrices (`!!opencv-matrix`) as mappings."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> Any:
    if isinstance(node, yaml.MappingNode):
        return loader.construct_mapping(node, deep=True)
    raise yaml.constructor.ConstructorError(
        None, None, "!!opencv-matrix must be a mapping", node.start_mark
    )


_SensorYamlLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)


def load_sensor_yaml_text(text: str, path: Path | str) -> dict[str, Any]:
    """Parse the text of a sensor.yaml (with or without its `%YAML:1.0` line).

    Accepts the OpenCV directive in any spelling (`%YAML:1.0`, `%YAML 1.2`), a UTF-8 byte-order
    mark, CRLF line endings and OpenCV `!!opencv-matrix` tags.
    """
    text = text.lstrip("\ufeff")
    lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("%YAML")]
    try:
        data = yaml.load("\n".join(lines), Loader=_SensorYamlLoader)  # a SafeLoader subclass
    except yaml.YAMLError as e:
        msg = " ".join(str(e).split())
        raise CalibrationError(f"{path}: not valid YAML: {msg}") from None
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: expected a mapping of keys, got {type(data).__name__}")
    return data


def read_yaml_text(path: Path | str) -> str:
    """Read a sensor.yaml as text (UTF-8, BOM tolerated); errors name the file."""
    return read_text(path, CalibrationError)


def load_sensor_yaml(path: Path) -> dict[str, Any]:
    return load_sensor_yaml_text(read_yaml_text(path), path)


def require_key(data: dict[str, Any], key: str, path: Path | str) -> Any:
    if key not in data:
        raise CalibrationError(f"{path}: missing key '{key}'")
    return data[key]


def float_list(value: Any, n: int | None, key: str, path: Path | str) -> list[float]:
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise CalibrationError(f"{path}: key '{key}' must be a list of numbers") from None
    if n is not None and len(out) != n:
        raise CalibrationError(f"{path}: key '{key}' must have {n} values, has {len(out)}")
    if not all(np.isfinite(out)):
        raise CalibrationError(f"{path}: key '{key}' holds a non-finite value")
    return out


def _matrix4(data: dict[str, Any], path: Path | str) -> F64:
    t = require_key(data, "T_BS", path)
    if not isinstance(t, dict) or "data" not in t:
        raise CalibrationError(f"{path}: key 'T_BS' must have 'rows', 'cols' and 'data'")
    vals = float_list(t["data"], 16, "T_BS.data", path)
    return np.array(vals, dtype=np.float64).reshape(4, 4)


def distortion_model_of(value: Any, path: Path | str, key: str = "distortion_model") -> str:
    """Our name (`camera_models.MODELS`) of a calibration file's distortion model; an unknown
    one is an error naming the file and key."""
    name = canonical_model_name(str(value))
    if name is None:
        known = ", ".join(sorted(MODELS))
        raise CalibrationError(
            f"{path}: key '{key}': distortion model '{value}' not supported (known: {known})"
        )
    return name


def check_coefficient_count(model: str, coeffs: list[float], key: str, path: Path | str) -> None:
    """The model takes this many coefficients (an equidistant lens 4, radial-tangential 4 or
    5); else an error naming the file and key."""
    counts = MODELS[model].coeff_counts
    if len(coeffs) not in counts:
        n = " or ".join(str(c) for c in counts if c)
        raise CalibrationError(
            f"{path}: key '{key}' must have {n} values for distortion model '{model}', "
            f"has {len(coeffs)}"
        )


def camera_from_yaml(
    data: dict[str, Any], name: str, path: Path | str, *, validate: bool = True
) -> CameraCalib:
    """A `CameraCalib` from a parsed cam sensor.yaml. With `validate` (the default), values that
    cannot be a calibration (see `check_camera`) raise `CalibrationError` naming the key."""
    model = str(data.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise CalibrationError(f"{path}: camera_model '{model}' not supported (only pinhole)")
    dmodel = distortion_model_of(data.get("distortion_model", "radial-tangential"), path)
    intr = float_list(require_key(data, "intrinsics", path), 4, "intrinsics", path)
    res = float_list(require_key(data, "resolution", path), 2, "resolution", path)
    dist = float_list(data.get("distortion_coefficients", [0, 0, 0, 0]), None, "distortion", path)
    check_coefficient_count(dmodel, dist, "distortion_coefficients", path)
    rate = float(float_list([require_key(data, "rate_hz", path)], 1, "rate_hz", path)[0])
    if any(r != int(r) for r in res):
        raise CalibrationError(f"{path}: key 'resolution' must be whole pixels, got {res}")
    cam = CameraCalib(
        name=name,
        T_body_cam=_matrix4(data, path),
        rate_hz=rate,
        width=int(res[0]),
        height=int(res[1]),
        fx=intr[0],
        fy=intr[1],
        cx=intr[2],
        cy=intr[3],
        distortion=tuple(dist),
        distortion_model=dmodel,
    )
    if validate:
        raise_errors(check_camera(cam), path)
    return cam


def imu_from_yaml(data: dict[str, Any], path: Path | str, *, validate: bool = True) -> ImuCalib:
    """An `ImuCalib` from a parsed imu0 sensor.yaml; `validate` as in `camera_from_yaml`."""

    def f(key: str) -> float:
        return float_list([require_key(data, key, path)], 1, key, path)[0]

    imu = ImuCalib(
        T_body_imu=_matrix4(data, path),
        rate_hz=f("rate_hz"),
        gyro_noise_density=f("gyroscope_noise_density"),
        gyro_random_walk=f("gyroscope_random_walk"),
        accel_noise_density=f("accelerometer_noise_density"),
        accel_random_walk=f("accelerometer_random_walk"),
    )
    if validate:
        raise_errors(check_imu(imu), path)
    return imu


def rig_from_texts(texts: dict[str, str], origin: str) -> StereoRig:
    """Build a rig from the texts of cam0, cam1 and (optional: a stereo-only rig has none) imu0
    sensor.yaml files."""
    for s in ("cam0", "cam1"):
        if s not in texts:
            raise CalibrationError(f"{origin}/{s}/sensor.yaml: file not found")
    p = {s: f"{origin}/{s}/sensor.yaml" for s in texts}
    imu = (
        imu_from_yaml(load_sensor_yaml_text(texts["imu0"], p["imu0"]), p["imu0"])
        if "imu0" in texts
        else None
    )
    rig = StereoRig(
        cam0=camera_from_yaml(load_sensor_yaml_text(texts["cam0"], p["cam0"]), "cam0", p["cam0"]),
        cam1=camera_from_yaml(load_sensor_yaml_text(texts["cam1"], p["cam1"]), "cam1", p["cam1"]),
        imu=imu,
        yaml_texts=tuple(sorted(texts.items())),
    )
    raise_errors(check_stereo(rig), f"{p['cam0']} + {p['cam1']}")
    return rig


def calib_folder(folder: Path | str) -> Path:
    """The folder holding `cam0/`, `cam1/`, `imu0/`...: `folder` itself, or its `mav0/`."""
    folder = Path(folder)
    if not (folder / "cam0").exists() and (folder / "mav0").is_dir():
        return folder / "mav0"
    return folder


def load_rig(folder: Path) -> StereoRig:
    """Load cam0, cam1, imu0 calibration from `folder/{cam0,cam1,imu0}/sensor.yaml`.

    `folder` is a `mav0/` folder or any folder laid out the same way (a calibration folder), or
    a sequence folder holding `mav0/` (as every command accepts for SEQUENCE). Without an
    `imu0/` folder the rig is stereo-only (`imu` None); an `imu0/` folder without its
    sensor.yaml is an error.
    """
    folder = calib_folder(folder)
    texts: dict[str, str] = {}
    for s in ("cam0", "cam1", "imu0"):
        path = folder / s / "sensor.yaml"
        if s == "imu0" and not path.parent.is_dir():
            continue
        texts[s] = read_yaml_text(path)
    return rig_from_texts(texts, str(folder))


@functools.cache
def default_rig() -> StereoRig:
    """EuRoC's real cam0/cam1/imu0 calibration, shipped inside the package."""
    base = resources.files("eurocslam") / "data" / "euroc_calib"
    texts = {s: (base / s / "sensor.yaml").read_text() for s in ("cam0", "cam1", "imu0")}
    return rig_from_texts(texts, "<built-in EuRoC calibration>")
