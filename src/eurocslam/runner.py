"""`eurocslam run` as a library call: one pass over a sequence writing every output.

    result = run_slam(source, out_dir, RunOptions(...))

Writes into `out_dir`:

* `run.mcap`: everything `eurocslam convert` writes (same single pass, the images the pipeline
  already decoded) plus the SLAM topics of `io/slam_topics.py`;
* `trajectory_online.tum` / `trajectory_online.csv`: the causal per-frame estimate;
* `trajectory_final.tum` / `trajectory_final.csv`: after the final batch optimisation;
* `map.ply`: the batch-optimised landmarks (with their segment);
* `config.yaml`: the resolved configuration; `summary.json` / `summary.txt`: the run summary.

Trajectories carry segment ids (`# segment N` lines) when the estimator was reset.
Whatever happens, the MCAP is left readable (`run.mcap.partial` if the run stopped early).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.config import RunConfig
from eurocslam.dataset.types import SequenceSource
from eurocslam.errors import EurocSlamError, OutputError
from eurocslam.io.ply import write_ply
from eurocslam.io.sink import Sink
from eurocslam.io.trajectory_io import Trajectory, write_euroc_csv, write_tum
from eurocslam.pipeline import FrameOutput, RunResult, SlamPipeline
from eurocslam.progress import bar


@dataclass(frozen=True)
class RunOptions:
    use_imu: bool = True
    start: float | None = None  # seconds from the sequence start, or absolute ns (>= 1e15)
    end: float | None = None
    mcap: bool = True
    compression: str = "zstd"
    images: str = "raw"
    progress: bool | None = None  # None: when stderr is a terminal


def _trajectory(t: np.ndarray, T: np.ndarray, seg: np.ndarray, name: str) -> Trajectory:
    segment = seg if len(seg) and np.unique(seg).size > 1 else None
    return Trajectory.from_poses(t, T.reshape(-1, 4, 4), segment, name)


def write_outputs(out_dir: Path, result: RunResult, cfg: RunConfig) -> None:
    online = _trajectory(result.online_t_ns, result.online_T, result.online_segment, "online")
    final = _trajectory(result.final_t_ns, result.final_T, result.final_segment, "final")
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


OUTPUT_NAMES = (
    "run.mcap",
    "run.mcap.partial",
    "trajectory_online.tum",
    "trajectory_online.csv",
    "trajectory_final.tum",
    "trajectory_final.csv",
    "map.ply",
    "config.yaml",
    "summary.json",
    "summary.txt",
)


def _remove_previous_outputs(out_dir: Path) -> None:
    """A previous run's outputs in OUT are removed first, so no stale file (e.g. a run.mcap
    left by an earlier run when this one has --no-mcap) is mistaken for this run's."""
    old = [out_dir / n for n in OUTPUT_NAMES if (out_dir / n).is_file()]
    if not old:
        return
    print(
        f"note: replacing the outputs of a previous run in {out_dir} "
        f"({', '.join(p.name for p in old)})",
        file=sys.stderr,
    )
    for p in old:
        try:
            p.unlink()
        except OSError as e:
            raise OutputError(f"{p}: cannot replace the previous run's output: {e}") from None


def run_slam(
    source: SequenceSource,
    out_dir: Path | str,
    cfg: RunConfig | None = None,
    options: RunOptions | None = None,
    extra_sinks: Sequence[Sink] = (),
) -> RunResult:
    """`extra_sinks` (e.g. the live view's `io.live.LiveSink`) receive every message that goes
    into run.mcap, in the same order, from the pipeline thread; the caller closes them."""
    from eurocslam.convert import calibration_attachments, resolve_time, sequence_start_ns
    from eurocslam.frontend.config import FrontendConfig
    from eurocslam.io.mcap_writer import McapSink
    from eurocslam.io.sensor_streams import SensorStreams, StreamOptions
    from eurocslam.io.sink import TeeSink, ThreadedSink
    from eurocslam.io.slam_topics import SlamMcapWriter

    cfg = cfg or RunConfig()
    opt = options or RunOptions()
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{out_dir}: cannot create the output folder: {e}") from None
    if len(source.imu) == 0 and opt.use_imu:
        raise EurocSlamError(f"{source.name}: no IMU data; run with --no-imu for visual-only")
    t_ref = sequence_start_ns(source)
    t0, t1 = resolve_time(opt.start, t_ref), resolve_time(opt.end, t_ref)
    if t0 is not None and t1 is not None and t1 < t0:
        raise OutputError(f"--end ({opt.end}) is before --start ({opt.start})")
    ft = np.asarray(source.frame_times)
    n_frames = int(
        np.sum(
            (ft >= (t0 if t0 is not None else ft.min(initial=0)))
            & (ft <= (t1 if t1 is not None else ft.max(initial=0)))
        )
    )
    if n_frames == 0:
        raise OutputError(f"{source.name}: no stereo frames in the selected time range")
    _remove_previous_outputs(out_dir)

    observers = []
    mcap = sink = writer = None
    if opt.mcap:
        alpha = FrontendConfig.from_dict(cfg.frontend).rectify_alpha  # CameraInfo R/P = SLAM's
        streams = SensorStreams(
            source,
            StreamOptions(images=opt.images, t_start_ns=t0, t_end_ns=t1, rectify_alpha=alpha),
        )
        mcap = McapSink(out_dir / "run.mcap", compression=opt.compression)
        sink = ThreadedSink(mcap)
        for name, data in calibration_attachments(source).items():
            mcap.add_attachment(name, data, "text/yaml", streams.t0_ns)
        mcap.add_attachment("config.yaml", cfg.to_yaml().encode(), "text/yaml", streams.t0_ns)
        mcap.add_metadata(
            "eurocslam",
            {
                "source": str(getattr(source, "root", source.name)),
                "mode": "stereo-inertial" if opt.use_imu else "visual-only",
            },
        )
        dest = TeeSink([sink, *extra_sinks]) if extra_sinks else sink
        streams.write_static(dest)
        writer = SlamMcapWriter(dest, streams, source.groundtruth, cfg.output)
        observers.append(writer)

    pipeline = SlamPipeline(source, cfg, use_imu=opt.use_imu, observers=observers)
    pb = bar(total=n_frames, desc=f"run {source.name}", unit="frame", enabled=opt.progress)
    counter = {"n": 0}

    def progress(out: FrameOutput) -> None:
        counter["n"] += 1
        pb.update(1)
        if counter["n"] % 10 == 0 or out.reset_reason:
            fr = out.frontend
            pb.set_postfix(
                state=out.state.value,
                tracked=fr.n_tracked if fr else 0,
                kf=pipeline.est.k + 1 if pipeline.est else 0,
                resets=len(pipeline.summary.resets),
                refresh=False,
            )

    try:
        result = pipeline.run(t0, t1, on_progress=progress)
        pb.close()
        if writer is not None and sink is not None:
            writer.finish(result)
            sink.close()
    except BaseException as e:
        pb.close()
        if mcap is not None and sink is not None:
            try:
                sink.join()
            except BaseException:
                sink.abort()
            try:
                partial = mcap.abort()
                print(
                    f"eurocslam run: stopped early ({type(e).__name__}); what was written so "
                    f"far is in {partial} (a readable MCAP)",
                    file=sys.stderr,
                )
            except Exception as e2:  # pragma: no cover - disk full etc.
                print(f"eurocslam run: could not finish {mcap.partial}: {e2}", file=sys.stderr)
        raise
    write_outputs(out_dir, result, cfg)
    return result
