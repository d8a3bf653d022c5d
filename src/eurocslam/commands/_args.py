"""Argument types shared by the subcommands (not a command itself: the CLI skips `_` modules).

argparse's plain `type=float` accepts `nan` and `inf`, which then fail deep inside as an internal
error; these reject them at the command line with argparse's usual one-line message."""

from __future__ import annotations

import argparse
import math


def finite_float(value: str) -> float:
    """A finite number (`nan`/`inf` rejected)."""
    try:
        v = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{value}' is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"'{value}' is not a finite number")
    return v


def positive_float(value: str) -> float:
    """A finite number > 0."""
    v = finite_float(value)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"'{value}' must be > 0")
    return v
