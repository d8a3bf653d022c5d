"""The time base: one seconds-vs-nanoseconds rule, exact conversions, and the edge cases where the
reader's, the doctor's and the trajectory reader's earlier copies of the rule disagreed."""

from __future__ import annotations

from decimal import InvalidOperation
from pathlib import Path

import numpy as np
import pytest

from eurocslam.errors import DatasetError, EvalError
from eurocslam.timebase import (
    ABSOLUTE_NS_MIN,
    NS_MIN,
    NS_PER_S,
    SECONDS_MAX,
    FractionalNs,
    column_unit_mismatch,
    could_be_seconds,
    int_ns,
    looks_like_seconds,
    magnitude,
    ns_to_seconds_str,
    parse_timestamp,
    resolve_time,
    seconds_str_to_ns,
    stamp_ns,
    unit_hint,
    unit_outliers,
)
from eurocslam.trajectory_io import read_euroc_csv, read_tum


@pytest.mark.parametrize(
    ("tok", "expected"),
    [
        ("1403636580.838555648", True),
        ("1.4e9", True),
        ("1.4E+09", True),
        (" 12.5 ", True),
        ("-0.5", True),
        ("1e11", True),  # SECONDS_MAX itself
        ("1403636580838555648", False),  # an integer is never seconds by its form
        ("1403636580838555648.5", False),  # a fraction, but 4e10 years: a broken ns stamp
        ("1.5e18", False),
        ("2e11", False),
        ("-inf", False),  # the reader's copy called this seconds (v < 1e12), the doctor's not
        ("inf", False),
        ("nan", False),
        ("abc", False),
        ("", False),
    ],
)
def test_looks_like_seconds(tok: str, expected: bool) -> None:
    assert looks_like_seconds(tok) is expected


def test_parse_timestamp_messages() -> None:
    assert parse_timestamp("1403636580838555648", "f:2") == 1403636580838555648
    assert parse_timestamp("0", "f:2") == 0
    with pytest.raises(DatasetError, match=r"^f:2: timestamp '1403715273.4121' is not an integer "):
        parse_timestamp("1403715273.4121", "f:2")
    for tok in ("-inf", "1403636580838555648.5", "12abc"):
        with pytest.raises(DatasetError) as ei:
            parse_timestamp(tok, "f:3")
        assert str(ei.value) == f"f:3: timestamp '{tok}' is not an integer"
    for tok in ("-1", str(2**63)):
        with pytest.raises(DatasetError, match="out of range"):
            parse_timestamp(tok, "f:4")
    assert parse_timestamp(str(2**63 - 1), "f") == 2**63 - 1


def test_int_ns() -> None:
    assert int_ns("1403636580838555648") == 1403636580838555648
    assert int_ns("1403636580838555648.000000") == 1403636580838555648  # ORB-SLAM style
    assert int_ns("-12.0") == -12
    assert int_ns("1.5e3") == 1500
    for tok in ("12.5", "1403636580.838", "1.5e-3"):
        with pytest.raises(FractionalNs):
            int_ns(tok)
    with pytest.raises(ValueError):
        int_ns("inf")
    with pytest.raises(InvalidOperation):
        int_ns("abc")


def test_seconds_strings_are_exact() -> None:
    assert seconds_str_to_ns("1403636580.838555648") == 1403636580838555648
    assert seconds_str_to_ns("1403636580.8385556485") == 1403636580838555649  # half up
    assert seconds_str_to_ns("1.4e+09") == 1_400_000_000 * NS_PER_S
    assert seconds_str_to_ns("-1.5") == -1_500_000_000
    assert seconds_str_to_ns("7.") == 7 * NS_PER_S
    for v in (0, 1, 999_999_999, 1403636580838555648, -5):
        assert seconds_str_to_ns(ns_to_seconds_str(v)) == v
    assert ns_to_seconds_str(-1_500_000_000) == "-1.500000000"
    for tok in ("abc", "inf", "1.2.3"):
        with pytest.raises(ValueError):
            seconds_str_to_ns(tok)


def test_stamp_and_resolve_time() -> None:
    assert stamp_ns(1403636580, 838555648) == 1403636580838555648
    assert resolve_time(None, 5) is None
    assert resolve_time(1.5, 10**18) == 10**18 + 1_500_000_000
    assert resolve_time(-0.5, 10**18) == 10**18 - 500_000_000
    assert resolve_time(float(ABSOLUTE_NS_MIN), 7) == ABSOLUTE_NS_MIN  # absolute
    assert resolve_time(1.4036365808385556e18, 0) == int(1.4036365808385556e18)


