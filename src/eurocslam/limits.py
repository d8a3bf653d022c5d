"""Range limits of the configuration: declared beside each field (`limited`), checked by one
function (`check_limits`) with a one-line error naming the file and the dotted key.

A bound is a number or the name of another field of the same section (`le="fast_threshold"`).
Every number without a lower bound of its own must be >= 0 (and not NaN).
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field, fields
from typing import Any

from eurocslam.errors import ConfigError

Bound = float | str | None


@dataclass(frozen=True)
class Limits:
    gt: Bound = None
    ge: Bound = None
    lt: Bound = None
    le: Bound = None

    def broken(self, obj: Any, v: float) -> str | None:
        """The rule `v` (a field of `obj`) breaks, as text ('> 0', '<= 30'), or None."""
        for name, op, holds in _RULES:
            bound = getattr(self, name)
            if bound is None:
                continue
            value = getattr(obj, bound) if isinstance(bound, str) else bound
            if math.isnan(v) or not holds(v, value):
                return f"{op} {bound}"
        return None


_RULES = (
    ("gt", ">", operator.gt),
    ("ge", ">=", operator.ge),
    ("lt", "<", operator.lt),
    ("le", "<=", operator.le),
)
_NON_NEGATIVE = Limits(ge=0)


def limited(
    default: Any, *, gt: Bound = None, ge: Bound = None, lt: Bound = None, le: Bound = None
) -> Any:
    """A dataclass field with its `default` and its range (without `gt` or `ge`: >= 0)."""
    if gt is None and ge is None:
        ge = 0
    return field(default=default, metadata={"limits": Limits(gt, ge, lt, le)})


def check_limits(obj: Any, prefix: str, origin: str) -> None:
    """Every number of the section `obj` (a dataclass named `prefix`) within its limits."""
    for f in fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        rule = f.metadata.get("limits", _NON_NEGATIVE).broken(obj, v)
        if rule is not None:
            raise ConfigError(
                f"{origin}: key '{prefix}.{f.name}' value {v!r} out of range (must be {rule})"
            )
