"""Calibration: EuRoC `sensor.yaml` files -> typed camera, IMU and stereo-rig descriptions.

EuRoC's `sensor.yaml` files begin with an OpenCV-style `%YAML:1.0` directive that PyYAML
rejects; `load_sensor_yaml` strips it. A camera's `T_BS` is `T_body_cam`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from eurocslam.errors import CalibrationError
from eurocslam.geometry import F64, inv_T


def load_sensor_yaml_text(text: str, path: Path | str) -> dict[str, Any]:
    """Parse the text of a sensor.yaml (with or without its `%YAML:1.0` line)."""
    lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("%YAML")]
    try:
        data = yaml.safe_load("\n".join(lines))
    except yaml.YAMLError as e:
        raise CalibrationError(f"{path}: not valid YAML: {e}") from None
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: expected a mapping of keys, got {type(data).__name__}")
    return data


def load_sensor_yaml(path: Path) -> dict[str, Any]:
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise CalibrationError(f"{path}: file not found") from None
    except OSError as e:
        raise CalibrationError(f"{path}: cannot read: {e}") from None
    return load_sensor_yaml_text(text, path)


def _key(data: dict[str, Any], key: str, path: Path | str) -> Any:
    if key not in data:
        raise CalibrationError(f"{path}: missing key '{key}'")
    return data[key]


def _floats(value: Any, n: int | None, key: str, path: Path | str) -> list[float]:
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
    t = _key(data, "T_BS", path)
    if not isinstance(t, dict) or "data" not in t:
        raise CalibrationError(f"{path}: key 'T_BS' must have 'rows', 'cols' and 'data'")
    vals = _floats(t["data"], 16, "T_BS.data", path)
    return np.array(vals, dtype=np.float64).reshape(4, 4)


@dataclass(frozen=True)
class CameraCalib:
    """Pinhole + radial-tangential camera, as in EuRoC's cam{0,1}/sensor.yaml."""

    name: str
    T_body_cam: F64
    rate_hz: float
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...]  # k1, k2, p1, p2 (OpenCV plumb_bob order)
    distortion_model: str = "radial-tangential"

    @property
    def K(self) -> F64:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> F64:
        return np.array(self.distortion, dtype=np.float64)

    @property
    def resolution(self) -> tuple[int, int]:
        return self.width, self.height


@dataclass(frozen=True)
class ImuCalib:
    """IMU noise model (continuous-time densities) and extrinsics, from imu0/sensor.yaml."""

    T_body_imu: F64
    rate_hz: float
    gyro_noise_density: float  # rad/s/sqrt(Hz)
    gyro_random_walk: float  # rad/s^2/sqrt(Hz)
    accel_noise_density: float  # m/s^2/sqrt(Hz)
    accel_random_walk: float  # m/s^3/sqrt(Hz)

    def discrete_gyro_variance(self, dt: float | None = None) -> float:
        """Per-sample white-noise variance: density**2 / dt."""
        return self.gyro_noise_density**2 / (dt if dt else 1.0 / self.rate_hz)

    def discrete_accel_variance(self, dt: float | None = None) -> float:
        return self.accel_noise_density**2 / (dt if dt else 1.0 / self.rate_hz)


@dataclass(frozen=True)
class StereoRig:
    cam0: CameraCalib
    cam1: CameraCalib
    imu: ImuCalib
    # raw text of each sensor.yaml, keyed by sensor name (for MCAP attachments / synth output)
    yaml_texts: tuple[tuple[str, str], ...] = ()

    @property
    def T_cam1_cam0(self) -> F64:
        return inv_T(self.cam1.T_body_cam) @ self.cam0.T_body_cam

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T_cam1_cam0[:3, 3]))


def camera_from_yaml(data: dict[str, Any], name: str, path: Path | str) -> CameraCalib:
    model = str(data.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise CalibrationError(f"{path}: camera_model '{model}' not supported (only pinhole)")
    dmodel = str(data.get("distortion_model", "radial-tangential"))
    if dmodel not in ("radial-tangential", "radtan", "plumb_bob", "none"):
        raise CalibrationError(
            f"{path}: distortion_model '{dmodel}' not supported (only radial-tangential)"
        )
    intr = _floats(_key(data, "intrinsics", path), 4, "intrinsics", path)
    res = _floats(_key(data, "resolution", path), 2, "resolution", path)
    dist = _floats(data.get("distortion_coefficients", [0, 0, 0, 0]), None, "distortion", path)
    if len(dist) not in (4, 5):
        raise CalibrationError(f"{path}: key 'distortion_coefficients' must have 4 values")
    rate = float(_floats([_key(data, "rate_hz", path)], 1, "rate_hz", path)[0])
    return CameraCalib(
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
        distortion_model="radial-tangential" if dmodel != "none" else "none",
    )


def imu_from_yaml(data: dict[str, Any], path: Path | str) -> ImuCalib:
    def f(key: str) -> float:
        return _floats([_key(data, key, path)], 1, key, path)[0]

    return ImuCalib(
        T_body_imu=_matrix4(data, path),
        rate_hz=f("rate_hz"),
        gyro_noise_density=f("gyroscope_noise_density"),
        gyro_random_walk=f("gyroscope_random_walk"),
        accel_noise_density=f("accelerometer_noise_density"),
        accel_random_walk=f("accelerometer_random_walk"),
    )


def rig_from_texts(texts: dict[str, str], origin: str) -> StereoRig:
    """Build a rig from the texts of cam0, cam1 and imu0 sensor.yaml files."""
    for s in ("cam0", "cam1", "imu0"):
        if s not in texts:
            raise CalibrationError(f"{origin}/{s}/sensor.yaml: file not found")
    p = {s: f"{origin}/{s}/sensor.yaml" for s in texts}
    return StereoRig(
        cam0=camera_from_yaml(load_sensor_yaml_text(texts["cam0"], p["cam0"]), "cam0", p["cam0"]),
        cam1=camera_from_yaml(load_sensor_yaml_text(texts["cam1"], p["cam1"]), "cam1", p["cam1"]),
        imu=imu_from_yaml(load_sensor_yaml_text(texts["imu0"], p["imu0"]), p["imu0"]),
        yaml_texts=tuple(sorted(texts.items())),
    )


def load_rig(folder: Path) -> StereoRig:
    """Load cam0, cam1, imu0 calibration from `folder/{cam0,cam1,imu0}/sensor.yaml`.

    `folder` is a `mav0/` folder or any folder laid out the same way (a calibration folder).
    """
    folder = Path(folder)
    texts: dict[str, str] = {}
    for s in ("cam0", "cam1", "imu0"):
        path = folder / s / "sensor.yaml"
        try:
            texts[s] = path.read_text()
        except FileNotFoundError:
            raise CalibrationError(f"{path}: file not found") from None
        except OSError as e:
            raise CalibrationError(f"{path}: cannot read: {e}") from None
    return rig_from_texts(texts, str(folder))


@functools.cache
def default_rig() -> StereoRig:
    """EuRoC's real cam0/cam1/imu0 calibration, shipped inside the package."""
    base = resources.files("eurocslam") / "data" / "euroc_calib"
    texts = {s: (base / s / "sensor.yaml").read_text() for s in ("cam0", "cam1", "imu0")}
    return rig_from_texts(texts, "<built-in EuRoC calibration>")