def test_column_unit_mismatch() -> None:
    ns = np.array([1403636580838555648, 1403636580888555648], dtype=np.int64)
    secs_read_as_ns = np.array([0, 1_000_000, 2_000_000], dtype=np.int64)  # '0.000, 0.001, ...'
    assert column_unit_mismatch(ns, "ns") is None
    assert column_unit_mismatch(secs_read_as_ns, "ns") == 2
    assert column_unit_mismatch(np.array([0, int(NS_MIN)], dtype=np.int64), "ns") is None
    assert column_unit_mismatch(np.zeros(3, dtype=np.int64), "ns") is None  # all zero: no evidence
    assert column_unit_mismatch(np.zeros(0, dtype=np.int64), "s") is None
    # seconds above SECONDS_MAX do not fit int64 nanoseconds: the parser refuses them first
    # (test_trajectory_column_checks); inside int64, a seconds column is always plausible
    assert np.iinfo(np.int64).max < SECONDS_MAX * NS_PER_S
    assert column_unit_mismatch(np.array([np.iinfo(np.int64).max], dtype=np.int64), "s") is None


def test_unit_outliers_take_the_majority() -> None:
    ns, s = 18.15, 9.15
    # the IMU alone in seconds: the IMU is the outlier (the reader's copy blamed cam0 and cam1)
    ref, out = unit_outliers({"imu0": s, "cam0": ns, "cam1": ns, "gt": ns}, prefer="imu0")
    assert ref == "cam0" and out == ["imu0"]
    ref, out = unit_outliers({"imu0": ns, "cam0": s, "cam1": ns}, prefer="imu0")
    assert ref == "imu0" and out == ["cam0"]
    # a tie: the preferred stream is the reference
    ref, out = unit_outliers({"cam0": s, "imu0": ns}, prefer="imu0")
    assert ref == "imu0" and out == ["cam0"]
    # within 100x: no mix-up
    assert unit_outliers({"imu0": ns, "cam0": ns - 1.9}, prefer="imu0") == ("imu0", [])
    assert magnitude(np.array([10**18, 10**18], dtype=np.int64)) == pytest.approx(18.0)
    assert magnitude(np.zeros(0, dtype=np.int64)) == 0.0


def test_could_be_seconds_uses_seconds_max() -> None:
    epoch_s = float(np.log10(1.4e9))
    relative_ns_5min = float(np.log10(3e11))  # the doctor's copy (< 1e12) noted these
    assert could_be_seconds({"imu0": epoch_s, "cam0": epoch_s})
    assert not could_be_seconds({"imu0": relative_ns_5min, "cam0": relative_ns_5min})
    assert not could_be_seconds({"imu0": epoch_s, "cam0": 18.1})


def test_unit_hint() -> None:
    assert unit_hint(1e-9) == "timestamps in seconds?"
    assert unit_hint(1e-3) == "timestamps in microseconds?"
    assert unit_hint(1e9) == "seconds and nanoseconds mixed?"
    assert unit_hint(30.0) == "wrong rate_hz or wrong time unit?"
    assert unit_hint(0.0) == "wrong rate_hz or wrong time unit?"


# ---- the same rule in the trajectory reader -----------------------------------------------------


def test_euroc_csv_fraction_is_seconds_only_when_small(tmp_path: Path) -> None:
    header = "#timestamp [ns],x,y,z,qw,qx,qy,qz\n"
    secs = tmp_path / "secs.csv"
    secs.write_text(header + "1403636580.5,0,0,0,1,0,0,0\n")
    with pytest.raises(EvalError, match="looks like seconds"):
        read_euroc_csv(secs)
    broken = tmp_path / "broken.csv"
    broken.write_text(header + "1403636580838555648.5,0,0,0,1,0,0,0\n")
    with pytest.raises(EvalError) as ei:
        read_euroc_csv(broken)
    assert "is not an integer number of ns" in str(ei.value)
    assert "seconds" not in str(ei.value)


def test_trajectory_column_checks(tmp_path: Path) -> None:
    tum = tmp_path / "ns.tum"
    tum.write_text("1403636580838555648 0 0 0 0 0 0 1\n")
    with pytest.raises(EvalError, match="looks like nanoseconds"):
        read_tum(tum)
    assert len(read_tum(tum, time_unit="ns")) == 1
    csv = tmp_path / "small.csv"
    csv.write_text("#timestamp [ns],x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n5,0,0,0,1,0,0,0\n")
    with pytest.raises(EvalError, match=r"small.csv:3: timestamp 5 ns looks like seconds"):
        read_euroc_csv(csv)


def test_time_base_follows_foxglove_rule() -> None:
    from eurocslam.timebase import RELATIVE_STAMP_MAX_NS, time_base

    assert time_base(0) == "relative"  # KITTI's times.txt
    assert time_base(5_185_269_000) == "relative"
    assert time_base(1_403_715_273_262_142_976) == "unix"  # EuRoC V1_01
    # Foxglove's isAbsoluteTime: sec > 20 * 365 days is a date
    assert time_base(RELATIVE_STAMP_MAX_NS) == "relative"
    assert time_base(RELATIVE_STAMP_MAX_NS + 1_000_000_000) == "unix"
