"""The extraction stage over a stream of frames: (frame, features) in frame order.

With `frontend.prefetch` (the default) the next frames are read and decoded by a reader thread
and extracted by `frontend.prefetch_workers` worker processes (`frontend/workers.py`) while the
caller tracks the current one; otherwise, or where worker processes cannot start, inline.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.extraction import Extractor, FrameFeatures

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ExtractionCost:
    """What a stream's extraction cost outside the caller's thread: each worker process's peak
    memory and CPU time, and the reader thread's CPU time (reading and decoding the images).
    Empty when the stream ran inline."""

    worker_peak_rss_mb: tuple[float, ...] = ()
    worker_cpu_s: tuple[float, ...] = ()
    reader_cpu_s: float = 0.0


class FeatureStream:
    """Extraction for one rig and configuration; `cost` after a stream ends."""

    def __init__(self, extractor: Extractor) -> None:
        self.extractor = extractor
        self.config = extractor.config
        self.cost = ExtractionCost()  # of the last stream

    def __call__(
        self, frames: Iterable[StereoFrame]
    ) -> Iterator[tuple[StereoFrame, FrameFeatures]]:
        workers = None
        if self.config.prefetch:
            try:
                from eurocslam.frontend.workers import ExtractionWorkers

                workers = ExtractionWorkers(self.extractor, self.config.prefetch_workers)
            # no shared memory or no processes here (a locked-down container, a platform
            # without pass_fds), or the workers' Python cannot import eurocslam
            except (OSError, ValueError, ImportError, AssertionError) as e:
                logger.warning(
                    "note: feature extraction workers could not start (%s); extracting in this "
                    "process (slower; frontend.prefetch: false silences this)",
                    e,
                )
        if workers is None:
            ex = self.extractor
            for n, frame in enumerate(frames):
                local = ex.without_extraction(frame, n)
                yield frame, ex.extract(frame, checked=True) if local is None else local
            return
        try:
            yield from workers.stream(frames)
        finally:
            self.cost = ExtractionCost(
                tuple(workers.peak_rss_mb), tuple(workers.cpu_s), workers.reader_cpu_s
            )
