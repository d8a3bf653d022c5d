"""Calibration: EuRoC `sensor.yaml` files -> typed camera, IMU and stereo-rig descriptions.

EuRoC's `sensor.yaml` files begin with an OpenCV-style `%YAML:1.0` directive that PyYAML
rejects; `load_sensor_yaml` strips it. A camera's `T_BS` is `T_body_cam`.

A rig without an IMU (a stereo-only sequence: an ASL folder without `imu0/`, KITTI) has
`imu = None`; it runs visual-only.
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
from eurocslam.textfile import read_text


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


# ROS's 8-coefficient model (k1 k2 p1 p2 k3 k4 k5 k6, OpenCV's CALIB_RATIONAL_MODEL order)
RATIONAL = "rational_polynomial"


@dataclass(frozen=True)
class CameraCalib:
    """Pinhole + radial-tangential camera, as in EuRoC's cam{0,1}/sensor.yaml (or ROS's
    `rational_polynomial`, 8 coefficients, from a bag's CameraInfo)."""

    name: str
    T_body_cam: F64
    rate_hz: float
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...]  # k1, k2, p1, p2[, k3[, k4, k5, k6]] (OpenCV order)
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
    """Two cameras and, on a stereo-inertial rig, the IMU (`imu` is None on a stereo-only rig)."""

    cam0: CameraCalib
    cam1: CameraCalib
    imu: ImuCalib | None
    # raw text of each sensor.yaml, keyed by sensor name (for MCAP attachments / synth output)
    yaml_texts: tuple[tuple[str, str], ...] = ()

    @property
    def T_cam1_cam0(self) -> F64:
        return inv_T(self.cam1.T_body_cam) @ self.cam0.T_body_cam

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T_cam1_cam0[:3, 3]))


def camera_from_yaml(
    data: dict[str, Any], name: str, path: Path | str, *, validate: bool = True
) -> CameraCalib:
    """A `CameraCalib` from a parsed cam sensor.yaml. With `validate` (the default), values that
    cannot be a calibration (see `check_camera`) raise `CalibrationError` naming the key."""
    model = str(data.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise CalibrationError(f"{path}: camera_model '{model}' not supported (only pinhole)")
    dmodel = str(data.get("distortion_model", "radial-tangential"))
    if dmodel not in ("radial-tangential", "radtan", "plumb_bob", "none", RATIONAL):
        raise CalibrationError(
            f"{path}: distortion_model '{dmodel}' not supported (radial-tangential, "
            f"{RATIONAL} or none)"
        )
    intr = _floats(_key(data, "intrinsics", path), 4, "intrinsics", path)
    res = _floats(_key(data, "resolution", path), 2, "resolution", path)
    dist = _floats(data.get("distortion_coefficients", [0, 0, 0, 0]), None, "distortion", path)
    if dmodel == RATIONAL and len(dist) != 8:
        raise CalibrationError(
            f"{path}: key 'distortion_coefficients' must have 8 values for {RATIONAL}"
        )
    if dmodel != RATIONAL and len(dist) not in (4, 5):
        raise CalibrationError(f"{path}: key 'distortion_coefficients' must have 4 values")
    rate = float(_floats([_key(data, "rate_hz", path)], 1, "rate_hz", path)[0])
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
        distortion_model=dmodel if dmodel in ("none", RATIONAL) else "radial-tangential",
    )
    if validate:
        _raise_errors(check_camera(cam), path)
    return cam


def imu_from_yaml(data: dict[str, Any], path: Path | str, *, validate: bool = True) -> ImuCalib:
    """An `ImuCalib` from a parsed imu0 sensor.yaml; `validate` as in `camera_from_yaml`."""

    def f(key: str) -> float:
        return _floats([_key(data, key, path)], 1, key, path)[0]

    imu = ImuCalib(
        T_body_imu=_matrix4(data, path),
        rate_hz=f("rate_hz"),
        gyro_noise_density=f("gyroscope_noise_density"),
        gyro_random_walk=f("gyroscope_random_walk"),
        accel_noise_density=f("accelerometer_noise_density"),
        accel_random_walk=f("accelerometer_random_walk"),
    )
    if validate:
        _raise_errors(check_imu(imu), path)
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
    _raise_errors(check_stereo(rig), f"{p['cam0']} + {p['cam1']}")
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


# ---- sanity checks (shared by the loaders and `eurocslam doctor`) --------------------------------


@dataclass(frozen=True)
class CalibIssue:
    """A problem with a calibration value. `error`: cannot be a calibration; `warning`: possible
    but implausible for a stereo-inertial rig."""

    severity: str  # "error" | "warning"
    key: str
    message: str


def _raise_errors(issues: list[CalibIssue], path: Path | str) -> None:
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
    or None. `k` holds k1, k2[, p1, p2, k3[, k4, k5, k6]] in OpenCV order (the last three are
    the rational model's denominator)."""
    k1 = k[0] if len(k) > 0 else 0.0
    k2 = k[1] if len(k) > 1 else 0.0
    k3 = k[4] if len(k) > 4 else 0.0
    r = np.linspace(0.0, r_max, 512)
    r2 = r * r
    if len(k) >= 8:  # rational: r (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
        dnum = r2 * (2 * k1 + r2 * (4 * k2 + r2 * 6 * k3))  # r * d(num)/dr
        dden = r2 * (2 * k[5] + r2 * (4 * k[6] + r2 * 6 * k[7]))
        deriv = np.where(den > 0, (num + dnum) / den - num * dden / den**2, -1.0)
    else:
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
