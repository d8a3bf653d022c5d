"""`eurocslam doctor`: check an EuRoC ASL sequence folder before trusting it.

Every problem becomes a `Finding` (error, warning or info) naming the file, line and key; the
doctor itself never raises on bad input: a reader `DatasetError`, an unreadable file or a bug in
one check becomes an error finding and the other checks still run.

Severity follows what the reader does with the problem:
  error   the reader refuses the sequence, or its output would be wrong (no stereo pairs, image
          size different from the calibration, seconds mixed with nanoseconds, broken calibration)
  warning the reader copes (skips and counts, sorts, converts) but the data is not as it should be
          (missing images, gaps, duplicates, partial time overlap, implausible calibration)
  info    worth knowing, harmless (no ground truth, a byte-order mark, blank lines)

Fast on full sequences: every image's PNG header (IHDR: size, bit depth, colour type) and its last
12 bytes (the IEND chunk: truncation) are read; only an evenly spaced sample is fully decoded
(`full=True` decodes all of them).
"""

from __future__ import annotations

import math
import os
import struct
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.asl import (
    PNG_SIGNATURE,
    decode_image,
    parse_numeric_rows,
    resolve_mav0,
)
from eurocslam.dataset.calib import (
    CalibIssue,
    CameraCalib,
    _matrix4,
    camera_from_yaml,
    check_camera,
    check_imu,
    check_stereo_pair,
    check_transform,
    imu_from_yaml,
    load_sensor_yaml,
)
from eurocslam.dataset.types import I64
from eurocslam.errors import EurocSlamError
from eurocslam.timebase import (
    could_be_seconds,
    looks_like_seconds,
    magnitude,
    parse_timestamp,
    unit_hint,
    unit_outliers,
)

ERROR = "error"
WARNING = "warning"
INFO = "info"
_SEVERITY_RANK = {ERROR: 0, WARNING: 1, INFO: 2}

GT = "state_groundtruth_estimate0"
# stream name -> (folder, number of CSV columns, required)
STREAMS: dict[str, tuple[str, int, bool]] = {
    "cam0": ("cam0", 2, True),
    "cam1": ("cam1", 2, True),
    "imu0": ("imu0", 7, True),
    "groundtruth": (GT, 17, False),
    "leica0": ("leica0", 4, False),
}
GAP_PERIODS = 1.5  # a step longer than this many sample periods is a gap
MAX_EXAMPLES = 3


@dataclass(frozen=True)
class Finding:
    """One problem. `file` is relative to the sequence folder; `line` is 1-based."""

    severity: str  # "error" | "warning" | "info"
    check: str  # files, csv, timestamps, images, calibration, overlap, units, values, reader
    message: str
    file: str | None = None
    line: int | None = None
    key: str | None = None

    @property
    def location(self) -> str:
        if self.file is None:
            return "(sequence)"
        s = self.file
        if self.line is not None:
            s += f":{self.line}"
        if self.key is not None:
            s += f" ({self.key})"
        return s

    def text(self) -> str:
        return f"{self.severity.upper():<7} {self.location}: {self.message}"


@dataclass(frozen=True)
class StreamStats:
    """What the doctor measured in one CSV."""

    name: str
    file: str
    rows: int
    t_first_ns: int | None
    t_last_ns: int | None
    rate_hz: float | None  # measured: 1 / median spacing
    rate_hz_yaml: float | None  # sensor.yaml's rate_hz

    @property
    def span_s(self) -> float:
        if self.t_first_ns is None or self.t_last_ns is None:
            return 0.0
        return (self.t_last_ns - self.t_first_ns) / 1e9


