"""Where an ASL folder's calibration comes from, and loading it.

Looked for in this order (the first found is used; `doctor` checks every one it finds):

1. EuRoC: `mav0/cam0/sensor.yaml`, `mav0/cam1/sensor.yaml` (+ `mav0/imu0/sensor.yaml`);
2. TUM-VI as distributed: `dso/camchain.yaml` + `dso/imu_config.yaml` beside `mav0/`;
3. Kalibr beside the folder: a `*camchain*.yaml` in the sequence folder or in `mav0/` (a
   `camchain-imucam-*` before a camera-only `camchain-*`), with an `imu.yaml`, `imu_config.yaml`
   or `imu-*.yaml` beside it.

`--calib FILE|DIR` names one instead: a camchain file (its imu.yaml found beside it as above), a
folder of `cam0/ cam1/ imu0/` sensor.yaml files, or a folder holding a camchain (or a `dso/`).
A camchain carries no rates: they are measured from the folder's `data.csv` timestamps. Without
an imu.yaml the IMU noise comes from `eurocslam/data/imu_noise_defaults.yaml`, with a note.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from eurocslam.dataset.calib import (
    calib_folder,
    load_rig,
    load_sensor_yaml_text,
)
from eurocslam.dataset.calib_kalibr import NOISE_KEYS, ImuNoise, kalibr_rig
from eurocslam.dataset.rig import StereoRig
from eurocslam.errors import CalibrationError
from eurocslam.timebase import NS_PER_S

SENSOR_YAML = "sensor.yaml"
KALIBR = "kalibr"
RATE_ROWS = 2000  # timestamps read to measure a stream's rate
TUMVI_RATES_HZ = {"cam0": 20.0, "cam1": 20.0, "imu0": 200.0}  # TUM-VI's 512x512 sequences


@dataclass(frozen=True)
class CalibrationSource:
    """One place a calibration can be read from: a folder of sensor.yaml files (`path`) or a
    Kalibr camchain (`path`) with its IMU file (`imu_path`, None: the default noise)."""

    kind: str  # SENSOR_YAML | KALIBR
    path: Path
    imu_path: Path | None = None

    def describe(self) -> str:
        if self.kind == SENSOR_YAML:
            return f"{self.path}/{{cam0,cam1,imu0}}/sensor.yaml"
        imu = f" + {self.imu_path}" if self.imu_path is not None else " (no imu.yaml)"
        return f"Kalibr {self.path}{imu}"

    def where(self, cam: str, key: str) -> tuple[str, str]:
        """The file and key a camera's calibration value comes from."""
        if self.kind == KALIBR:
            return str(self.path), f"{cam}.{key}"
        return str(self.path / cam / "sensor.yaml"), key


@dataclass(frozen=True)
class Calibration:
    """A loaded calibration: the rig, where it came from, and what the user should know."""

    rig: StereoRig
    source: CalibrationSource
    notes: tuple[str, ...] = field(default_factory=tuple)


def _camchains(folder: Path) -> list[Path]:
    """Kalibr camchain files in `folder`, camera-IMU ones first."""
    if not folder.is_dir():
        return []
    found = sorted(p for p in folder.glob("*camchain*.yaml") if p.is_file())
    return sorted(found, key=lambda p: "imucam" not in p.name)


def imu_file_beside(camchain: Path) -> Path | None:
    """The imu.yaml that goes with a camchain: `imu.yaml`, `imu_config.yaml`, Kalibr's
    `imu-<name>.yaml` for `camchain-imucam-<name>.yaml`, else a single `imu*.yaml`."""
    folder = camchain.parent
    suffix = camchain.stem.replace("camchain-imucam-", "").replace("camchain-", "")
    names = ["imu.yaml", "imu_config.yaml", f"imu-{suffix}.yaml"]
    for n in names:
        if (folder / n).is_file():
            return folder / n
    others = [p for p in sorted(folder.glob("imu*.yaml")) if "camchain" not in p.name]
    return others[0] if len(others) == 1 else None


def kalibr_source(camchain: Path) -> CalibrationSource:
    return CalibrationSource(KALIBR, camchain, imu_file_beside(camchain))


def sources_in(mav0: Path) -> list[CalibrationSource]:
    """Every calibration source of an ASL folder (`mav0/`), in the order they are preferred."""
    root = mav0.parent if mav0.name == "mav0" else mav0
    out: list[CalibrationSource] = []
    if (mav0 / "cam0" / "sensor.yaml").is_file() or (mav0 / "cam1" / "sensor.yaml").is_file():
        out.append(CalibrationSource(SENSOR_YAML, mav0))
    dso = root / "dso" / "camchain.yaml"
    if dso.is_file():
        imu = root / "dso" / "imu_config.yaml"
        out.append(CalibrationSource(KALIBR, dso, imu if imu.is_file() else None))
    seen = {s.path for s in out}
    for folder in (root, mav0):
        out += [kalibr_source(p) for p in _camchains(folder) if p not in seen]
    return out


