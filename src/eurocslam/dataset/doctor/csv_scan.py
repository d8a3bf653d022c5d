"""Scanning the CSVs of an ASL folder tolerantly: every problem is collected (counted, with the
first lines as examples) instead of stopping at the first, and the good rows are kept for the
timestamp, overlap and value checks."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from eurocslam.dataset.asl import parse_numeric_rows
from eurocslam.dataset.doctor.report import ERROR, INFO, WARNING, Findings
from eurocslam.dataset.types import I64
from eurocslam.errors import EurocSlamError
from eurocslam.timebase import looks_like_seconds, parse_timestamp

GT = "state_groundtruth_estimate0"
# stream name -> (folder, number of CSV columns, required)
STREAMS: dict[str, tuple[str, int, bool]] = {
    "cam0": ("cam0", 2, True),
    "cam1": ("cam1", 2, True),
    "imu0": ("imu0", 7, True),
    "groundtruth": (GT, 17, False),
    "mocap0": ("mocap0", 8, False),  # TUM-VI's ground truth (the IMU's pose)
    "leica0": ("leica0", 4, False),
}
MAX_EXAMPLES = 3


@dataclass
class Problems:
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
class ScannedCsv:
    """The good rows of one CSV."""

    name: str
    rel: str
    t: I64  # timestamps of the good rows, in file order
    lines: I64  # their 1-based line numbers
    values: np.ndarray | None  # (N, ncols - 1) for numeric CSVs
    names: list[str] | None  # image file names for camera CSVs


def expect(name: str) -> str:
    """The columns a stream's CSV should have, for messages."""
    return {
        "cam0": "timestamp, filename",
        "cam1": "timestamp, filename",
        "imu0": "timestamp, gyro xyz, accel xyz",
        "groundtruth": "timestamp, p xyz, q wxyz, v xyz, bg xyz, ba xyz",
        "leica0": "timestamp, p xyz",
        "mocap0": "timestamp, p xyz, q wxyz",
    }[name]


def scan_csv(
    found: Findings, name: str, path: Path, ncols: int, required: bool
) -> ScannedCsv | None:
    """Every row of one ASL CSV, tolerantly: each kind of problem is one finding (counted, a few
    examples); the good rows are kept for the other checks. None when the file is not usable
    text at all (empty, not UTF-8)."""
    raw = path.read_bytes()
    if not raw.strip():
        found.add(ERROR if required else WARNING, "csv", "empty file", path)
        return None
    if raw.startswith(b"\xef\xbb\xbf"):
        found.add(INFO, "csv", "starts with a UTF-8 byte-order mark (tolerated)", path)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        found.add(ERROR, "csv", f"not a text file (byte {e.start} is not UTF-8)", path, line)
        return None
    lines = text.splitlines()
    is_image = ncols == 2
    rows = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
    blank = len(lines) - len(rows)
    if blank:
        found.add(INFO, "csv", f"{blank} blank line(s) (ignored)", path)
    header = next(((no, ln) for no, ln in rows if ln.lstrip().startswith("#")), None)
    data_rows = [(no, ln) for no, ln in rows if not ln.lstrip().startswith("#")]
    if header is None:
        found.add(WARNING, "csv", "no '#' header line", path, 1)
    elif header[0] != rows[0][0]:
        found.add(WARNING, "csv", "header is not the first line", path, header[0])
    else:
        hcols = len(header[1].split(","))
        if hcols != ncols:
            found.add(
                ERROR,
                "csv",
                f"header has {hcols} columns, expected {ncols} ({expect(name)})",
                path,
                header[0],
            )
    probs: dict[str, Problems] = {}
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
            probs.setdefault(kind, Problems()).add(no, f"{len(parts)} columns")
            continue
        try:
            ti = parse_timestamp(parts[0], "")
        except EurocSlamError:
            kind = "seconds" if looks_like_seconds(parts[0]) else "timestamp"
            probs.setdefault(kind, Problems()).add(no, repr(parts[0]))
            continue
        if is_image:
            assert names is not None
            if not parts[1]:
                probs.setdefault("filename", Problems()).add(no, "empty file name")
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
                probs.setdefault(bad, Problems()).add(no, ln.strip()[:60])
            vals[n] = row
        t[n] = ti
        nos[n] = no
        n += 1
    messages = {
        "truncated": (WARNING, "truncated last row ({ex}); the reader skips it"),
        "columns": (ERROR, f"{{n}} row(s) without {ncols} columns ({expect(name)}): {{ex}}"),
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
        found.add(sev, "csv", fmt.format(n=p.count, ex=ex), path, p.lines[0])
    if n == 0 and not probs:
        found.add(ERROR if required else WARNING, "csv", "no data rows", path)
    return ScannedCsv(
        name,
        found.rel(path) or "",
        t[:n],
        nos[:n],
        vals[:n] if vals is not None else None,
        names,
    )
