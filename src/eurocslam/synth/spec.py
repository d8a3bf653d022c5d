"""What to synthesise (`SynthSpec`), apart from the rendering: importing it costs nothing (the
command line reads its defaults to build `eurocslam synth --help`, for every command)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64

DEFAULT_DURATION_S = 30.0
RIGS = ("euroc", "tumvi", "realsense")  # SynthSpec.rig
TINY_DURATION_S = 2.0
REALSENSE_ACCEL_HZ = 250.0  # a D435i's accelerometer (63 or 250 Hz; gyro 200 or 400 Hz)


@dataclass(frozen=True)
class Marker:
    """A small plate with a white disc on black, its disc centre at `center`, facing `-axis`
    or `+axis` (`side`), for projection tests."""

    center: tuple[float, float, float]
    axis: int = 1
    side: int = 0  # 0: the disc is on the plate's lower-coordinate face
    size: float = 0.2
    disc_radius: float = 0.05


@dataclass(frozen=True)
class SynthSpec:
    """What to synthesise. Identical specs give byte-identical sequences.

    Motion: the built-in flight (`trajectory=None`, `duration_s` seconds, default 30) or a given
    ground truth (`trajectory`: EuRoC ASL CSV or TUM), cropped to [`start_s`, `end_s`] seconds
    after its first pose (`duration_s`, when given, caps the length). `imu`: real IMU rows
    (ASL imu0/data.csv) to ship instead of simulated ones; the images then follow the motion
    those rows measured (high frequency) on the ground truth (low frequency), in a world turned
    onto the accelerometer's gravity (`fusion.py`; `knot_dt_s` is unused). `calib`: a folder
    with cam0/cam1/imu0 sensor.yaml (default: EuRoC's, shipped in the package).

    `rig`: "euroc" (EuRoC's cameras and IMU, or `calib`'s; an EuRoC ASL folder), "tumvi"
    (TUM-VI's 512x512 stereo fisheye and IMU, shipped in the package; written as a TUM-VI folder
    as distributed: `dso/camchain.yaml`, `dso/imu_config.yaml`, `mav0/mocap0`) or "realsense"
    (a RealSense-like 848x480 infrared pair at 30 Hz and a 400 Hz IMU, shipped in the package;
    an EuRoC ASL folder). With another rig than EuRoC's the motion is re-expressed so that its
    cam0 flies where EuRoC's cam0 flies in the same motion (the IMU then sits where that rig puts
    it), in the same world: a rig is compared with EuRoC's on the same views.

    `imu_rate_hz`: the IMU (gyro) rate instead of the calibration's; `accel_rate_hz`: the
    accelerometer as a separate stream at this rate, united onto the gyro's stamps by linear
    interpolation (`imu0/data.csv`; both streams also in `accel0/`, `gyro0/`). A camera rate that
    the IMU rate is no whole multiple of gives the cameras their own clock.
    """

    duration_s: float | None = None
    seed: int = 0
    trajectory: Path | None = None
    imu: Path | None = None
    start_s: float | None = None
    end_s: float | None = None
    calib: Path | None = None
    image_noise: bool = True
    vignetting: bool = True
    exposure: bool = True
    motion_blur: bool = False
    imu_noise: bool = True
    imu_bias: bool = True
    max_speed: float = 1.5
    max_yaw_rate: float = 1.0
    knot_dt_s: float = 0.1
    marker: Marker | None = None
    # (start, end) seconds from the first frame: both cameras black and no IMU rows in between
    # (the ground truth goes on): a sensor blackout, for relocalization and merging tests
    blackout: tuple[float, float] | None = None
    # ground truths of one place (one frame) the world is built around instead of `trajectory`
    # alone: every sequence rendered with the same files and seed flies through the same world
    # (`shared_world.py`)
    world_from: tuple[Path, ...] | None = None
    rig: str = "euroc"  # RIGS
    imu_rate_hz: float | None = None
    accel_rate_hz: float | None = None

    @classmethod
    def tiny(cls, seed: int = 0, **kw: Any) -> SynthSpec:
        """A ~2 s built-in sequence (40 stereo pairs): a few seconds to make, for tests."""
        kw.setdefault("duration_s", TINY_DURATION_S)
        return cls(seed=seed, **kw)

    @classmethod
    def realsense(cls, seed: int = 0, **kw: Any) -> SynthSpec:
        """The RealSense-like rig: 848x480 infrared pair at 30 Hz, ~5 cm baseline, gyroscope
        at 400 Hz and the accelerometer apart at 250 Hz."""
        kw.setdefault("accel_rate_hz", REALSENSE_ACCEL_HZ)
        return cls(seed=seed, rig="realsense", **kw)

    def ideal(self) -> SynthSpec:
        """The same spec with every realism switch off (no noise, biases, vignetting, ...)."""
        return replace(
            self,
            image_noise=False,
            vignetting=False,
            exposure=False,
            motion_blur=False,
            imu_noise=False,
            imu_bias=False,
        )

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("trajectory", "imu", "calib"):
            if d[k] is not None:
                d[k] = str(Path(d[k]).resolve())
        if d["blackout"] is None:
            del d["blackout"]  # the specs made before it existed keep their identity
        else:
            d["blackout"] = list(d["blackout"])
        if d["rig"] == "euroc":
            del d["rig"]  # (likewise)
        if d["world_from"] is None:
            del d["world_from"]  # (likewise)
        else:
            d["world_from"] = [str(Path(p).resolve()) for p in d["world_from"]]
        for k in ("imu_rate_hz", "accel_rate_hz"):
            if d[k] is None:
                del d[k]  # (likewise)
        return d

    def in_blackout(self, t_s: F64) -> NDArray[np.bool_]:
        """Which times (seconds from the first frame) fall in the blackout."""
        t = np.asarray(t_s, dtype=np.float64)
        if self.blackout is None:
            return np.zeros(t.shape, dtype=bool)
        return (t >= self.blackout[0]) & (t <= self.blackout[1])
