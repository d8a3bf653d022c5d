"""Peak memory of the current process."""

from __future__ import annotations

import math
import sys


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
