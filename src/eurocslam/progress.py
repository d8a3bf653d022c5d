"""Progress bars on stderr (tqdm), quiet when not a terminal unless asked."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")


def progress(
    it: Iterable[T],
    *,
    total: int | None = None,
    desc: str = "",
    unit: str = "it",
    enabled: bool | None = None,
) -> Iterator[T]:
    """Wrap an iterable in a progress bar. Disabled by default when stderr is not a TTY."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    return iter(
        tqdm(
            it,
            total=total,
            desc=desc,
            unit=unit,
            disable=not enabled,
            dynamic_ncols=True,
            file=sys.stderr,
        )
    )


def bar(*, total: float | None, desc: str, unit: str = "it", enabled: bool | None = None) -> tqdm:
    """A manual progress bar (`update`, `set_postfix`) for loops with live figures."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    return tqdm(
        total=total, desc=desc, unit=unit, disable=not enabled, dynamic_ncols=True, file=sys.stderr
    )