@dataclass(frozen=True)
class DoctorReport:
    sequence: str
    mav0: str | None
    findings: tuple[Finding, ...]
    streams: tuple[StreamStats, ...]
    stereo_pairs: int  # timestamps in both cameras with both images present
    image_headers_read: int
    images_decoded: int
    elapsed_s: float

    def count(self, severity: str) -> int:
        return sum(1 for f in self.findings if f.severity == severity)

    @property
    def errors(self) -> int:
        return self.count(ERROR)

    @property
    def warnings(self) -> int:
        return self.count(WARNING)

    @property
    def exit_code(self) -> int:
        """0 ok (info only), 1 warnings, 2 errors."""
        return 2 if self.errors else 1 if self.warnings else 0

    def by_check(self, check: str) -> list[Finding]:
        return [f for f in self.findings if f.check == check]

    def to_dict(self) -> dict[str, Any]:
        return {
            "sequence": self.sequence,
            "mav0": self.mav0,
            "exit_code": self.exit_code,
            "summary": {
                "errors": self.errors,
                "warnings": self.warnings,
                "info": self.count(INFO),
                "stereo_pairs": self.stereo_pairs,
                "image_headers_read": self.image_headers_read,
                "images_decoded": self.images_decoded,
                "elapsed_s": round(self.elapsed_s, 3),
            },
            "streams": [asdict(s) for s in self.streams],
            "findings": [asdict(f) for f in self.findings],
        }

    def format_text(self) -> str:
        out = [f"eurocslam doctor: {self.sequence}"]
        if self.streams:
            out.append(
                f"  {'stream':<12} {'rows':>7} {'first t [ns]':>20} {'span [s]':>9} "
                f"{'rate [Hz]':>10} {'yaml [Hz]':>10}"
            )
            for s in self.streams:
                rate = f"{s.rate_hz:.2f}" if s.rate_hz else "-"
                yrate = f"{s.rate_hz_yaml:g}" if s.rate_hz_yaml else "-"
                first = str(s.t_first_ns) if s.t_first_ns is not None else "-"
                out.append(
                    f"  {s.name:<12} {s.rows:>7} {first:>20} {s.span_s:>9.2f} "
                    f"{rate:>10} {yrate:>10}"
                )
            out.append(
                f"  stereo pairs (both images present): {self.stereo_pairs}; "
                f"image headers read: {self.image_headers_read}; "
                f"images decoded: {self.images_decoded}"
            )
        out.extend(f.text() for f in self.findings)
        verdict = {0: "ok", 1: "warnings", 2: "errors"}[self.exit_code]
        out.append(
            f"summary: {self.errors} error(s), {self.warnings} warning(s), {self.count(INFO)} "
            f"note(s) in {self.elapsed_s:.2f} s -> exit {self.exit_code} ({verdict})"
        )
        return "\n".join(out)


# ---- CSV scanning (tolerant: collects every problem instead of stopping at the first) ---------


@dataclass
class _Problems:
    """Rows sharing one kind of problem: counted, first few kept as examples."""

    count: int = 0
    lines: list[int] = field(default_factory=list)
    examples: list[str] = field(default_factory=list)

    def add(self, line: int, example: str) -> None:
        self.count += 1
        if len(self.lines) < MAX_EXAMPLES:
            self.lines.append(line)
            self.examples.append(example)


@dataclass
class _Csv:
    name: str
    rel: str
    t: I64  # timestamps of the good rows, in file order
    lines: I64  # their 1-based line numbers
    values: np.ndarray | None  # (N, ncols - 1) for numeric CSVs
    names: list[str] | None  # image file names for camera CSVs


@dataclass(frozen=True)
class PngHeader:
    """What the first 33 and last 12 bytes of a PNG say. `problem` is None for a sound file."""

    width: int = 0
    height: int = 0
    bit_depth: int = 0
    colour_type: int = 0
    problem: str | None = None


_COLOUR_TYPES = {0: "grey", 2: "RGB", 3: "palette", 4: "grey+alpha", 6: "RGBA"}


def read_png_header(path: Path) -> PngHeader:
    """Size, bit depth and colour type from the IHDR chunk; truncation from the IEND chunk."""
    try:
        with open(path, "rb") as f:
            head = f.read(33)
            if not head:
                return PngHeader(problem="empty file")
            if not head.startswith(PNG_SIGNATURE):
                return PngHeader(problem="not a PNG file (bad signature)")
            if len(head) < 33 or head[12:16] != b"IHDR":
                return PngHeader(problem="corrupt PNG (no IHDR chunk)")
            f.seek(-12, os.SEEK_END)
            tail = f.read(12)
    except OSError as e:
        return PngHeader(problem=f"cannot read: {e.strerror or e}")
    width, height, depth, ctype = struct.unpack(">IIBB", head[16:26])
    problem = None if b"IEND" in tail else "truncated PNG (no IEND chunk at the end)"
    return PngHeader(width, height, depth, ctype, problem)


