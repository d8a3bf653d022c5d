"""IMU noise figures (continuous-time white-noise densities and bias random walks) from outside
the input: a Kalibr-style `imu.yaml` (`--imu-calib FILE`), the run configuration's `imu:`
section, or, for a bag whose calibration came from its CameraInfo and `/tf_static` (bags carry
no noise figures), EuRoC's ADIS16448 figures with a note saying so.

Accepted files: Kalibr's `imu.yaml` (the four keys at the top level, or under `imu0`/any
`imuN` as in its results files), and an EuRoC `imu0/sensor.yaml` (the same key names).
Precedence: `--imu-calib` > the configuration's `imu:` figures > the input's own calibration >
the EuRoC default (bags only).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eurocslam.dataset.calib import ImuCalib, StereoRig, default_rig, load_sensor_yaml
from eurocslam.dataset.doctor.calib_checks import check_imu
from eurocslam.errors import CalibrationError

KEYS = (
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
)
_FIELDS = dict(
    zip(KEYS, ("gyro_noise_density", "gyro_random_walk", "accel_noise_density",
               "accel_random_walk"), strict=True)
)  # fmt: skip


@dataclass(frozen=True)
class ImuNoise:
    """Noise figures to put on an IMU calibration; a None figure keeps the calibration's."""

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

    def over(self, other: ImuNoise) -> ImuNoise:
        """These figures, the unset ones taken from `other`."""
        vals = {k: getattr(self, k) if getattr(self, k) is not None else getattr(other, k)
                for k in KEYS}  # fmt: skip
        if self.empty or other.empty:
            src = other.source if self.empty else self.source
        else:
            src = f"{self.source}, else {other.source}"
        return ImuNoise(**vals, source=src)


def _imu_mapping(data: dict[str, Any], path: Path) -> dict[str, Any]:
    if any(k in data for k in KEYS):
        return data
    nested = [k for k, v in data.items() if str(k).startswith("imu") and isinstance(v, dict)]
    if nested:
        return dict(data[sorted(nested)[0]])
    raise CalibrationError(
        f"{path}: no IMU noise figures (expected the keys {', '.join(KEYS)}, at the top level "
        "or under imu0)"
    )


def load_imu_noise(path: Path | str) -> ImuNoise:
    """All four figures from a Kalibr `imu.yaml` or an EuRoC `imu0/sensor.yaml`; errors name the
    file and the key."""
    p = Path(path)
    if not p.is_file():
        raise CalibrationError(f"{p}: IMU calibration file not found")
    data = _imu_mapping(load_sensor_yaml(p), p)
    vals: dict[str, float] = {}
    for k in KEYS:
        if k not in data:
            raise CalibrationError(f"{p}: missing key '{k}'")
        try:
            v = float(data[k])
        except (TypeError, ValueError):
            raise CalibrationError(f"{p}: key '{k}' must be a number, got {data[k]!r}") from None
        if not v > 0 or v == float("inf"):
            raise CalibrationError(f"{p}: key '{k}' must be a positive number, got {v!r}")
        vals[k] = v
    return ImuNoise(**vals, source=str(p))


def noise_from_config(imu_cfg: Any, origin: str = "the configuration") -> ImuNoise:
    """The figures a run configuration's `imu:` section sets (`ImuConfig`; unset keys None)."""
    return ImuNoise(**{k: getattr(imu_cfg, k, None) for k in KEYS}, source=f"{origin} (imu:)")


def default_imu_noise() -> ImuNoise:
    """EuRoC's ADIS16448 figures (the built-in imu0/sensor.yaml)."""
    imu = default_rig().imu
    assert imu is not None
    return ImuNoise(
        imu.gyro_noise_density,
        imu.gyro_random_walk,
        imu.accel_noise_density,
        imu.accel_random_walk,
        source="EuRoC's ADIS16448 figures (built in)",
    )


def with_imu_noise(rig: StereoRig, noise: ImuNoise, origin: str) -> StereoRig:
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
