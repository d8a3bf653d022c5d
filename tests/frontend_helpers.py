"""The frontend's two stages run one after the other on single frames, as the pipeline does."""

from __future__ import annotations

from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.types import StereoFrame
from eurocslam.frontend.config import FrontendConfig
from eurocslam.frontend.extraction import Extractor
from eurocslam.frontend.tracker import StereoTracker
from eurocslam.frontend.types import FrontendResult
from eurocslam.geometry import F64


class Frontend:
    def __init__(self, rig: StereoRig, config: FrontendConfig | None = None) -> None:
        config = config or FrontendConfig()
        self.extractor = Extractor.for_rig(rig, config)
        self.tracker = StereoTracker(self.extractor.rectifier, config)

    def process(self, frame: StereoFrame, T_world_body_pred: F64 | None = None) -> FrontendResult:
        return self.tracker.track(self.extractor.extract(frame), T_world_body_pred)
