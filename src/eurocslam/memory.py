"""What the current process may use and has used: its cores, its peak memory."""

from __future__ import annotations

import math
import os
import sys


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity where the platform has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MB (NaN where unknown).

    Linux: `VmHWM`, the high-water mark of this process's own memory. Not `ru_maxrss`: that
    survives exec, so a worker process started by a large parent reports the parent's peak.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource
    except ImportError:  # pragma: no cover - Windows
        return math.nan
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # kilobytes on Linux, bytes on macOS
    return rss / (1024.0 * 1024.0 if sys.platform == "darwin" else 1024.0)
