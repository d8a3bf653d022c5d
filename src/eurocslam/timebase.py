"""The time base: int64 nanoseconds inside, and the one rule that tells seconds from nanoseconds.

Every timestamp in eurocslam is an integer number of nanoseconds (`int`, or `int64` arrays:
`I64`). Units outside:

* EuRoC ASL CSVs (`mav0/*/data.csv`) and EuRoC trajectory CSVs: integer nanoseconds;
* TUM trajectory files: decimal seconds, converted exactly (`seconds_str_to_ns`,
  `ns_to_seconds_str`: a write/read round trip keeps every nanosecond);
* `--start`/`--end` on the command line: seconds from the sequence start, or an absolute
  nanosecond timestamp when at least `ABSOLUTE_NS_MIN` (1e15) (`resolve_time`).

Seconds or nanoseconds? One rule, by magnitude:

* `SECONDS_MAX` = 1e11: no time in seconds is larger (3,000 years; Unix time is ~1.7e9 s). A time
  column in seconds with a larger value holds nanoseconds; a number token with a fraction or an
  exponent looks like seconds only up to this value (`looks_like_seconds`).
* `NS_MIN` = 1e7: an integer nanosecond column whose largest value is below 10 ms holds seconds
  (relative nanosecond times from 0, as synthetic sequences can have, pass it after 10 ms).
* `UNIT_MIX_ORDERS` = 2: streams of one recording whose median timestamps differ by more than 100x
  are a unit mix-up (seconds, milli- or microseconds among nanoseconds); the reference is the
  magnitude most streams agree with, the IMU's on a tie (`unit_outliers`).

So a token such as `'1403636580838555648.5'` (a fraction, but far above `SECONDS_MAX`) is a
malformed nanosecond stamp, not seconds; `'-inf'` or `'nan'` never look like seconds; the reader
and the doctor take the same reference stream when they look for a unit mix-up, and the doctor's
note "timestamps are small" uses `SECONDS_MAX`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Hashable, Mapping
from decimal import Decimal, InvalidOperation
from typing import Any, Final, Literal, TypeVar, overload

import numpy as np
from numpy.typing import NDArray

from eurocslam.errors import DatasetError

I64 = NDArray[np.int64]
Unit = Literal["s", "ns"]
K = TypeVar("K", bound=Hashable)

NS_PER_S: Final = 1_000_000_000
INT64_MAX: Final = 2**63 - 1
SECONDS_MAX: Final = 1e11
NS_MIN: Final = 1e7
UNIT_MIX_ORDERS: Final = 2.0
ABSOLUTE_NS_MIN: Final = 10**15

_DEC_RE = re.compile(r"^([+-]?)(\d*)(?:\.(\d*))?$")


# ---- float seconds for numeric kernels ----------------------------------------------------------
@overload
def ns_to_s(dt_ns: int | float) -> float: ...
@overload
def ns_to_s(dt_ns: NDArray[Any]) -> NDArray[np.float64]: ...
def ns_to_s(dt_ns: int | float | NDArray[Any]) -> float | NDArray[np.float64]:
    """A duration, or a time relative to a t0, in nanoseconds as float seconds (`dt_ns *
    1e-9`): the one conversion numeric kernels use. Absolute EuRoC stamps (1.4e18 ns) lose
    their nanoseconds in a float: subtract the t0 first."""
    return dt_ns * 1e-9


def s_to_ns(s: float) -> int:
    """Float seconds as int64 nanoseconds, rounded to the nearest."""
    return round(s * 1e9)


# ---- tokens -----------------------------------------------------------------------------------


def looks_like_seconds(tok: str) -> bool:
    """A timestamp token that is a finite decimal number with a fraction or an exponent, at most
    `SECONDS_MAX` in size: `'1403636580.838'`, `'1.4e9'`; not `'1403636580838555648.5'`,
    `'-inf'`, `'abc'` or an integer."""
    s = tok.strip()
    if "." not in s and "e" not in s.lower():
        return False
    try:
        v = float(s)
    except ValueError:
        return False
    return math.isfinite(v) and abs(v) <= SECONDS_MAX


def parse_timestamp(tok: str, where: str) -> int:
    """An integer-nanosecond timestamp in [0, 2^63); `DatasetError` naming `where` otherwise
    (with a hint when the token looks like seconds)."""
    try:
        t = int(tok)
    except ValueError:
        hint = " (looks like seconds; expected integer nanoseconds)"
        raise DatasetError(
            f"{where}: timestamp '{tok}' is not an integer"
            + (hint if looks_like_seconds(tok) else "")
        ) from None
    if not 0 <= t <= INT64_MAX:
        raise DatasetError(
            f"{where}: timestamp '{tok}' is out of range (integer nanoseconds, 0 <= t < 2^63)"
        )
    return t


class FractionalNs(ValueError):
    """A nanosecond token with a non-zero fractional part."""


def int_ns(tok: str) -> int:
    """Integer nanoseconds from a token; also '1403636580838555648.000000' (ORB-SLAM style).

    A non-zero fractional part raises `FractionalNs`; anything else that is not a number raises
    ValueError (or `decimal.InvalidOperation`)."""
    try:
        return int(tok)
    except ValueError:
        pass
    m = _DEC_RE.match(tok)
    if m and m.group(2):
        if (m.group(3) or "").strip("0"):
            raise FractionalNs(tok)
        return int(m.group(1) + m.group(2))
    d = Decimal(tok)  # raises InvalidOperation: the caller reports
    if not d.is_finite():
        raise ValueError(tok)
    if d != d.to_integral_value():
        raise FractionalNs(tok)
    return int(d)


def seconds_str_to_ns(tok: str) -> int:
    """Exact conversion of a decimal seconds string ('1403636580.838555648', '1.4e+09') to ns.

    Digits beyond the nanosecond are rounded half away from zero. Raises ValueError.
    """
    ip, dot, fp = tok.partition(".")
    if ip.isdigit() and (fp.isdigit() or (dot and not fp)) and len(fp) <= 9:
        return int(ip) * NS_PER_S + (int(fp.ljust(9, "0")) if fp else 0)
    m = _DEC_RE.match(tok)
    if m and (m.group(2) or m.group(3)):
        sign, ip, fp = m.group(1), m.group(2) or "0", m.group(3) or ""
        frac = (fp + "000000000")[:9]
        ns = int(ip) * NS_PER_S + int(frac)
        if len(fp) > 9 and fp[9] >= "5":
            ns += 1
        return -ns if sign == "-" else ns
    try:
        d = Decimal(tok)
    except InvalidOperation:
        raise ValueError(tok) from None
    if not d.is_finite():
        raise ValueError(tok)
    return int((d * NS_PER_S).to_integral_value(rounding="ROUND_HALF_UP"))


def ns_to_seconds_str(t_ns: int) -> str:
    """Exact decimal seconds with 9 digits: 1403636580838555648 -> '1403636580.838555648'."""
    t = int(t_ns)
    sign = "-" if t < 0 else ""
    s, ns = divmod(abs(t), NS_PER_S)
    return f"{sign}{s}.{ns:09d}"


def stamp_ns(sec: int, nanosec: int) -> int:
    """A ROS `(sec, nanosec)` stamp in nanoseconds."""
    return int(sec) * NS_PER_S + int(nanosec)


def resolve_time(value: float | None, t_ref_ns: int) -> int | None:
    """A command-line time: seconds relative to `t_ref_ns`, or an absolute nanosecond timestamp
    when `|value| >= ABSOLUTE_NS_MIN` (1e15)."""
    if value is None:
        return None
    if abs(value) >= ABSOLUTE_NS_MIN:
        return int(value)
    return t_ref_ns + s_to_ns(value)


# ---- columns and streams ----------------------------------------------------------------------


def column_unit_mismatch(t_ns: I64, unit_in_file: Unit) -> int | None:
    """Index of the value that shows a column read in `unit_in_file` holds the other unit, or
    None: a seconds column with a value above `SECONDS_MAX` s (nanoseconds), an integer
    nanosecond column whose largest value is below `NS_MIN` ns (seconds)."""
    if t_ns.size == 0:
        return None
    a = np.abs(t_ns)
    k = int(np.argmax(a))
    mag = float(a[k])
    if unit_in_file == "s" and mag / NS_PER_S > SECONDS_MAX:
        return k
    if unit_in_file == "ns" and 0 < mag < NS_MIN:
        return k
    return None


def magnitude(t_ns: I64) -> float:
    """log10 of a stream's median timestamp (0 for an empty stream or one near 0)."""
    if t_ns.size == 0:
        return 0.0
    return math.log10(max(abs(float(np.median(t_ns))), 1.0))


