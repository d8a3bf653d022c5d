"""What the index pass of a bag records per role: the stamps of its topic (`TopicStats`), what a
camera topic's first message says about its images (`ImageInfo`), and a stream's rate."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.types import I64
from eurocslam.timebase import NS_PER_S


def rate_hz(stamps: I64) -> float:
    """Rate of a stream from the median period of its sorted unique stamps (0: fewer than 2)."""
    t = np.unique(np.asarray(stamps, dtype=np.int64))
    if t.size < 2:
        return 0.0
    return round(NS_PER_S / float(np.median(np.diff(t))), 3)


@dataclass
class TopicStats:
    """Stamps of one role's topic in the order the bag stores them (log-time order)."""

    role: str
    topic: str
    msgtype: str
    header_ns: list[int] | I64 = field(default_factory=list)  # lists while scanning,
    log_ns: list[int] | I64 = field(default_factory=list)  # int64 arrays after `freeze`

    def freeze(self) -> None:
        """Turn the stamp lists into int64 arrays (a quarter of the memory)."""
        self.header_ns = np.asarray(self.header_ns, dtype=np.int64)
        self.log_ns = np.asarray(self.log_ns, dtype=np.int64)

    @property
    def count(self) -> int:
        return len(self.log_ns)

    def header_array(self) -> I64:
        return np.asarray(self.header_ns, dtype=np.int64)

    def log_array(self) -> I64:
        return np.asarray(self.log_ns, dtype=np.int64)

    def unset_stamps(self) -> NDArray[np.bool_]:
        """Messages whose header stamp is zero though they were logged later: the stamp was never
        set (a stamp and log time both 0, as a sequence whose times start at 0 has, is real)."""
        unset: NDArray[np.bool_] = (self.header_array() == 0) & (self.log_array() != 0)
        return unset

    @property
    def zero_stamps(self) -> int:
        return int(np.count_nonzero(self.unset_stamps()))


@dataclass(frozen=True)
class ImageInfo:
    """What the first message of a camera topic says about its images."""

    topic: str
    msgtype: str
    encoding: str  # Image encoding, or CompressedImage format
    width: int
    height: int
