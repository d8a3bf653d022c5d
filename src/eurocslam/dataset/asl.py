"""EuRoC ASL folder reader: `mav0/{cam0,cam1,imu0,state_groundtruth_estimate0,leica0}`, and
TUM-VI's folders in the same format (`mav0/mocap0` ground truth, `dso/camchain.yaml`).

A folder without `imu0/` is a stereo-only sequence: no IMU rows, a rig without an IMU
calibration (it runs visual-only). An `imu0/` folder must hold its rows. The calibration is
found by `calib_sources.sequence_calibration` (EuRoC sensor.yaml files, TUM-VI's dso/, a Kalibr
camchain beside the folder, or `--calib`); how it was found is in `notes`. The ground truth is
`state_groundtruth_estimate0` (EuRoC, 17 columns) or `mocap0` (TUM-VI: the IMU's pose from the
motion-capture room, 8 columns, only where the room sees it).

Streams images lazily (memory does not grow with sequence length). Stereo pairs are joined on
timestamp, never on position. Listed-but-missing images, unreadable PNGs and frames present in
one camera only are skipped and counted in `skips` (reported once by the caller).
Malformed CSV rows raise `DatasetError` naming the file and line; a truncated *last* row (an
interrupted copy) is skipped and counted. Also tolerated and counted: out-of-order and duplicate
timestamps (sorted, first kept), IMU gaps, empty optional files, 16-bit or colour PNGs (converted
to 8-bit mono), images whose size differs from the calibration (skipped). Text files may carry a
UTF-8 byte-order mark, CRLF line endings and blank lines. Streams whose timestamps differ by
orders of magnitude (seconds vs nanoseconds) are refused.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.calib_sources import (
    SENSOR_YAML,
    CalibrationSource,
    check_image_sizes,
    sequence_calibration,
)
from eurocslam.dataset.images import decode_image
from eurocslam.dataset.types import (
    I64,
    U8,
    GroundTruth,
    ImuData,
    PositionData,
    SkipReport,
    StereoFrame,
    empty_imu,
)
from eurocslam.errors import DatasetError
from eurocslam.geometry import normalize_quat
from eurocslam.textfile import read_text
from eurocslam.timebase import NS_PER_S, magnitude, parse_timestamp, unit_outliers

SENSORS = ("cam0", "cam1", "imu0", "state_groundtruth_estimate0", "leica0")
# ground-truth folders, preferred first, and their columns (timestamp included)
GROUNDTRUTH_FOLDERS = (("state_groundtruth_estimate0", 17), ("mocap0", 8))


def resolve_mav0(path: Path | str) -> Path:
    """Accept a sequence folder (containing `mav0/`) or the `mav0/` folder itself."""
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: no such file or folder")
    if (p / "mav0").is_dir():
        return p / "mav0"
    if (p / "cam0").is_dir() or (p / "imu0").is_dir():
        return p
    raise DatasetError(
        f"{p}: not an EuRoC ASL sequence (expected a 'mav0/' folder with cam0, cam1, imu0) "
        "or KITTI sequence (expected image_0, image_1, calib.txt, times.txt)"
    )


@dataclass(frozen=True)
class CsvTable:
    """Numeric rows of an ASL data.csv: int64 timestamps plus float columns."""

    path: Path
    t_ns: I64
    values: np.ndarray  # (N, ncols-1) float64
    line_numbers: np.ndarray  # 1-based line number of each row in the file


def read_text_file(path: Path) -> str:
    """Read a CSV as text (UTF-8, BOM tolerated); errors name the file."""
    return read_text(path, DatasetError)


def parse_numeric_rows(rows: list[str], ncols: int) -> tuple[I64, np.ndarray] | None:
    """Fast path: parse well-formed rows (exactly `ncols` comma-separated numbers, an integer
    timestamp first, finite values) in C. Returns None when any row is not like that; the caller
    then parses row by row to name the line at fault. Timestamps are parsed as int64, exactly."""
    if not rows or any(r.count(",") != ncols - 1 for r in rows):
        return None
    try:
        t = np.loadtxt(rows, delimiter=",", dtype=np.int64, usecols=0, ndmin=1)
        v = np.loadtxt(rows, delimiter=",", dtype=np.float64, usecols=range(1, ncols), ndmin=2)
    except (ValueError, OverflowError):
        return None
    if t.shape[0] != len(rows) or v.shape != (len(rows), ncols - 1) or not np.isfinite(v).all():
        return None
    return t, v


def read_numeric_csv(path: Path, ncols: int, skips: SkipReport | None = None) -> CsvTable:
    """Read an ASL CSV with `ncols` columns: timestamp [ns] (integer) then floats.

    Comment/header lines start with '#'. Errors name the file and line.
    """
    text = read_text_file(path)
    lines = text.splitlines()
    data_lines = [
        (i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")
    ]
    fast = parse_numeric_rows([ln for _, ln in data_lines], ncols)
    if fast is not None:
        nos = np.array([no for no, _ in data_lines], dtype=np.int64)
        return CsvTable(path, fast[0], fast[1], nos)
    t = np.empty(len(data_lines), dtype=np.int64)
    vals = np.empty((len(data_lines), ncols - 1), dtype=np.float64)
    lineno = np.empty(len(data_lines), dtype=np.int64)
    n = 0
    last = len(data_lines) - 1
    for k, (no, ln) in enumerate(data_lines):
        parts = [s.strip() for s in ln.split(",")]
        if len(parts) != ncols:
            if k == last and len(parts) < ncols and skips is not None:
                skips.add("truncated last row", f"{path}:{no}")
                continue
            raise DatasetError(f"{path}:{no}: expected {ncols} columns, found {len(parts)}")
        t[n] = parse_timestamp(parts[0], f"{path}:{no}")
        try:
            vals[n] = [float(s) for s in parts[1:]]
        except ValueError:
            raise DatasetError(f"{path}:{no}: non-numeric value in '{ln.strip()}'") from None
        if not np.all(np.isfinite(vals[n])):
            raise DatasetError(f"{path}:{no}: non-finite value in '{ln.strip()}'")
        lineno[n] = no
        n += 1
    return CsvTable(path, t[:n], vals[:n], lineno[:n])


def read_image_csv(path: Path, skips: SkipReport | None = None) -> tuple[I64, list[str], I64]:
    """Read cam*/data.csv: (timestamps, filenames, line numbers)."""
    text = read_text_file(path)
    ts: list[int] = []
    names: list[str] = []
    nos: list[int] = []
    rows = [
        (i + 1, ln)
        for i, ln in enumerate(text.splitlines())
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    for k, (no, ln) in enumerate(rows):
        parts = [s.strip() for s in ln.split(",")]
        if len(parts) != 2 or not parts[1]:
            if k == len(rows) - 1 and skips is not None:
                skips.add("truncated last row", f"{path}:{no}")
                continue
            raise DatasetError(f"{path}:{no}: expected 2 columns (timestamp, filename)")
        ts.append(parse_timestamp(parts[0], f"{path}:{no}"))
        names.append(parts[1])
        nos.append(no)
    return np.array(ts, dtype=np.int64), names, np.array(nos, dtype=np.int64)


def _sorted_unique(t: I64, what: str, path: Path, skips: SkipReport) -> np.ndarray:
    """Indices that sort `t` and drop duplicate timestamps (counted)."""
    if t.size and np.any(np.diff(t) < 0):
        skips.add("out-of-order timestamps (sorted)", str(path))
    order = np.argsort(t, kind="stable")
    ts = t[order]
    keep = np.ones(ts.size, dtype=bool)
    keep[1:] = ts[1:] != ts[:-1]
    for _ in range(int((~keep).sum())):
        skips.add(f"duplicate {what} timestamp (dropped)", str(path))
    return order[keep]


@dataclass(frozen=True)
class FrameEntry:
    """A stereo frame's timestamp and image files (None when that camera lacks it)."""

    t_ns: int
    left: Path | None
    right: Path | None