class _Doctor:
    def __init__(
        self,
        path: Path | str,
        *,
        full: bool,
        sample: int,
        progress: Callable[[int, str], Any] | None,
    ) -> None:
        self.path = Path(path)
        self.full = full
        self.sample = sample
        self.progress = progress
        self.findings: list[Finding] = []
        self.streams: dict[str, StreamStats] = {}
        self.csvs: dict[str, _Csv] = {}
        self.cams: dict[str, CameraCalib] = {}
        self.rates: dict[str, float] = {}
        self.present: dict[str, set[str]] = {}
        self.usable: dict[str, set[str]] = {}
        self.headers_read = 0
        self.decoded = 0
        self.stereo_pairs = 0
        self.mav0: Path | None = None
        self.root = self.path

    # ---- plumbing ---------------------------------------------------------------------------
    def add(
        self,
        severity: str,
        check: str,
        message: str,
        file: Path | str | None = None,
        line: int | None = None,
        key: str | None = None,
    ) -> None:
        self.findings.append(Finding(severity, check, message, self.rel(file), line, key))

    def rel(self, p: Path | str | None) -> str | None:
        if p is None:
            return None
        p = Path(p)
        try:
            return p.relative_to(self.root).as_posix()
        except ValueError:
            return str(p)

    def strip_path(self, message: str, path: Path) -> str:
        """'<abs path>: msg' -> 'msg' (the finding names the file already)."""
        for prefix in (f"{path}: ", f"{path}:"):
            if message.startswith(prefix):
                return message[len(prefix) :]
        return message

    @contextmanager
    def guard(self, check: str, file: Path | None = None) -> Iterator[None]:
        try:
            yield
        except EurocSlamError as e:
            msg = self.strip_path(str(e), file) if file is not None else str(e)
            self.add(ERROR, check, msg, file)
        except OSError as e:
            self.add(ERROR, check, f"cannot read: {e.strerror or e}", e.filename or file)
        except Exception as e:  # a bug in a check must not hide the other checks' findings
            self.add(
                ERROR,
                "internal",
                f"check '{check}' failed: {type(e).__name__}: {e} (a bug in eurocslam doctor; "
                "please report it)",
                file,
            )

    # ---- run --------------------------------------------------------------------------------
    def run(self) -> DoctorReport:
        t0 = time.perf_counter()
        try:
            self.mav0 = resolve_mav0(self.path)
        except EurocSlamError as e:
            self.add(ERROR, "files", str(e))
        if self.mav0 is not None:
            self.root = self.mav0.parent if self.mav0.name == "mav0" else self.mav0
            self.check_files()
            self.check_calibration()
            for name, (folder, ncols, required) in STREAMS.items():
                path = self.mav0 / folder / "data.csv"
                if path.is_file():
                    with self.guard("csv", path):
                        self.scan_csv(name, path, ncols, required)
            for name in self.csvs:
                with self.guard("timestamps", self.mav0 / STREAMS[name][0] / "data.csv"):
                    self.check_times(name)
            with self.guard("units"):
                self.check_time_units()
            for cam in ("cam0", "cam1"):
                with self.guard("images", self.mav0 / cam / "data"):
                    self.check_images(cam)
            with self.guard("overlap"):
                self.check_overlap()
            with self.guard("values"):
                self.check_values()
            self.check_reader()
        findings = sorted(
            self.findings, key=lambda f: (_SEVERITY_RANK[f.severity], f.file or "", f.line or 0)
        )
        order = [n for n in STREAMS if n in self.streams]
        return DoctorReport(
            sequence=str(self.path),
            mav0=str(self.mav0) if self.mav0 is not None else None,
            findings=tuple(findings),
            streams=tuple(self.streams[n] for n in order),
            stereo_pairs=self.stereo_pairs,
            image_headers_read=self.headers_read,
            images_decoded=self.decoded,
            elapsed_s=time.perf_counter() - t0,
        )

    # ---- files ------------------------------------------------------------------------------
    def check_files(self) -> None:
        assert self.mav0 is not None
        for _name, (folder, _ncols, required) in STREAMS.items():
            d = self.mav0 / folder
            csv, yml = d / "data.csv", d / "sensor.yaml"
            if not d.is_dir():
                if required:
                    self.add(ERROR, "files", "folder missing", d)
                elif folder == GT:
                    self.add(INFO, "files", "no ground truth: evaluation needs an external file", d)
                continue
            if not csv.is_file():
                self.add(ERROR if required else WARNING, "files", "file missing", csv)
            if not yml.is_file():
                sev = ERROR if folder in ("cam0", "cam1", "imu0") else INFO
                self.add(sev, "files", "file missing", yml)
            if folder in ("cam0", "cam1") and not (d / "data").is_dir():
                self.add(ERROR, "files", "image folder missing", d / "data")

    # ---- calibration ------------------------------------------------------------------------
    def calib_findings(self, issues: list[CalibIssue], path: Path, prefix: str = "") -> None:
        for i in issues:
            self.add(i.severity, "calibration", prefix + i.message, path, key=i.key)

    def check_calibration(self) -> None:
        assert self.mav0 is not None
        for cam in ("cam0", "cam1"):
            path = self.mav0 / cam / "sensor.yaml"
            if not path.is_file():
                continue
            with self.guard("calibration", path):
                data = load_sensor_yaml(path)
                self.rates[cam] = _yaml_rate(data)
                calib = camera_from_yaml(data, cam, path, validate=False)
                self.cams[cam] = calib
                self.calib_findings(check_camera(calib), path)
        if "cam0" in self.cams and "cam1" in self.cams:
            stereo = check_stereo_pair(self.cams["cam0"], self.cams["cam1"])
            self.calib_findings(stereo, self.mav0 / "cam1" / "sensor.yaml", "stereo: ")
        path = self.mav0 / "imu0" / "sensor.yaml"
        if path.is_file():
            with self.guard("calibration", path):
                data = load_sensor_yaml(path)
                self.rates["imu0"] = _yaml_rate(data)
                self.calib_findings(check_imu(imu_from_yaml(data, path, validate=False)), path)
        for folder in (GT, "leica0"):
            path = self.mav0 / folder / "sensor.yaml"
            if path.is_file():
                with self.guard("calibration", path):
                    data = load_sensor_yaml(path)
                    if "T_BS" in data:
                        self.calib_findings(check_transform(_matrix4(data, path)), path)

    # ---- CSVs -------------------------------------------------------------------------------
    def scan_csv(self, name: str, path: Path, ncols: int, required: bool) -> None:
        raw = path.read_bytes()
        if not raw.strip():
            self.add(ERROR if required else WARNING, "csv", "empty file", path)
            return
        if raw.startswith(b"\xef\xbb\xbf"):
            self.add(INFO, "csv", "starts with a UTF-8 byte-order mark (tolerated)", path)
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError as e:
            line = raw[: e.start].count(b"\n") + 1
            self.add(ERROR, "csv", f"not a text file (byte {e.start} is not UTF-8)", path, line)
            return
        lines = text.splitlines()
        is_image = ncols == 2
        rows = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
        blank = len(lines) - len(rows)
        if blank:
            self.add(INFO, "csv", f"{blank} blank line(s) (ignored)", path)
        header = next(((no, ln) for no, ln in rows if ln.lstrip().startswith("#")), None)
        data_rows = [(no, ln) for no, ln in rows if not ln.lstrip().startswith("#")]
        if header is None:
            self.add(WARNING, "csv", "no '#' header line", path, 1)
        elif header[0] != rows[0][0]:
            self.add(WARNING, "csv", "header is not the first line", path, header[0])
        else:
            hcols = len(header[1].split(","))
            if hcols != ncols:
                self.add(
                    ERROR,
                    "csv",
                    f"header has {hcols} columns, expected {ncols} ({_expect(name)})",
                    path,
                    header[0],
                )
        probs: dict[str, _Problems] = {}
        t = np.empty(len(data_rows), dtype=np.int64)
        nos = np.empty(len(data_rows), dtype=np.int64)
        vals = None if is_image else np.empty((len(data_rows), ncols - 1), dtype=np.float64)
        names: list[str] | None = [] if is_image else None
        n = 0
        last = len(data_rows) - 1
        fast = None if is_image else parse_numeric_rows([ln for _, ln in data_rows], ncols)
        if fast is not None:
            n = len(data_rows)
            t, vals = fast
            nos = np.array([no for no, _ in data_rows], dtype=np.int64)
            data_rows = []
        for k, (no, ln) in enumerate(data_rows):
            parts = [s.strip() for s in ln.split(",")]
            if len(parts) != ncols:
                kind = "truncated" if k == last and len(parts) < ncols else "columns"
                probs.setdefault(kind, _Problems()).add(no, f"{len(parts)} columns")
                continue
            try:
                ti = parse_timestamp(parts[0], "")
            except EurocSlamError:
                kind = "seconds" if looks_like_seconds(parts[0]) else "timestamp"
                probs.setdefault(kind, _Problems()).add(no, repr(parts[0]))
                continue
            if is_image:
                assert names is not None
                if not parts[1]:
                    probs.setdefault("filename", _Problems()).add(no, "empty file name")
                    continue
                names.append(parts[1])
            else:
                assert vals is not None
                # a row with a bad value keeps its timestamp (no spurious gap), values NaN
                try:
                    row = [float(s) for s in parts[1:]]
                    bad = None if all(math.isfinite(v) for v in row) else "finite"
                except ValueError:
                    row, bad = [math.nan] * (ncols - 1), "number"
                if bad is not None:
                    probs.setdefault(bad, _Problems()).add(no, ln.strip()[:60])
                vals[n] = row
            t[n] = ti
            nos[n] = no
            n += 1
        messages = {
            "truncated": (WARNING, "truncated last row ({ex}); the reader skips it"),
            "columns": (ERROR, f"{{n}} row(s) without {ncols} columns ({_expect(name)}): {{ex}}"),
            "seconds": (
                ERROR,
                "{n} timestamp(s) look like seconds ({ex}); EuRoC timestamps are integer ns",
            ),
            "timestamp": (ERROR, "{n} timestamp(s) are not integer ns in [0, 2^63): {ex}"),
            "filename": (ERROR, "{n} row(s) with an empty file name"),
            "number": (ERROR, "{n} row(s) with a non-numeric value: {ex}"),
            "finite": (ERROR, "{n} row(s) with a non-finite value (nan/inf): {ex}"),
        }
        for kind, p in probs.items():
            sev, fmt = messages[kind]
            ex = ", ".join(f"line {li}: {e}" for li, e in zip(p.lines, p.examples, strict=True))
            self.add(sev, "csv", fmt.format(n=p.count, ex=ex), path, p.lines[0])
        if n == 0 and not probs:
            self.add(ERROR if required else WARNING, "csv", "no data rows", path)
        self.csvs[name] = _Csv(
            name,
            self.rel(path) or "",
            t[:n],
            nos[:n],
            vals[:n] if vals is not None else None,
            names,
        )

    # ---- timestamps ---------------------------------------------------------------------------
    def check_times(self, name: str) -> None:
        assert self.mav0 is not None
        c = self.csvs[name]
        path = self.mav0 / STREAMS[name][0] / "data.csv"
        t = c.t
        yaml_rate = self.rates.get(name)
        stats = StreamStats(name, c.rel, int(t.size), None, None, None, yaml_rate)
        if t.size == 0:
            self.streams[name] = stats
            return
        d = np.diff(t)
        back = np.nonzero(d < 0)[0]
        if back.size:
            i = int(back[0])
            self.add(
                WARNING,
                "timestamps",
                f"{back.size} timestamp(s) go backwards (first: {t[i + 1]} after {t[i]}); "
                "the reader sorts them",
                path,
                int(c.lines[i + 1]),
            )
        order = np.argsort(t, kind="stable")
        ts = t[order]
        dup = np.nonzero(ts[1:] == ts[:-1])[0]
        if dup.size:
            li = int(c.lines[order[dup[0] + 1]])
            self.add(
                WARNING,
                "timestamps",
                f"{dup.size} duplicate timestamp(s) (first: {ts[dup[0]]}); the reader keeps one",
                path,
                li,
            )
        u = np.unique(ts)
        measured = None
        if u.size > 1:
            du = np.diff(u)
            med = float(np.median(du))
            measured = 1e9 / med if med > 0 else None
            period = 1e9 / yaml_rate if yaml_rate else med
            if yaml_rate and med > 0:
                ratio = med / period
                if ratio < 0.01 or ratio > 100:
                    self.add(
                        ERROR,
                        "units",
                        f"median spacing {med:.0f} ns, but rate_hz {yaml_rate:g} means "
                        f"{period:.0f} ns: {unit_hint(ratio)}",
                        path,
                    )
                    period = med
                elif abs(ratio - 1) > 0.1:
                    self.add(
                        WARNING,
                        "timestamps",
                        f"measured rate {1e9 / med:.2f} Hz differs from sensor.yaml rate_hz "
                        f"{yaml_rate:g}",
                        path,
                        key="rate_hz",
                    )
            gaps = np.nonzero(du > GAP_PERIODS * period)[0]
            if gaps.size:
                big = int(gaps[np.argmax(du[gaps])])
                # line of the row after the largest gap
                pos = np.searchsorted(ts, u[big + 1])
                li = int(c.lines[order[pos]])
                lost = int(np.sum(np.round(du[gaps] / period) - 1))
                self.add(
                    WARNING,
                    "timestamps",
                    f"{gaps.size} gap(s) longer than {GAP_PERIODS:g} periods "
                    f"({GAP_PERIODS * period / 1e6:.1f} ms), about {lost} sample(s) missing; "
                    f"largest {du[big] / 1e6:.1f} ms ({du[big] / period:.1f} periods) "
                    f"ends at this line",
                    path,
                    li,
                )
        self.streams[name] = StreamStats(
            name, c.rel, int(t.size), int(u[0]), int(u[-1]), measured, yaml_rate
        )

    def check_time_units(self) -> None:
        """Timestamps of different files differing by orders of magnitude: s vs ns mix-ups."""
        assert self.mav0 is not None
        mags = {n: magnitude(c.t) for n, c in self.csvs.items() if c.t.size}
        if len(mags) < 2:
            return
        ref_name, outliers = unit_outliers(mags, prefer="imu0")
        ref = mags[ref_name]
        for n in outliers:
            m = mags[n]
            self.add(
                ERROR,
                "units",
                f"timestamps are ~1e{m:.0f} while the other files' are ~1e{ref:.0f} "
                f"({unit_hint(10 ** (m - ref))}); EuRoC timestamps are integer nanoseconds",
                self.mav0 / STREAMS[n][0] / "data.csv",
            )
        if could_be_seconds(mags):
            self.add(
                INFO,
                "units",
                "timestamps are small (< 1e11): if these are seconds, the files are not in "
                "EuRoC's nanoseconds",
            )

    # ---- images -------------------------------------------------------------------------------
    def check_images(self, cam: str) -> None:
        assert self.mav0 is not None
        folder = self.mav0 / cam / "data"
        csv_path = self.mav0 / cam / "data.csv"
        c = self.csvs.get(cam)
        if c is None or c.names is None or not folder.is_dir():
            return
        present = set(os.listdir(folder))
        self.present[cam] = present
        listed = set(c.names)
        missing = [
            (int(li), nm) for li, nm in zip(c.lines, c.names, strict=True) if nm not in present
        ]
        if missing:
            ex = ", ".join(f"{nm} (line {li})" for li, nm in missing[:MAX_EXAMPLES])
            self.add(
                WARNING,
                "images",
                f"{len(missing)} of {len(c.names)} listed image(s) missing: {ex}; the reader "
                "skips those frames",
                csv_path,
                missing[0][0],
            )
        unlisted = sorted(
            n for n in present if n not in listed and n.lower().endswith((".png", ".jpg", ".pgm"))
        )
        if unlisted:
            self.add(
                WARNING,
                "images",
                f"{len(unlisted)} image file(s) not listed in data.csv (ignored by the reader): "
                + ", ".join(unlisted[:MAX_EXAMPLES]),
                folder,
            )
        calib = self.cams.get(cam)
        probs: dict[str, list[str]] = {}
        sizes: dict[tuple[int, int], int] = {}
        usable: list[str] = []
        seen: set[str] = set()
        for name in c.names:
            if name not in present or name in seen:
                continue
            seen.add(name)
            h = read_png_header(folder / name)
            self.headers_read += 1
            if h.problem is not None:
                probs.setdefault(h.problem, []).append(name)
                continue
            sizes[(h.width, h.height)] = sizes.get((h.width, h.height), 0) + 1
            if calib is not None and (h.width, h.height) != calib.resolution:
                probs.setdefault(f"size {h.width}x{h.height}", []).append(name)
                continue
            if h.bit_depth != 8:
                probs.setdefault(f"{h.bit_depth}-bit", []).append(name)
            if h.colour_type != 0:
                probs.setdefault(_COLOUR_TYPES.get(h.colour_type, "colour"), []).append(name)
            usable.append(name)
        for kind, names in probs.items():
            ex = ", ".join(names[:MAX_EXAMPLES])
            if kind.startswith("size "):
                assert calib is not None
                self.add(
                    ERROR,
                    "images",
                    f"{len(names)} image(s) are {kind[5:]} but sensor.yaml resolution is "
                    f"{calib.width}x{calib.height}: {ex}; the reader skips them",
                    folder,
                    key="resolution",
                )
            elif kind.endswith("-bit") or kind in _COLOUR_TYPES.values() or kind == "colour":
                self.add(
                    WARNING,
                    "images",
                    f"{len(names)} image(s) are {kind}, not 8-bit mono: {ex}; the reader "
                    "converts them",
                    folder,
                )
            else:
                self.add(
                    WARNING,
                    "images",
                    f"{len(names)} unreadable image(s), {kind}: {ex}; the reader skips them",
                    folder,
                )
        if c.names and not usable:
            self.add(ERROR, "images", f"no usable image among {len(c.names)} listed", folder)
        self.usable[cam] = set(usable)
        self.decode_sample(cam, folder, usable)

    def decode_sample(self, cam: str, folder: Path, usable: list[str]) -> None:
        if not usable:
            return
        if self.full or len(usable) <= self.sample:
            picks = usable
        elif self.sample <= 0:
            return
        else:
            idx = np.unique(np.linspace(0, len(usable) - 1, self.sample).round().astype(int))
            picks = [usable[i] for i in idx]
        unreadable: list[str] = []
        blank: list[str] = []
        for name in picks:
            if self.progress is not None:
                self.progress(1, cam)
            dec = decode_image(folder / name, check_crc=True)
            self.decoded += 1
            if dec.image is None:
                unreadable.append(f"{name} ({dec.problem})")
            elif int(dec.image.min()) == int(dec.image.max()):
                blank.append(f"{name} (every pixel {int(dec.image.min())})")
        what = "all" if len(picks) == len(usable) else f"a sample of {len(picks)}"
        if unreadable:
            self.add(
                WARNING,
                "images",
                f"{len(unreadable)} image(s) of {what} decoded are unreadable: "
                + ", ".join(unreadable[:MAX_EXAMPLES])
                + "; the reader skips them",
                folder,
            )
            self.usable[cam] -= {u.split(" ")[0] for u in unreadable}
        if blank:
            self.add(
                WARNING,
                "images",
                f"{len(blank)} blank image(s) among {what} decoded: "
                + ", ".join(blank[:MAX_EXAMPLES]),
                folder,
            )

    # ---- time overlap ---------------------------------------------------------------------------
    def check_overlap(self) -> None:
        c0, c1 = self.csvs.get("cam0"), self.csvs.get("cam1")
        if c0 is None or c1 is None or c0.t.size == 0 or c1.t.size == 0:
            return
        t0, t1 = np.unique(c0.t), np.unique(c1.t)
        both = np.intersect1d(t0, t1)
        only0, only1 = np.setdiff1d(t0, t1), np.setdiff1d(t1, t0)
        for cam, only, c in (("cam0", only0, c0), ("cam1", only1, c1)):
            if only.size and both.size:
                li = int(c.lines[np.nonzero(c.t == only[0])[0][0]])
                self.add(
                    WARNING,
                    "overlap",
                    f"{only.size} timestamp(s) in {cam} only (first: {only[0]}); the reader "
                    "skips those frames",
                    c.rel,
                    li,
                )
        # complete pairs: both listed and both images usable
        names0 = dict(zip(c0.t.tolist(), c0.names or [], strict=True))
        names1 = dict(zip(c1.t.tolist(), c1.names or [], strict=True))
        u0, u1 = self.usable.get("cam0"), self.usable.get("cam1")
        self.stereo_pairs = sum(
            1
            for t in both.tolist()
            if (u0 is None or names0[t] in u0) and (u1 is None or names1[t] in u1)
        )
        if both.size == 0:
            self.add(
                ERROR,
                "overlap",
                "cam0 and cam1 share no timestamp: no stereo pairs (the reader joins on timestamp)",
                c1.rel,
            )
            return
        if self.stereo_pairs == 0:
            self.add(ERROR, "overlap", "no stereo pair has both images usable")
        a, b = int(both[0]), int(both[-1])
        imu = self.csvs.get("imu0")
        if imu is not None and imu.t.size:
            i0, i1 = int(imu.t.min()), int(imu.t.max())
            tol = int(1e9 / self.rates["imu0"]) if self.rates.get("imu0") else 0
            if i1 < a or i0 > b:
                self.add(
                    ERROR,
                    "overlap",
                    f"IMU [{i0}, {i1}] does not overlap the stereo frames [{a}, {b}]",
                    imu.rel,
                )
            elif i0 > a + tol or i1 < b - tol:
                cover = (min(i1, b) - max(i0, a)) / max(b - a, 1)
                parts = []
                if i0 > a + tol:
                    parts.append(f"starts {(i0 - a) / 1e9:.3f} s after the first stereo frame")
                if i1 < b - tol:
                    parts.append(f"ends {(b - i1) / 1e9:.3f} s before the last stereo frame")
                self.add(
                    WARNING,
                    "overlap",
                    f"IMU {' and '.join(parts)}: it covers {100 * cover:.0f}% of the image span; "
                    "frames outside it have no inertial data",
                    imu.rel,
                )
        for name, label in (("groundtruth", "ground truth"), ("leica0", "leica0")):
            g = self.csvs.get(name)
            if g is None or g.t.size == 0:
                continue
            g0, g1 = int(g.t.min()), int(g.t.max())
            if g1 < a or g0 > b:
                self.add(
                    WARNING if name == "groundtruth" else INFO,
                    "overlap",
                    f"{label} [{g0}, {g1}] does not overlap the stereo frames [{a}, {b}]"
                    + ("; an evaluation against it is impossible" if name == "groundtruth" else ""),
                    g.rel,
                )
            elif g0 > a or g1 < b:
                cover = (min(g1, b) - max(g0, a)) / max(b - a, 1)
                self.add(
                    INFO,
                    "overlap",
                    f"{label} covers {100 * cover:.0f}% of the stereo frames' time span",
                    g.rel,
                )

    # ---- values -------------------------------------------------------------------------------
    def check_values(self) -> None:
        imu = self.csvs.get("imu0")
        if imu is not None and imu.values is not None and imu.t.size:
            ok = np.isfinite(imu.values).all(axis=1)
            if not ok.any():
                return
            acc = np.linalg.norm(imu.values[ok, 3:6], axis=1)
            med = float(np.median(acc))
            if not 5.0 <= med <= 15.0:
                hint = " (in g instead of m/s^2?)" if 0.5 <= med <= 1.5 else ""
                self.add(
                    WARNING,
                    "values",
                    f"median accelerometer norm {med:.3f} m/s^2 is far from gravity{hint}",
                    imu.rel,
                )
            gmax = float(np.abs(imu.values[ok, 0:3]).max())
            if gmax > 35.0:
                self.add(
                    WARNING,
                    "values",
                    f"largest gyroscope value {gmax:.1f} rad/s is implausible (deg/s?)",
                    imu.rel,
                )
        gt = self.csvs.get("groundtruth")
        if gt is not None and gt.values is not None and gt.t.size:
            norms = np.linalg.norm(gt.values[:, 3:7], axis=1)
            zero = np.nonzero(norms < 1e-9)[0]
            if zero.size:
                self.add(
                    ERROR,
                    "values",
                    f"{zero.size} zero quaternion(s) (q_RS_w..z all 0)",
                    gt.rel,
                    int(gt.lines[zero[0]]),
                    "q_RS",
                )
            dev = np.abs(norms - 1.0)
            off = np.nonzero((dev > 1e-3) & (norms >= 1e-9))[0]
            if off.size:
                worst = int(off[np.argmax(dev[off])])
                self.add(
                    WARNING,
                    "values",
                    f"{off.size} quaternion(s) not unit length (worst norm {norms[worst]:.4f}); "
                    "the reader normalises them",
                    gt.rel,
                    int(gt.lines[worst]),
                    "q_RS",
                )

    # ---- the reader's verdict -------------------------------------------------------------------
    def check_reader(self) -> None:
        """Open the sequence with the reader the pipeline uses: anything it refuses is an error."""
        from eurocslam.dataset.asl import AslSequence

        try:
            AslSequence(self.path)
        except EurocSlamError as e:
            msg = str(e).replace(f"{self.root}{os.sep}", "")
            self.add(ERROR, "reader", f"the reader refuses this sequence (convert/run stop): {msg}")
        except Exception as e:
            self.add(
                ERROR,
                "internal",
                f"the reader crashed: {type(e).__name__}: {e} "
                "(a bug in eurocslam; please report it)",
            )


