"""`eurocslam run` as a library call: one pass over a sequence writing every output.

    result = run_slam(source, out_dir, cfg, RunOptions(...))

Writes into `out_dir`:

* `run.mcap`: everything `eurocslam convert` writes (same single pass, the images the pipeline
  already decoded; with `--images png` their 8-bit grey PNG files as they are) plus the SLAM
  topics of `io/slam_topics.py`;
* `trajectory_online.tum` / `trajectory_online.csv`: the causal per-frame estimate;
* `trajectory_final.tum` / `trajectory_final.csv`: after the final batch optimisation;
* `map.ply`: the batch-optimised landmarks (with their segment);
* `map/`: the map for later sessions (`run --map OUT/map`; maps/store.py): keyframes with their
  descriptors and bag-of-words vectors, landmarks; with `--map`, the union of the earlier map
  and this session's (unless `localize_only`);
* `config.yaml`: the resolved configuration; `summary.json` / `summary.txt`: the run summary.

Trajectories carry segment ids (`# segment N` lines) when the estimator was reset.

Everything that can be checked (the configuration and its mode against the sequence, the time
range) is checked before anything on disk is touched. The outputs are written beside the
previous run's (`io/staging.py`) and swapped in once complete: a run that fails leaves the
previous outputs as they were, plus `run.mcap.partial` (readable) if it had written frames.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from eurocslam.config import RunConfig
from eurocslam.dataset.types import SequenceSource
from eurocslam.errors import OutputError
from eurocslam.io.layout import run_layout, write_run_layouts
from eurocslam.io.ply import write_ply
from eurocslam.io.sink import Sink
from eurocslam.io.staging import StagedOutputs
from eurocslam.maps.store import save_map
from eurocslam.pipeline.outputs import RunResult
from eurocslam.pipeline.records import FrameOutput
from eurocslam.pipeline.session_map import PriorMap
from eurocslam.pipeline.slam import SlamPipeline
from eurocslam.progress import bar
from eurocslam.run_options import COMPRESSIONS, IMAGE_MODES, RunOptions
from eurocslam.trajectory import Trajectory
from eurocslam.trajectory_io import write_euroc_csv, write_tum

logger = logging.getLogger(__name__)

OUTPUT_NAMES = (
    "run.mcap",
    "run.mcap.partial",
    "trajectory_online.tum",
    "trajectory_online.csv",
    "trajectory_final.tum",
    "trajectory_final.csv",
    "map.ply",
    "map",
    "config.yaml",
    "summary.json",
    "summary.txt",
    "layout.json",
    "layout-1.48.json",
)


def _for_files(traj: Trajectory) -> Trajectory:
    """Segment ids are written only where the run has several."""
    return traj if traj.has_segments else dataclasses.replace(traj, segment=None)


def write_outputs(out_dir: Path, result: RunResult, cfg: RunConfig) -> None:
    online, final = _for_files(result.online), _for_files(result.final)
    mode = result.summary.mode
    write_tum(
        out_dir / "trajectory_online.tum",
        online,
        f"eurocslam {mode}: online (causal) pose per frame, body in world",
    )
    write_euroc_csv(out_dir / "trajectory_online.csv", online)
    write_tum(
        out_dir / "trajectory_final.tum",
        final,
        f"eurocslam {mode}: final trajectory after batch optimisation, body in world",
    )
    write_euroc_csv(out_dir / "trajectory_final.csv", final)
    write_ply(out_dir / "map.ply", result.landmarks, segment=result.landmark_segment)
    try:
        (out_dir / "config.yaml").write_text(cfg.to_yaml())
        (out_dir / "summary.json").write_text(json.dumps(result.summary.to_dict(), indent=2))
        (out_dir / "summary.txt").write_text("\n".join(result.summary.lines()) + "\n")
    except OSError as e:
        raise OutputError(f"{out_dir}: cannot write: {e}") from None


def _frames_in_range(source: SequenceSource, t0: int | None, t1: int | None) -> int:
    ft = np.asarray(source.frame_times)
    lo = t0 if t0 is not None else ft.min(initial=0)
    hi = t1 if t1 is not None else ft.max(initial=0)
    return int(np.sum((ft >= lo) & (ft <= hi)))


def run_slam(
    source: SequenceSource,
    out_dir: Path | str,
    cfg: RunConfig | None = None,
    options: RunOptions | None = None,
    extra_sinks: Sequence[Sink] = (),
) -> RunResult:
    """`extra_sinks` (e.g. the live view's `io.live.LiveSink`) receive every message that goes
    into run.mcap, in the same order, from the pipeline thread; the caller closes them."""
    from eurocslam.convert import sequence_start_ns
    from eurocslam.timebase import resolve_time

    opt = options or RunOptions()
    out_dir = Path(out_dir)
    if opt.compression not in COMPRESSIONS:
        raise OutputError(f"compression {opt.compression!r}: one of {', '.join(COMPRESSIONS)}")
    if opt.images not in IMAGE_MODES:
        raise OutputError(f"images {opt.images!r}: one of {', '.join(IMAGE_MODES)}")
    t_ref = sequence_start_ns(source)
    t0, t1 = resolve_time(opt.start, t_ref), resolve_time(opt.end, t_ref)
    if t0 is not None and t1 is not None and t1 < t0:
        raise OutputError(f"--end ({opt.end}) is before --start ({opt.start})")
    n_frames = _frames_in_range(source, t0, t1)
    if n_frames == 0:
        raise OutputError(f"{source.name}: no stereo frames in the selected time range")
    prior = PriorMap.load(opt.map) if opt.map is not None else None
    pipeline = SlamPipeline(source, cfg, prior_map=prior)
    cfg = pipeline.cfg  # the mode resolved against the source

    staged = StagedOutputs(out_dir, OUTPUT_NAMES)
    started = False  # a frame has been processed (and written)
    mcap: _McapOutput | None = None
    try:
        mcap = _McapOutput(source, staged.dir, cfg, opt, t0, t1, extra_sinks) if opt.mcap else None
        if mcap is not None:
            pipeline.observers.append(mcap.writer)
        pb = bar(total=n_frames, desc=f"run {source.name}", unit="frame", enabled=opt.progress)

        tracked = 0  # of the last frame tracked (a frame left out by track_every has no count)

        def progress(out: FrameOutput) -> None:
            nonlocal started, tracked
            started = True
            pb.update(1)
            if not out.left_out:
                tracked = out.frontend.n_tracked if out.frontend else 0
            if pb.n == n_frames:  # the final batch follows: seconds on a long sequence
                pb.set_postfix_str("final batch: optimising the whole trajectory and map ...")
            elif pb.n % 10 == 0 or out.reset_reason:
                pb.set_postfix(
                    state=out.state.value,
                    tracked=tracked,
                    kf=out.n_keyframes,
                    resets=out.n_resets,
                    refresh=False,
                )

        try:
            result = pipeline.run(t0, t1, on_progress=progress)
        finally:
            pb.close()
        if mcap is not None:
            mcap.finish(result)
            write_run_layouts(
                staged.dir,
                run_layout(
                    inertial=cfg.inertial, images=opt.images, points=mcap.run_positions(result)
                ),
            )
        write_outputs(staged.dir, result, cfg)
        saved = None if opt.localize_only else pipeline.saved_map()
        if saved is not None:
            try:
                save_map(staged.dir / "map", saved)
            except OSError as e:
                raise OutputError(f"{out_dir}: cannot write the map: {e}") from None
    except BaseException as e:
        partial = mcap.abort() if mcap is not None else None
        kept = staged.abandon(keep=[partial.name] if partial is not None and started else [])
        if kept:
            logger.warning(
                "eurocslam run: stopped early (%s); what was written so far is in %s (a readable "
                "MCAP); the previous outputs in %s are unchanged",
                type(e).__name__,
                kept[0],
                out_dir,
            )
        raise
    staged.commit()
    return result


class _McapOutput:
    """run.mcap: the sensor streams and the SLAM topics through a writer thread."""

    def __init__(
        self,
        source: SequenceSource,
        folder: Path,
        cfg: RunConfig,
        opt: RunOptions,
        t0: int | None,
        t1: int | None,
        extra_sinks: Sequence[Sink],
    ) -> None:
        from eurocslam.convert import calibration_attachments
        from eurocslam.io.drone import flies_on
        from eurocslam.io.mcap_writer import McapSink
        from eurocslam.io.sensor_streams import SensorStreams, StreamOptions
        from eurocslam.io.sink import TeeSink, ThreadedSink
        from eurocslam.io.slam_topics import SlamMcapWriter
        from eurocslam.timebase import time_base

        self.source = source
        streams = SensorStreams(
            source,
            StreamOptions(
                images=opt.images,
                t_start_ns=t0,
                t_end_ns=t1,
                rectify_alpha=cfg.frontend.rectify_alpha,  # CameraInfo R/P = the SLAM's
                rectify_fov_deg=cfg.frontend.rectify_fov_deg,
                rectify_size=cfg.frontend.rectify_size,
            ),
        )
        self.mcap = McapSink(folder / "run.mcap", compression=opt.compression)
        self.sink = ThreadedSink(self.mcap)
        try:
            for name, data in calibration_attachments(source).items():
                self.mcap.add_attachment(name, data, "text/yaml", streams.t0_ns)
            self.mcap.add_attachment(
                "config.yaml", cfg.to_yaml().encode(), "text/yaml", streams.t0_ns
            )
            self.mcap.add_metadata(
                "eurocslam",
                {
                    "source": str(getattr(source, "root", source.name)),
                    "mode": cfg.mode,
                    # stamps are the sequence's own (never shifted: trajectories, ground truth
                    # and run.mcap share them, so evaluation is exact); "relative": from 0 s
                    "time_base": time_base(streams.t0_ns),
                    "first_stamp_ns": str(streams.t0_ns),
                },
            )
            dest = TeeSink([self.sink, *extra_sinks]) if extra_sinks else self.sink
            streams.write_static(dest)
            self.writer = SlamMcapWriter(
                dest,
                streams,
                source.groundtruth,
                cfg.output,
                inertial=cfg.inertial,
                drone_model=cfg.output.drone_model == "firefly"
                or (cfg.output.drone_model == "auto" and flies_on(source.rig)),
            )
        except BaseException:
            self.abort()
            raise

    def finish(self, result: RunResult) -> None:
        self.writer.finish(result)
        self.sink.close()

    def run_positions(self, result: RunResult) -> np.ndarray:
        """Where the run went, in `world` (what its layout frames): the final trajectory (the
        online one if there is none) and the ground truth as the MCAP places it."""
        traj = result.final if len(result.final) else result.online
        t = traj.t_ns
        parts = [np.asarray(traj.p, dtype=np.float64).reshape(-1, 3)]
        gt, T_w_gw = self.source.groundtruth, self.writer.T_world_gtworld
        if gt is not None and len(gt) and T_w_gw is not None and len(t):
            inside = (gt.t_ns >= t.min()) & (gt.t_ns <= t.max())  # the part this run covered
            p = np.asarray(gt.p, dtype=np.float64)[inside]
            parts.append(p @ T_w_gw[:3, :3].T + T_w_gw[:3, 3])
        return np.concatenate(parts)

    def abort(self) -> Path | None:
        """Stop the writer; the partial MCAP (readable), or None if it could not be finished."""
        try:
            self.sink.join()
        except BaseException:
            self.sink.abort()
        try:
            return Path(self.mcap.abort())
        except Exception as e:  # pragma: no cover - disk full etc.
            logger.warning("eurocslam run: could not finish %s: %s", self.mcap.partial, e)
            return None