class ImageFileFrames:
    """`frames()` over `self.entries`: stereo pairs of image files, decoded lazily and checked
    against `self.rig`'s image size; problems are counted in `self.skips`. Shared by the ASL and
    KITTI readers (they differ only in what the size is compared with)."""

    entries: list[FrameEntry]
    rig: StereoRig
    skips: SkipReport
    SIZE_PROBLEM = "{cam} image size differs from calibration (skipped)"
    SIZE_EXPECTED = "sensor.yaml says {w}x{h}"

    def frames(
        self,
        *,
        include_incomplete: bool = False,
        t_start_ns: int | None = None,
        t_end_ns: int | None = None,
    ) -> Iterator[StereoFrame]:
        """Yield stereo frames in time order, decoding images lazily.

        Unreadable images are counted in `skips`. With `include_incomplete`, frames lacking one
        or both images are yielded with None in their place (the pipeline bridges them).
        """
        for e in self.entries:
            if t_start_ns is not None and e.t_ns < t_start_ns:
                continue
            if t_end_ns is not None and e.t_ns > t_end_ns:
                break
            left = self._load(e.left, "cam0")
            right = self._load(e.right, "cam1")
            if (left is None or right is None) and not include_incomplete:
                continue
            yield StereoFrame(e.t_ns, left, right, e.left, e.right)

    def _load(self, path: Path | None, cam: str) -> U8 | None:
        if path is None:
            return None
        dec = decode_image(path)
        if dec.image is None:
            self.skips.add("unreadable image", f"{path}: {dec.problem}")
            return None
        calib = self.rig.cam0 if cam == "cam0" else self.rig.cam1
        h, w = dec.image.shape[:2]
        if (w, h) != (calib.width, calib.height):
            self.skips.add(
                self.SIZE_PROBLEM.format(cam=cam),
                f"{path}: {w}x{h}, " + self.SIZE_EXPECTED.format(w=calib.width, h=calib.height),
            )
            return None
        if dec.converted:
            self.skips.add(f"{cam} image converted ({dec.converted})", str(path))
        return dec.image


