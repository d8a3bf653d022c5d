"""Options of one `eurocslam run` that are not SLAM configuration: what to process and how to
write it. Light on imports, so the command line can show its defaults without loading GTSAM."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

COMPRESSIONS = ("zstd", "lz4", "none")
IMAGE_MODES = ("raw", "png", "jpeg")


@dataclass(frozen=True)
class RunOptions:
    start: float | None = None  # seconds from the sequence start, or absolute ns (>= 1e15)
    end: float | None = None
    mcap: bool = True
    compression: str = "lz4"  # MCAP chunk compression, one of COMPRESSIONS
    images: str = "raw"  # how images go into the MCAP, one of IMAGE_MODES
    progress: bool | None = None  # None: when stderr is a terminal
    # an earlier run's OUT/map to localize in and map on (its frame becomes this run's)
    map: Path | None = None
    # keep the earlier map as it is: OUT/map is not written (without --map: no OUT/map either)
    localize_only: bool = False
