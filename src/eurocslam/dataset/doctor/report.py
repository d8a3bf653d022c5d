"""The doctor's report: one `Finding` type for every check (ASL folders and bags), the report
with its text and JSON forms, and `Findings`, the collector the checks add to.

Severity follows what the reader does with the problem:
  error   the reader refuses the sequence, or its output would be wrong (no stereo pairs, image
          size different from the calibration, seconds mixed with nanoseconds, broken calibration)
  warning the reader copes (skips and counts, sorts, converts) but the data is not as it should be
          (missing images, gaps, duplicates, partial time overlap, implausible calibration)
  info    worth knowing, harmless (no ground truth, a byte-order mark, blank lines)
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from eurocslam.errors import EurocSlamError
from eurocslam.timebase import NS_PER_S

ERROR = "error"
WARNING = "warning"
INFO = "info"
SEVERITY_RANK = {ERROR: 0, WARNING: 1, INFO: 2}


def exit_code(findings: Iterable[Finding]) -> int:
    """0 ok (info only), 1 warnings, 2 errors."""
    severities = {f.severity for f in findings}
    return 2 if ERROR in severities else 1 if WARNING in severities else 0


@dataclass(frozen=True)
class Finding:
    """One problem. `file` is relative to the sequence folder; `line` is 1-based."""

    severity: str  # "error" | "warning" | "info"
    check: str  # files, csv, timestamps, images, calibration, overlap, units, values, reader, bag
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
        return (self.t_last_ns - self.t_first_ns) / NS_PER_S


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
        return exit_code(self.findings)

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


class Findings:
    """Collects findings; files are named relative to `root` (the sequence folder)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.items: list[Finding] = []

    def add(
        self,
        severity: str,
        check: str,
        message: str,
        file: Path | str | None = None,
        line: int | None = None,
        key: str | None = None,
    ) -> None:
        self.items.append(Finding(severity, check, message, self.rel(file), line, key))

    def rel(self, p: Path | str | None) -> str | None:
        if p is None:
            return None
        p = Path(p)
        try:
            return p.relative_to(self.root).as_posix()
        except ValueError:
            return str(p)

    def sorted(self) -> tuple[Finding, ...]:
        """Errors first, then warnings, then notes; by file and line within each."""
        return tuple(
            sorted(self.items, key=lambda f: (SEVERITY_RANK[f.severity], f.file or "", f.line or 0))
        )

    def reader_verdict(self, open_reader: Callable[[], object], folder: Path) -> None:
        """Open the sequence with the reader the pipeline uses: anything it refuses is an error
        (paths inside `folder` shortened)."""
        try:
            open_reader()
        except EurocSlamError as e:
            msg = str(e).replace(f"{folder}{os.sep}", "")
            self.add(ERROR, "reader", f"the reader refuses this sequence (convert/run stop): {msg}")
        except Exception as e:
            self.add(
                ERROR,
                "internal",
                f"the reader crashed: {type(e).__name__}: {e} "
                "(a bug in eurocslam; please report it)",
            )

    @contextmanager
    def guard(self, check: str, file: Path | None = None) -> Iterator[None]:
        """Turn what a check raises into an error finding, so the other checks still run."""
        try:
            yield
        except EurocSlamError as e:
            msg = strip_path(str(e), file) if file is not None else str(e)
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


def strip_path(message: str, path: Path) -> str:
    """'<abs path>: msg' -> 'msg' (the finding names the file already)."""
    for prefix in (f"{path}: ", f"{path}:"):
        if message.startswith(prefix):
            return message[len(prefix) :]
    return message