def _expect(name: str) -> str:
    return {
        "cam0": "timestamp, filename",
        "cam1": "timestamp, filename",
        "imu0": "timestamp, gyro xyz, accel xyz",
        "groundtruth": "timestamp, p xyz, q wxyz, v xyz, bg xyz, ba xyz",
        "leica0": "timestamp, p xyz",
    }[name]


def _yaml_rate(data: dict[str, Any]) -> float:
    try:
        r = float(data.get("rate_hz", 0) or 0)
    except (TypeError, ValueError):
        return 0.0
    return r if math.isfinite(r) and r > 0 else 0.0


def diagnose(
    path: Path | str,
    *,
    full: bool = False,
    sample: int = 24,
    progress: Callable[[int, str], Any] | None = None,
) -> DoctorReport:
    """Check a sequence folder (or its `mav0/`). Never raises on bad data: every problem is a
    `Finding`. `sample` images per camera are decoded (all of them with `full`); `progress(n,
    camera)` is called once per decoded image."""
    return _Doctor(path, full=full, sample=sample, progress=progress).run()


def diagnose_bag(
    path: Path | str,
    *,
    calib: Path | str | None = None,
    topics: Any = None,
) -> DoctorReport:
    """The doctor on a ROS bag / MCAP input: `dataset.bag.check_bag`'s findings as a report."""
    from eurocslam.dataset.bag import check_bag

    t0 = time.perf_counter()
    found = check_bag(path, calib=calib, topics=topics)
    findings = sorted(
        (Finding(f.level, "bag", f.message, Path(path).name) for f in found),
        key=lambda f: _SEVERITY_RANK[f.severity],
    )
    return DoctorReport(
        sequence=str(path),
        mav0=None,
        findings=tuple(findings),
        streams=(),
        stereo_pairs=0,
        image_headers_read=0,
        images_decoded=0,
        elapsed_s=time.perf_counter() - t0,
    )
