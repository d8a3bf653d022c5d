"""Trajectory files: TUM and EuRoC CSV, read and write, with exact nanosecond timestamps.

What is read and written is a `eurocslam.trajectory.Trajectory` (poses `T_world_body` with int64
nanosecond times and optional segment ids; see that module).

File formats
------------
TUM (what evo and rpg_trajectory_evaluation read), whitespace separated, one pose per line::

    # comment lines start with '#'
    t[s] x y z qx qy qz qw

Time is in **seconds**. `write_tum` writes it as an exact decimal of the integer nanoseconds
(`1403636580.838555648`), so a write/read round trip is exact to the nanosecond (evo reads it as
a float64: ~0.2 us resolution at EuRoC epochs). Segments: a comment line ``# segment N`` starts
segment N; every pose line after it belongs to N until the next such line. Readers that ignore
comments (evo) see one continuous trajectory. A file without segment lines is one segment (id 0).

EuRoC CSV (ASL `data.csv` style), comma separated, a '#' header line::

    #timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []

Time is integer **nanoseconds**, quaternion **w first**. `write_euroc_csv` appends a 9th column
``segment`` when the trajectory has segments. `read_euroc_csv` also reads the 17-column ASL
ground truth (`state_groundtruth_estimate0/data.csv`; velocity and biases are ignored) and a
trailing `segment` column named in the header.

`read_trajectory(path)` detects the format from the content (separator, header names, number of
columns, timestamp magnitudes), not from the extension. Timestamps are checked against their unit:
a TUM file whose times look like nanoseconds, or a EuRoC CSV whose times look like seconds, is an
`EvalError` that says so (override with `time_unit=`). Every error names the file and line.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from decimal import InvalidOperation
from pathlib import Path
from typing import Literal

import numpy as np

from eurocslam.errors import EvalError, OutputError
from eurocslam.geometry import wxyz_to_xyzw, xyzw_to_wxyz
from eurocslam.textfile import read_text
from eurocslam.timebase import (
    I64,
    NS_PER_S,
    FractionalNs,
    Unit,
    column_unit_mismatch,
    int_ns,
    looks_like_seconds,
    ns_to_seconds_str,
    seconds_str_to_ns,
)
from eurocslam.trajectory import Trajectory

TimeUnit = Literal["auto", "s", "ns"]
Format = Literal["auto", "tum", "euroc"]

EUROC_HEADER = (
    "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []"
)
_SEGMENT_RE = re.compile(r"^#\s*segment\s+(-?\d+)\s*$", re.IGNORECASE)


# ---------------------------------------------------------------------------------------------
# reading


@dataclass(frozen=True)
class _Layout:
    fmt: Literal["tum", "euroc"]
    sep: str | None  # None = whitespace
    ncols: int  # columns per pose line
    w_first: bool
    segment_col: int | None


def _read_lines(path: Path) -> list[str]:
    return read_text(path, EvalError, "trajectory file (TUM or EuRoC CSV)").splitlines()


def _split(line: str, sep: str | None) -> list[str]:
    if sep is None:
        return line.split()
    return [s.strip() for s in line.split(sep)]


def _header_names(lines: list[str]) -> list[str] | None:
    """Column names from the last '#' line before the first data line, if it names columns."""
    header = None
    for ln in lines:
        s = ln.strip()
        if not s:
            continue
        if not s.startswith("#"):
            break
        if _SEGMENT_RE.match(s):
            continue
        body = s.lstrip("#").strip()
        names = [n.strip() for n in (body.split(",") if "," in body else body.split())]
        if len(names) >= 8:
            header = names
    return header


def _detect_layout(path: Path, lines: list[str], fmt: Format) -> _Layout:
    first = next(
        (
            (i + 1, ln.strip())
            for i, ln in enumerate(lines)
            if ln.strip() and not ln.lstrip().startswith("#")
        ),
        None,
    )
    if first is None:
        raise EvalError(f"{path}: no poses (only comments or blank lines)")
    lineno, ln = first
    sep = "," if "," in ln else None
    ncols = len(_split(ln, sep))
    names = _header_names(lines)
    if names is not None and len(names) != ncols:
        names = None  # free-text comment, not a column header
    if fmt == "auto":
        fmt = "euroc" if sep == "," else "tum"
        if names and any(n.lower().startswith("q_rs_w") for n in names):
            fmt = "euroc"
    w_first = fmt == "euroc"
    segment_col = None
    if names:
        lower = [n.lower().split()[0] if n.split() else "" for n in names]
        qw = [i for i, n in enumerate(lower) if n in ("qw", "q_rs_w", "q_w", "w")]
        if qw:
            w_first = qw[0] == 4
        if "segment" in lower:
            segment_col = lower.index("segment")
    if ncols < 8:
        raise EvalError(
            f"{path}:{lineno}: {ncols} columns; a trajectory needs 8 "
            f"({'t x y z qx qy qz qw' if fmt == 'tum' else 't_ns,x,y,z,qw,qx,qy,qz'})"
        )
    if segment_col is None and ncols == 9 and fmt == "euroc":
        raise EvalError(
            f"{path}:{lineno}: 9 columns but no header naming the 9th ('segment'); expected 8 "
            "(pose) or 17 (ASL ground truth)"
        )
    if segment_col is not None and segment_col >= ncols:
        raise EvalError(f"{path}: header names a 'segment' column but rows have {ncols} columns")
    return _Layout(fmt, sep, ncols, w_first, segment_col)


def _check_time_unit(
    path: Path, t_ns: I64, unit_in_file: Unit, lines: np.ndarray, time_unit: TimeUnit
) -> None:
    """Catch seconds-vs-nanoseconds mix-ups from the magnitudes (`timebase`'s rule)."""
    if time_unit != "auto":
        return
    k = column_unit_mismatch(t_ns, unit_in_file)
    if k is None:
        return
    mag = float(abs(t_ns[k]))
    if unit_in_file == "s":
        raise EvalError(
            f"{path}:{lines[k]}: timestamp {mag / NS_PER_S:.6g} s looks like nanoseconds; TUM "
            "time is in seconds (pass --time-unit ns if this file really holds nanoseconds)"
        )
    raise EvalError(
        f"{path}:{lines[k]}: timestamp {mag:.6g} ns looks like seconds; EuRoC CSV time is "
        "integer nanoseconds (pass --time-unit s if this file really holds seconds)"
    )


def read_trajectory(
    path: Path | str,
    fmt: Format = "auto",
    time_unit: TimeUnit = "auto",
    name: str | None = None,
) -> Trajectory:
    """Read a TUM or EuRoC CSV trajectory file (format from the content unless `fmt` is given).

    `time_unit`: 'auto' = the format's own unit (TUM seconds, EuRoC nanoseconds) with a
    magnitude check; 's' or 'ns' force the unit of the time column.
    Raises EvalError naming file and line for every malformed row, non-finite or zero-norm
    quaternion, or timestamps that do not increase within a segment.
    """
    path = Path(path)
    lines = _read_lines(path)
    lay = _detect_layout(path, lines, fmt)
    file_unit: Unit = "s" if lay.fmt == "tum" else "ns"
    unit: Unit = file_unit if time_unit == "auto" else time_unit
    to_ns = seconds_str_to_ns if unit == "s" else int_ns

    # pass 1 (plain Python, cheap): data lines, their tokens and segment ids
    rows: list[list[str]] = []
    line_no: list[int] = []
    seg_ids: list[int] = []
    cur_seg = 0
    saw_segment = lay.segment_col is not None
    for i, raw in enumerate(lines):
        s = raw.strip()
        if not s:
            continue
        if s[0] == "#":
            m = _SEGMENT_RE.match(s)
            if m:
                cur_seg = int(m.group(1))
                saw_segment = True
            continue
        parts = s.split() if lay.sep is None else [x.strip() for x in s.split(lay.sep)]
        if len(parts) != lay.ncols:
            raise EvalError(
                f"{path}:{i + 1}: expected {lay.ncols} columns like the first pose line, "
                f"found {len(parts)}: '{s[:80]}'"
            )
        rows.append(parts)
        line_no.append(i + 1)
        seg_ids.append(cur_seg)
    n = len(rows)
    lineno = np.asarray(line_no, dtype=np.int64)

    # timestamps: exact integer nanoseconds from the decimal text
    t = np.empty(n, dtype=np.int64)
    for k, parts in enumerate(rows):
        try:
            t[k] = to_ns(parts[0])
        except OverflowError:
            hint = (
                "; it looks like nanoseconds but TUM time is seconds (pass --time-unit ns if "
                "this file really holds nanoseconds)"
                if unit == "s"
                else ""
            )
            raise EvalError(
                f"{path}:{line_no[k]}: timestamp '{parts[0]}' is out of range{hint}"
            ) from None
        except FractionalNs:
            if time_unit == "ns" or not looks_like_seconds(parts[0]):
                raise EvalError(
                    f"{path}:{line_no[k]}: timestamp '{parts[0]}' is not an integer number of ns"
                ) from None
            raise EvalError(
                f"{path}:{line_no[k]}: timestamp '{parts[0]}' looks like seconds; EuRoC CSV "
                "time is integer nanoseconds (pass --time-unit s if this file really holds "
                "seconds)"
            ) from None
        except (ValueError, InvalidOperation):
            raise EvalError(
                f"{path}:{line_no[k]}: timestamp '{parts[0]}' is not a number"
            ) from None

    # values: one vectorised conversion; on failure find the row to name it
    try:
        vals = np.array([r[1:8] for r in rows], dtype=np.float64).reshape(n, 7)
    except ValueError:
        for k, r in enumerate(rows):
            try:
                [float(x) for x in r[1:8]]
            except ValueError:
                raise EvalError(
                    f"{path}:{line_no[k]}: non-numeric value in '{' '.join(r)[:80]}'"
                ) from None
        raise
    finite = np.isfinite(vals).all(axis=1)
    if not finite.all():
        k = int(np.argmin(finite))
        raise EvalError(f"{path}:{line_no[k]}: non-finite value in '{' '.join(rows[k])[:80]}'")
    if lay.segment_col is not None:
        seg = np.empty(n, dtype=np.int64)
        for k, r in enumerate(rows):
            try:
                seg[k] = int(float(r[lay.segment_col]))
            except ValueError:
                raise EvalError(
                    f"{path}:{line_no[k]}: segment '{r[lay.segment_col]}' is not an integer"
                ) from None
    else:
        seg = np.asarray(seg_ids, dtype=np.int64)
    _check_time_unit(path, t, unit, lineno, time_unit)

    q_raw = vals[:, 3:7] if lay.w_first else xyzw_to_wxyz(vals[:, 3:7])
    qn = np.linalg.norm(q_raw, axis=1)
    bad = np.flatnonzero(qn < 1e-9)
    if bad.size:
        raise EvalError(f"{path}:{lineno[bad[0]]}: zero-norm quaternion")
    q = q_raw / qn[:, None]
    # timestamps must not go backwards within a segment; repeated stamps are kept (evo keeps
    # them too; `count_repeated_stamps` lets callers warn)
    for sid in np.unique(seg):
        idx = np.flatnonzero(seg == sid)
        d = np.diff(t[idx])
        if np.any(d < 0):
            k = idx[int(np.argmax(d < 0)) + 1]
            raise EvalError(
                f"{path}:{lineno[k]}: timestamp goes backwards (must not decrease within a segment)"
            )
    return Trajectory(
        t,
        np.ascontiguousarray(vals[:, 0:3]),
        q,
        seg if saw_segment else None,
        name if name is not None else path.name,
    )


def count_repeated_stamps(traj: Trajectory) -> int:
    """Number of poses whose timestamp equals the previous pose's in the same segment."""
    n = 0
    for _, seg in traj.segments():
        n += int(np.count_nonzero(np.diff(seg.t_ns) == 0))
    return n


def read_tum(path: Path | str, time_unit: TimeUnit = "auto") -> Trajectory:
    """Read a TUM file (`t[s] x y z qx qy qz qw`, `# segment N` lines allowed)."""
    return read_trajectory(path, "tum", time_unit)


def read_euroc_csv(path: Path | str, time_unit: TimeUnit = "auto") -> Trajectory:
    """Read a EuRoC CSV: 8 columns (pose), 17 (ASL ground truth) or a named `segment` column."""
    return read_trajectory(path, "euroc", time_unit)


# ---------------------------------------------------------------------------------------------
# writing


def _atomic_write(path: Path, text: str) -> None:
    path = Path(path)
    tmp = path.with_name(path.name + ".partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        raise OutputError(f"{path}: cannot write: {e}") from None


def _segment_starts(traj: Trajectory) -> list[tuple[int, int]]:
    """(row index, segment id) where a new segment begins."""
    if traj.segment is None:
        return []
    s = traj.segment
    starts = [0, *(np.flatnonzero(np.diff(s) != 0) + 1).tolist()] if len(s) else []
    return [(i, int(s[i])) for i in starts]


def format_tum(traj: Trajectory, header: str | None = None) -> str:
    """TUM text for `traj` (see the module docstring); `header` becomes comment lines."""
    q = wxyz_to_xyzw(traj.q_wxyz)
    starts = dict(_segment_starts(traj))
    out = []
    if header:
        out += [f"# {h}" for h in header.splitlines()]
    out.append("# timestamp[s] tx ty tz qx qy qz qw")
    for i in range(len(traj)):
        if i in starts:
            out.append(f"# segment {starts[i]}")
        p = traj.p[i]
        out.append(
            f"{ns_to_seconds_str(traj.t_ns[i])} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} "
            f"{q[i, 0]:.9f} {q[i, 1]:.9f} {q[i, 2]:.9f} {q[i, 3]:.9f}"
        )
    return "\n".join(out) + "\n"


def write_tum(path: Path | str, traj: Trajectory, header: str | None = None) -> None:
    """Write a TUM file atomically (`path.partial` then rename). Time: exact seconds.ns.

    Segments become `# segment N` comment lines (only written when `traj.segment` is set).
    Raises OutputError when the file cannot be written.
    """
    _atomic_write(Path(path), format_tum(traj, header))


def format_euroc_csv(traj: Trajectory) -> str:
    with_seg = traj.segment is not None
    out = [EUROC_HEADER + (",segment" if with_seg else "")]
    q = traj.q_wxyz
    for i in range(len(traj)):
        p = traj.p[i]
        row = (
            f"{int(traj.t_ns[i])},{p[0]:.9f},{p[1]:.9f},{p[2]:.9f},"
            f"{q[i, 0]:.9f},{q[i, 1]:.9f},{q[i, 2]:.9f},{q[i, 3]:.9f}"
        )
        if with_seg:
            row += f",{int(traj.segment[i])}"  # type: ignore[index]
        out.append(row)
    return "\n".join(out) + "\n"


def write_euroc_csv(path: Path | str, traj: Trajectory) -> None:
    """Write a EuRoC CSV atomically: integer ns, position, quaternion w first, and a `segment`
    column when `traj.segment` is set. Raises OutputError when the file cannot be written."""
    _atomic_write(Path(path), format_euroc_csv(traj))
