"""The SLAM pipeline: reader -> extraction -> tracking -> estimator -> observers, one pass.

`slam.SlamPipeline` is the state machine; `records` holds what it hands to observers per frame
(`FrameOutput`) and returns at the end (`RunResult`); `segments` assembles the trajectories of
the segments; `summary` is the run summary.
"""
