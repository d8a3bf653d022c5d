"""An IMU whose accelerometer and gyroscope are separate streams at their own rates (a RealSense:
accel 63/250 Hz, gyro 200/400 Hz), as files beside an ASL folder's united `imu0/`:

    mav0/accel0/data.csv   #timestamp [ns], a_RS_S_x/y/z [m s^-2]
    mav0/gyro0/data.csv    #timestamp [ns], w_RS_S_x/y/z [rad s^-1]

`imu0/data.csv` is then their union on the gyro stamps (`dataset.bag.imu_union`, what the
driver's `unite_imu_method: linear_interpolation` publishes); readers of the ASL folder use
`imu0` and ignore these. `eurocslam synth` writes them for a rig with a separate accelerometer
rate, and a realsense-style bag written from the folder carries them as `/camera/accel/sample`
and `/camera/gyro/sample`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.dataset.asl import read_numeric_csv
from eurocslam.dataset.types import I64
from eurocslam.errors import DatasetError, OutputError
from eurocslam.geometry import F64

ACCEL_HEADER = "#timestamp [ns],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
GYRO_HEADER = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1]"
FOLDERS = {"accel": "accel0", "gyro": "gyro0"}


@dataclass(frozen=True)
class SplitImu:
    """Accelerometer and gyroscope samples, each stream on its own stamps (IMU frame)."""

    accel_t_ns: I64
    accel: F64  # (N, 3) m/s^2
    gyro_t_ns: I64
    gyro: F64  # (M, 3) rad/s


def _rows(t_ns: I64, values: F64) -> str:
    return "".join(
        f"{int(t)}," + ",".join(f"{x:.17g}" for x in row) + "\n"
        for t, row in zip(t_ns, values, strict=True)
    )


def write_split_imu(mav0: Path, split: SplitImu) -> None:
    """Write both streams under `mav0` (full precision)."""
    try:
        for kind, header, t, v in (
            ("accel", ACCEL_HEADER, split.accel_t_ns, split.accel),
            ("gyro", GYRO_HEADER, split.gyro_t_ns, split.gyro),
        ):
            folder = Path(mav0) / FOLDERS[kind]
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "data.csv").write_text(header + "\n" + _rows(t, v))
    except OSError as e:
        raise OutputError(f"{mav0}: cannot write the split IMU streams: {e}") from None


def read_split_imu(mav0: Path) -> SplitImu | None:
    """Both streams of `mav0`, or None when it has neither; one without the other is an error."""
    paths = {k: Path(mav0) / f / "data.csv" for k, f in FOLDERS.items()}
    present = {k: p.is_file() for k, p in paths.items()}
    if not any(present.values()):
        return None
    if not all(present.values()):
        missing = next(p for k, p in paths.items() if not present[k])
        raise DatasetError(f"{missing}: file not found (the other IMU stream has one)")
    tabs = {k: read_numeric_csv(p, 4) for k, p in paths.items()}
    for k, tab in tabs.items():
        if tab.t_ns.size and np.any(np.diff(tab.t_ns) <= 0):
            i = int(np.flatnonzero(np.diff(tab.t_ns) <= 0)[0]) + 1
            raise DatasetError(f"{paths[k]}:{tab.line_numbers[i]}: timestamps must increase")
    a, g = tabs["accel"], tabs["gyro"]
    return SplitImu(
        a.t_ns, np.ascontiguousarray(a.values[:, :3]), g.t_ns, np.ascontiguousarray(g.values[:, :3])
    )