def unit_outliers(mags: Mapping[K, float], prefer: K) -> tuple[K, list[K]]:
    """The reference stream (the magnitude most streams agree with within `UNIT_MIX_ORDERS`;
    `prefer` on a tie, then the first) and the streams more than `UNIT_MIX_ORDERS` orders of
    magnitude from it, in `mags`' order. `mags` must not be empty."""

    def support(key: K) -> tuple[int, bool]:
        agree = sum(abs(m - mags[key]) <= UNIT_MIX_ORDERS for m in mags.values())
        return agree, key == prefer

    ref = max(mags, key=support)
    return ref, [k for k, m in mags.items() if abs(m - mags[ref]) > UNIT_MIX_ORDERS]


def could_be_seconds(mags: Mapping[K, float]) -> bool:
    """Every stream's median timestamp is at most `SECONDS_MAX`: they might all be seconds."""
    return all(m <= math.log10(SECONDS_MAX) for m in mags.values())


def unit_hint(ratio: float) -> str:
    """Name the unit mix-up a ratio (measured / expected) suggests."""
    e = round(math.log10(ratio) / 3) * 3 if ratio > 0 else 0
    return {
        -9: "timestamps in seconds?",
        -6: "timestamps in milliseconds?",
        -3: "timestamps in microseconds?",
        3: "timestamps in picoseconds, or rate_hz wrong?",
        9: "seconds and nanoseconds mixed?",
    }.get(e, "wrong rate_hz or wrong time unit?")


# Foxglove's own rule (studio-base `isAbsoluteTime`): a time of at most 20 years (of 365 days) in
# seconds is a duration, not a date: its sidebar then shows the start and end as seconds
# (`0.000000000`), where a Unix time shows as a date.
RELATIVE_STAMP_MAX_NS: Final = 20 * 365 * 24 * 3600 * 1_000_000_000


def time_base(t_first_ns: int) -> Literal["relative", "unix"]:
    """ "relative" when a recording's first stamp is a sequence's own clock (KITTI's times.txt
    from 0 s, a synthetic sequence), "unix" when it is Unix time (EuRoC, a robot's bag)."""
    return "relative" if t_first_ns <= RELATIVE_STAMP_MAX_NS else "unix"
