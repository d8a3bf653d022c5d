"""Read a small text input (CSV, sensor.yaml, trajectory) with errors that name the file.

UTF-8, with a byte-order mark tolerated (Windows editors and spreadsheets write one); a file that
is not UTF-8 text is an error naming the line of the first bad byte."""

from __future__ import annotations

from pathlib import Path

from eurocslam.errors import EurocSlamError


def read_text(path: Path | str, error: type[EurocSlamError], what: str = "file") -> str:
    """The decoded text of `path`; any problem raises `error` naming the file (and line)."""
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, expected a {what}") from None
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror or e}") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise error(f"{path}:{line}: not a text file (byte {e.start} is not UTF-8)") from None
