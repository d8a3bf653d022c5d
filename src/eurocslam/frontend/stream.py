"""The extraction stage over a stream of frames: (frame, features) in frame order.

With `frontend.prefetch` (the default) the next frames are read and decoded by a reader thread
and extracted by `frontend.prefetch_workers` worker processes (`frontend/workers.py`) while the
caller tracks the current one; otherwise, or where worker processes cannot start, inline.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator

from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor, FrameFeatures

logger = logging.getLogger(__name__)


class FeatureStream:
    """Extraction for one rig and configuration; `worker_peak_rss_mb` after a stream ends."""

    def __init__(self, rig: StereoRig, config: FrontendConfig) -> None:
        self.extractor = Extractor(rig, config)
        self.config = config
        self.worker_peak_rss_mb: list[float] = []  # of the last stream's extraction workers

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
            for frame in frames:
                yield frame, self.extractor.extract(frame)
            return
        try:
            yield from workers.stream(frames)
        finally:
            self.worker_peak_rss_mb = workers.peak_rss_mb