class AslSequence(ImageFileFrames):
    """An EuRoC ASL sequence folder. Implements `SequenceSource`."""

    def __init__(
        self, path: Path | str, rig: StereoRig | None = None, *, calib: Path | str | None = None
    ) -> None:
        self.mav0 = resolve_mav0(path)
        self.root = self.mav0.parent if self.mav0.name == "mav0" else self.mav0
        self.name = self.root.name
        self.skips = SkipReport()
        self.notes: list[str] = []
        self.calibration: CalibrationSource | None = None  # None: a rig given by the caller
        if rig is None:
            loaded = sequence_calibration(self.mav0, Path(calib) if calib is not None else None)
            rig, self.calibration = loaded.rig, loaded.source
            self.notes += loaded.notes
        self.rig = rig
        self.groundtruth_path: Path | None = None
        self.imu = self._read_imu()
        self.groundtruth = self._read_groundtruth()
        self.leica = self._read_leica()
        self.entries = self._join_cameras()
        self._check_image_size()

    @property
    def has_imu(self) -> bool:
        """The folder has an `imu0/` (else it is a stereo-only sequence)."""
        return (self.mav0 / "imu0").is_dir()

    # ---- tables -----------------------------------------------------------------------------
    def _read_imu(self) -> ImuData:
        if not self.has_imu:
            return empty_imu()
        path = self.mav0 / "imu0" / "data.csv"
        tab = read_numeric_csv(path, 7, self.skips)
        if tab.t_ns.size == 0:
            raise DatasetError(f"{path}: no IMU rows")
        idx = _sorted_unique(tab.t_ns, "IMU", path, self.skips)
        v = tab.values[idx]
        t = tab.t_ns[idx]
        rate_hz = self.rig.imu.rate_hz if self.rig.imu is not None else 0.0
        if rate_hz > 0 and t.size > 1:
            period_ns = NS_PER_S / rate_hz
            dt = np.diff(t)
            for i in np.nonzero(dt > 1.5 * period_ns)[0].tolist():
                self.skips.add(
                    "imu0 gap > 1.5 sample periods",
                    f"{path}:{int(tab.line_numbers[idx][i + 1])} ({dt[i] / 1e6:.1f} ms)",
                )
        return ImuData(t, np.ascontiguousarray(v[:, 0:3]), np.ascontiguousarray(v[:, 3:6]))

    def _read_groundtruth(self) -> GroundTruth | None:
        found = [
            (self.mav0 / f / "data.csv", n)
            for f, n in GROUNDTRUTH_FOLDERS
            if (self.mav0 / f / "data.csv").exists()
        ]
        if not found:
            return None
        path, ncols = found[0]
        self.groundtruth_path = path
        tab = read_numeric_csv(path, ncols, self.skips)
        if tab.t_ns.size == 0:
            self.skips.add("empty ground-truth file (ignored)", str(path))
            return None
        idx = _sorted_unique(tab.t_ns, "ground-truth", path, self.skips)
        v = tab.values[idx]
        try:
            q = normalize_quat(v[:, 3:7])
        except ValueError:
            bad = int(np.argmin(np.linalg.norm(v[:, 3:7], axis=1)))
            raise DatasetError(f"{path}:{tab.line_numbers[idx][bad]}: zero quaternion") from None
        full = ncols == 17  # velocity and biases too
        return GroundTruth(
            t_ns=tab.t_ns[idx],
            p=v[:, 0:3].copy(),
            q_wxyz=q,
            v=v[:, 7:10].copy() if full else None,
            bg=v[:, 10:13].copy() if full else None,
            ba=v[:, 13:16].copy() if full else None,
        )

    def _read_leica(self) -> PositionData | None:
        path = self.mav0 / "leica0" / "data.csv"
        if not path.exists():
            return None
        tab = read_numeric_csv(path, 4, self.skips)
        if tab.t_ns.size == 0:
            self.skips.add("empty leica0 file (ignored)", str(path))
            return None
        idx = _sorted_unique(tab.t_ns, "leica0", path, self.skips)
        return PositionData(tab.t_ns[idx], tab.values[idx].copy())

    def _camera(self, cam: str) -> dict[int, Path | None]:
        path = self.mav0 / cam / "data.csv"
        t, names, _ = read_image_csv(path, self.skips)
        if t.size == 0:
            raise DatasetError(f"{path}: no image rows")
        if t.size > 1 and np.any(np.diff(t) < 0):
            self.skips.add("out-of-order timestamps (sorted)", str(path))
        folder = self.mav0 / cam / "data"
        if not folder.is_dir():
            raise DatasetError(f"{folder}: image folder not found")
        try:
            present = {p.name for p in folder.iterdir()}
        except OSError as e:
            raise DatasetError(f"{folder}: cannot list: {e.strerror or e}") from None
        if not present.intersection(names):
            raise DatasetError(f"{folder}: none of the {len(names)} images listed in {path} exist")
        out: dict[int, Path | None] = {}
        for ti, name in zip(t.tolist(), names, strict=True):
            if ti in out:
                self.skips.add(f"duplicate {cam} timestamp (dropped)", f"{path}: {ti}")
                continue
            if name in present:
                out[ti] = folder / name
            else:
                self.skips.add(f"{cam} image listed but missing", str(folder / name))
                out[ti] = None
        return out

    def _join_cameras(self) -> list[FrameEntry]:
        c0 = self._camera("cam0")
        c1 = self._camera("cam1")
        self._check_time_units(
            np.fromiter(c0.keys(), dtype=np.int64), np.fromiter(c1.keys(), dtype=np.int64)
        )
        if not c0.keys() & c1.keys():
            raise DatasetError(
                f"{self.mav0 / 'cam0' / 'data.csv'} and {self.mav0 / 'cam1' / 'data.csv'} share no "
                "timestamp: no stereo pair (cameras are paired on identical timestamps)"
            )
        entries = []
        for t in sorted(set(c0) | set(c1)):
            left, right = c0.get(t), c1.get(t)
            if t not in c0:
                self.skips.add("frame in cam1 only", str(t))
            elif t not in c1:
                self.skips.add("frame in cam0 only", str(t))
            entries.append(FrameEntry(t, left, right))
        return entries

    def _check_image_size(self) -> None:
        """Refuse a calibration whose image size no image has (`check_image_sizes`): the first,
        middle and last readable image of each camera (one odd image is skipped and counted)."""
        sizes: dict[str, list[tuple[int, int, Path]]] = {}
        for cam in ("cam0", "cam1"):
            present = [p for e in self.entries if (p := e.left if cam == "cam0" else e.right)]
            picks = {present[0], present[len(present) // 2], present[-1]} if present else set()
            imgs = [(decode_image(p).image, p) for p in sorted(picks)]
            sizes[cam] = [(im.shape[1], im.shape[0], p) for im, p in imgs if im is not None]
        check_image_sizes(self.rig, self.calibration, sizes)

    def _check_time_units(self, t_cam0: I64, t_cam1: I64) -> None:
        """Refuse streams whose timestamps differ by orders of magnitude (s vs ns mix-ups)."""
        streams: dict[Path, I64] = {
            self.mav0 / "imu0" / "data.csv": self.imu.t_ns,
            self.mav0 / "cam0" / "data.csv": t_cam0,
            self.mav0 / "cam1" / "data.csv": t_cam1,
        }
        if self.groundtruth is not None and self.groundtruth_path is not None:
            streams[self.groundtruth_path] = self.groundtruth.t_ns
        if self.leica is not None:
            streams[self.mav0 / "leica0" / "data.csv"] = self.leica.t_ns
        mags = {p: magnitude(t) for p, t in streams.items() if t.size}
        ref_path, outliers = unit_outliers(mags, prefer=self.mav0 / "imu0" / "data.csv")
        if outliers:
            p, ref = outliers[0], mags[ref_path]
            raise DatasetError(
                f"{p}: timestamps are ~1e{mags[p]:.0f} but {ref_path} has ~1e{ref:.0f}: seconds vs "
                "nanoseconds mix-up? EuRoC timestamps are integer nanoseconds"
            )

    # ---- streams ----------------------------------------------------------------------------
    @property
    def frame_times(self) -> I64:
        return np.array([e.t_ns for e in self.entries], dtype=np.int64)

    @property
    def complete_entries(self) -> list[FrameEntry]:
        return [e for e in self.entries if e.left is not None and e.right is not None]

    @property
    def calibration_is_own(self) -> bool:
        """The rig is the folder's own mav0/*/sensor.yaml (or one the caller gave)."""
        src = self.calibration
        return src is None or (src.kind == SENSOR_YAML and src.path == self.mav0)

    def sensor_yaml_paths(self) -> dict[str, Path]:
        out = {}
        for s in (*SENSORS, "body"):
            p = self.mav0 / s / "sensor.yaml" if s != "body" else self.mav0 / "body.yaml"
            if p.exists():
                out[s] = p
        return out
