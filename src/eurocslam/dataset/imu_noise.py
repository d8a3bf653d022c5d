"""IMU noise figures (continuous-time white-noise densities and bias random walks) from outside
the input: a Kalibr-style `imu.yaml` (`--imu-calib FILE`), the run configuration's `imu:`
section, or, for a bag whose calibration came from its CameraInfo and `/tf_static` (bags carry
no noise figures), the packaged defaults (`data/imu_noise_defaults.yaml`, a MEMS IMU of the
EuRoC / TUM-VI class) with a note saying so.

Accepted files: Kalibr's `imu.yaml` (the four keys at the top level, or under `imu0` as in its
results files; read by `calib_kalibr.read_imu_yaml`), and an EuRoC `imu0/sensor.yaml` (the same
key names). Precedence: `--imu-calib` > the configuration's `imu:` figures > the input's own
calibration > the defaults (bags calibrated by their CameraInfo only).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eurocslam.dataset.calib import ImuCalib, StereoRig, load_sensor_yaml
from eurocslam.dataset.calib_kalibr import NOISE_KEYS, read_imu_yaml
from eurocslam.dataset.doctor.calib_checks import check_imu
from eurocslam.errors import CalibrationError

KEYS = NOISE_KEYS  # gyroscope_noise_density, gyroscope_random_walk, accelerometer_...
_FIELDS = dict(
    zip(KEYS, ("gyro_noise_density", "gyro_random_walk", "accel_noise_density",
               "accel_random_walk"), strict=True)
)  # fmt: skip
DEFAULTS = "eurocslam/data/imu_noise_defaults.yaml"


@dataclass(frozen=True)
class NoiseFigures:
    """Noise figures to put on an IMU calibration, and where they came from; a None figure
    keeps the calibration's (a config's `imu:` may set some of the four)."""

    gyroscope_noise_density: float | None = None  # rad/s/sqrt(Hz)
    gyroscope_random_walk: float | None = None  # rad/s^2/sqrt(Hz)
    accelerometer_noise_density: float | None = None  # m/s^2/sqrt(Hz)
    accelerometer_random_walk: float | None = None  # m/s^3/sqrt(Hz)
    source: str = ""

    @property
    def complete(self) -> bool:
        return all(getattr(self, k) is not None for k in KEYS)

    @property
    def empty(self) -> bool:
        return all(getattr(self, k) is None for k in KEYS)

    def apply(self, imu: ImuCalib) -> ImuCalib:
        """`imu` with these figures (the ones set) in place of its own."""
        changes = {_FIELDS[k]: getattr(self, k) for k in KEYS if getattr(self, k) is not None}
        return dataclasses.replace(imu, **changes)

    def over(self, other: NoiseFigures) -> NoiseFigures:
        """These figures, the unset ones taken from `other`."""
        vals = {k: getattr(self, k) if getattr(self, k) is not None else getattr(other, k)
                for k in KEYS}  # fmt: skip
        if self.empty or other.empty:
            src = other.source if self.empty else self.source
        else:
            src = f"{self.source}, else {other.source}"
        return NoiseFigures(**vals, source=src)


def load_imu_noise(path: Path | str) -> NoiseFigures:
    """All four figures from a Kalibr `imu.yaml` or an EuRoC `imu0/sensor.yaml`; errors name the
    file and the key."""
    p = Path(path)
    if not p.is_file():
        raise CalibrationError(f"{p}: IMU calibration file not found")
    noise, _, _ = read_imu_yaml(load_sensor_yaml(p), p)
    for k in KEYS:
        v = float(getattr(noise, k))
        if not 0 < v < float("inf"):
            raise CalibrationError(f"{p}: key '{k}' must be a positive number, got {v!r}")
    return NoiseFigures(**{k: float(getattr(noise, k)) for k in KEYS}, source=str(p))


def noise_from_config(imu_cfg: Any, origin: str = "the configuration") -> NoiseFigures:
    """The figures a run configuration's `imu:` section sets (`ImuConfig`; unset keys None)."""
    return NoiseFigures(**{k: getattr(imu_cfg, k, None) for k in KEYS}, source=f"{origin} (imu:)")


def default_figures() -> NoiseFigures:
    """The packaged defaults (`calib_sources.default_imu_noise`)."""
    from eurocslam.dataset.calib_sources import default_imu_noise

    d = default_imu_noise()
    return NoiseFigures(**{k: float(getattr(d, k)) for k in KEYS}, source=DEFAULTS)


def with_imu_noise(rig: StereoRig, noise: NoiseFigures, origin: str) -> StereoRig:
    """`rig` with `noise` on its IMU (checked as a calibration; errors name `origin`); its
    imu0 sensor.yaml text (MCAP attachments) rewritten to match."""
    if rig.imu is None or noise.empty:
        return rig
    from eurocslam.dataset.calib_yaml import imu_yaml_text

    imu = noise.apply(rig.imu)
    for issue in check_imu(imu):
        if issue.severity == "error":
            raise CalibrationError(f"{origin}: key '{issue.key}': {issue.message}")
    texts = dict(rig.yaml_texts)
    if texts:
        texts["imu0"] = imu_yaml_text(imu)
    return dataclasses.replace(rig, imu=imu, yaml_texts=tuple(sorted(texts.items())))