def source_of(calib: Path) -> CalibrationSource:
    """The source `--calib FILE|DIR` names."""
    calib = Path(calib)
    if calib.is_file():
        return kalibr_source(calib)
    if not calib.is_dir():
        raise CalibrationError(f"{calib}: calibration file or folder not found")
    folder = calib_folder(calib)
    if (folder / "cam0").is_dir():
        return CalibrationSource(SENSOR_YAML, folder)
    for f in (calib, calib / "dso"):
        chains = _camchains(f)
        if chains:
            return kalibr_source(chains[0])
    raise CalibrationError(
        f"{calib}: no calibration in this folder (expected cam0/ and cam1/ sensor.yaml files, "
        "or a Kalibr camchain.yaml)"
    )


def _stream_rate(csv: Path) -> float | None:
    """Rate [Hz] of a data.csv from the median step of its first timestamps."""
    if not csv.is_file():
        return None
    stamps: list[int] = []
    try:
        with open(csv, encoding="utf-8-sig", errors="replace") as f:
            for line in f:
                head = line.split(",", 1)[0].strip()
                if head.isdigit() and int(head) < 2**63:  # (a damaged row: skipped)
                    stamps.append(int(head))
                    if len(stamps) >= RATE_ROWS:
                        break
    except OSError:
        return None
    steps = np.diff(np.array(sorted(set(stamps)), dtype=np.int64))
    if steps.size == 0:
        return None
    return round(NS_PER_S / float(np.median(steps)), 2)


def measured_rates(mav0: Path | None) -> dict[str, float]:
    """Rates of cam0, cam1 and imu0 measured from an ASL folder's data.csv files."""
    if mav0 is None:
        return {}
    rates = {s: _stream_rate(mav0 / s / "data.csv") for s in ("cam0", "cam1", "imu0")}
    return {s: r for s, r in rates.items() if r}


@functools.cache
def default_imu_noise() -> ImuNoise:
    """The IMU noise used when a calibration has none (a packaged config file)."""
    text = (resources.files("eurocslam") / "data" / "imu_noise_defaults.yaml").read_text()
    data = load_sensor_yaml_text(text, "eurocslam/data/imu_noise_defaults.yaml")
    return ImuNoise(*(float(data[k]) for k in NOISE_KEYS))


def load_source(src: CalibrationSource, rates_hz: dict[str, float] | None = None) -> Calibration:
    """Load one source; `rates_hz` are the streams' measured rates (a camchain has none)."""
    if src.kind == SENSOR_YAML:
        return Calibration(load_rig(src.path), src)
    notes: list[str] = []
    rig = kalibr_rig(src.path, src.imu_path, rates_hz or {}, default_imu_noise(), notes)
    return Calibration(rig, src, tuple(notes))


def sequence_calibration(mav0: Path, calib: Path | None = None) -> Calibration:
    """The calibration of an ASL folder: `calib` (`--calib FILE|DIR`) if given, else the first
    of `sources_in(mav0)`; a note names a source other than the folder's own sensor.yaml."""
    if calib is not None:
        src = source_of(calib)
    else:
        found = sources_in(mav0)
        if not found:
            load_rig(mav0)  # raises, naming the missing sensor.yaml
            raise CalibrationError(f"{mav0}: no calibration found")  # (not reached)
        src = found[0]
    loaded = load_source(src, measured_rates(mav0))
    if src.kind == SENSOR_YAML and src.path == mav0:
        return loaded
    return Calibration(loaded.rig, src, (f"calibration: {src.describe()}", *loaded.notes))


def load_calibration(calib: Path, mav0: Path | None = None) -> Calibration:
    """A calibration named by `--calib FILE|DIR` (rates measured from `mav0` when given)."""
    return load_source(source_of(calib), measured_rates(mav0))


def tumvi_kalibr_texts() -> dict[str, str]:
    """TUM-VI's dso/camchain.yaml and dso/imu_config.yaml texts, as shipped in the package."""
    base = resources.files("eurocslam") / "data" / "tumvi_calib"
    return {n: (base / n).read_text() for n in ("camchain.yaml", "imu_config.yaml")}


@functools.cache
def tumvi_rig() -> StereoRig:
    """TUM-VI's 512x512 stereo fisheye + IMU (its public dso/camchain.yaml and imu_config.yaml,
    shipped inside the package), 20 Hz cameras and a 200 Hz IMU."""
    base = resources.files("eurocslam") / "data" / "tumvi_calib"
    with (
        resources.as_file(base / "camchain.yaml") as chain,
        resources.as_file(base / "imu_config.yaml") as imu,
    ):
        notes: list[str] = []
        return kalibr_rig(chain, imu, TUMVI_RATES_HZ, default_imu_noise(), notes)


def check_image_sizes(
    rig: StereoRig,
    source: CalibrationSource | None,
    sizes: dict[str, list[tuple[int, int, Path]]],
) -> None:
    """Refuse a calibration that disagrees with every sampled image of a camera (`sizes`:
    width, height and file of a few images per camera), naming the file and key."""
    for cam, calib in (("cam0", rig.cam0), ("cam1", rig.cam1)):
        seen = sizes.get(cam, [])
        if seen and all((w, h) != calib.resolution for w, h, _ in seen):
            w, h, p = seen[0]
            where, key = (
                source.where(cam, "resolution")
                if source is not None
                else ("the given calibration", f"{cam}.resolution")
            )
            raise CalibrationError(
                f"{where}: key '{key}' is [{calib.width}, {calib.height}] but the {cam} images "
                f"are {w}x{h} (e.g. {p})"
            )
