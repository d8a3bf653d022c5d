"""The run summary: counts, states, resets, the IMU check, timings per stage, speed, memory; as
text lines (`summary.txt`, the console) and as JSON (`summary.json`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from eurocslam.backend.types import ImuCheck
from eurocslam.frontend.stream import ExtractionCost
from eurocslam.frontend.types import TrackPath
from eurocslam.memory import peak_rss_mb, usable_cores
from eurocslam.pipeline.records import FrameOutput, PlaceEvent, PlaceKind


def _finite(x: float) -> float | None:
    """Rounded for JSON; NaN (not measured) as null."""
    return None if math.isnan(x) else round(x, 3)


# summary.json `places`: the events by kind
_PLACE_LISTS = (
    ("loops", PlaceKind.LOOP),
    ("relocalizations", PlaceKind.RELOCALIZATION),
    ("merges", PlaceKind.MERGE),
)


@dataclass
class RunSummary:
    sequence: str = ""
    mode: str = "stereo-inertial"
    frames: int = 0
    frames_with_pose: int = 0
    keyframes: int = 0
    landmarks: int = 0
    landmarks_reused: int = 0  # archived landmarks re-found (map reuse: loop closures)
    segments: int = 0
    resets: list[tuple[int, str]] = field(default_factory=list)
    init_modes: list[str] = field(default_factory=list)
    imu_checks: list[ImuCheck] = field(default_factory=list)  # final batch, per segment
    state_frames: dict[str, int] = field(default_factory=dict)
    places: list[PlaceEvent] = field(default_factory=list)  # loops, relocalizations, merges
    place_db: dict[str, float] = field(default_factory=dict)  # the place database's size, cost
    # `run --map`: path, keyframes, landmarks, load_s, localized_after_s (None: not localized)
    prior_map: dict[str, object] = field(default_factory=dict)
    # how each frame's pose was found: projection | projection_wide | descriptor | lost (the
    # tracker's), imu_between / vo_between (a frame left out by frontend.track_every)
    track_paths: dict[str, int] = field(default_factory=dict)
    timings_ms: dict[str, list[float]] = field(default_factory=dict)
    wall_s: float = 0.0
    cpu_s: float = 0.0  # CPU time of the process (every thread) and its workers' since set up
    peak_rss_mb: float = math.nan  # this process's peak resident memory
    worker_peak_rss_mb: list[float] = field(default_factory=list)  # extraction workers'
    # CPU time by thread: the one running the pipeline (tracking, backend, places, final batch),
    # the extraction workers (processes) and the frame reader; NaN / empty: not measured
    tracking_cpu_s: float = math.nan
    worker_cpu_s: list[float] = field(default_factory=list)
    reader_cpu_s: float = math.nan
    cores: int = 0  # CPU cores the run could use
    duration_s: float = 0.0
    _clock0: tuple[float, float, float] = (0.0, 0.0, 0.0)  # wall, CPU, thread CPU at the start

    def add_time(self, stage: str, ms: float) -> None:
        self.timings_ms.setdefault(stage, []).append(ms)

    def count_path(self, path: TrackPath) -> None:
        """One more frame whose pose was found by `path` (`track_paths`)."""
        self.track_paths[path.value] = self.track_paths.get(path.value, 0) + 1

    def start_clock(self) -> None:
        """The run starts: wall, process and this thread's CPU time from now."""
        self._clock0 = (time.perf_counter(), time.process_time(), time.thread_time())

    def stop_clock(self, cost: ExtractionCost, span_s: float | None) -> None:
        """The run ends (its final batch included): wall and CPU time, the extraction workers'
        and the reader's, memory; `span_s`: the data's duration (None: no frame)."""
        wall0, cpu0, thread0 = self._clock0
        self.wall_s = time.perf_counter() - wall0
        self.cpu_s = time.process_time() - cpu0  # the workers' is added with their cost
        self.tracking_cpu_s = time.thread_time() - thread0
        self.cores = usable_cores()
        self.peak_rss_mb = peak_rss_mb()
        self.add_extraction_cost(cost)
        if span_s is not None:
            self.duration_s = span_s

    def count_frame(self, timings_ms: dict[str, float]) -> None:
        """One more frame, with its extraction stage's times."""
        self.frames += 1
        for k in ("decode", "rectify", "orb", "stereo_matching"):
            if k in timings_ms:
                self.add_time(k, timings_ms[k])

    def count_output(self, out: FrameOutput) -> None:
        """What the frame's output says: its state, whether it has a pose, how tracking found
        it and what that cost, the landmarks map reuse found again."""
        fr = out.frontend
        if fr is not None:
            self.landmarks_reused += fr.n_reused
            if fr.track_path is not None:
                self.count_path(fr.track_path)
            if "track_total" in fr.timings_ms:
                self.add_time("tracking", fr.timings_ms["track_total"])
        self.state_frames[out.state.value] = self.state_frames.get(out.state.value, 0) + 1
        if out.T_world_body is not None:
            self.frames_with_pose += 1

    def add_extraction_cost(self, cost: ExtractionCost) -> None:
        """The extraction workers' memory and CPU time, and the frame reader's (none inline)."""
        self.worker_peak_rss_mb = list(cost.worker_peak_rss_mb)
        self.worker_cpu_s = list(cost.worker_cpu_s)
        self.cpu_s += sum(c for c in cost.worker_cpu_s if not math.isnan(c))
        self.reader_cpu_s = cost.reader_cpu_s if cost.worker_cpu_s else math.nan

    @property
    def coverage(self) -> float:
        return self.frames_with_pose / self.frames if self.frames else 0.0

    @property
    def realtime_factor(self) -> float:
        return self.duration_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def other_cpu_s(self) -> float:
        """CPU time of the threads not measured one by one (the MCAP writer, ...); NaN when
        the tracking thread's was not measured."""
        reader = 0.0 if math.isnan(self.reader_cpu_s) else self.reader_cpu_s  # NaN: no reader
        measured = self.tracking_cpu_s + sum(self.worker_cpu_s) + reader
        return math.nan if math.isnan(measured) else max(0.0, self.cpu_s - measured)

    def realtime_bounds(self) -> tuple[float, float]:
        """The real-time factors this CPU time allows: all cores busy all the time, and the
        tracking thread busy all the time (it cannot use a second core)."""
        d = self.duration_s

        def bound(cpu_s: float) -> float:
            return d / cpu_s if cpu_s > 0 else math.nan

        return bound(self.cpu_s / max(self.cores, 1)), bound(self.tracking_cpu_s)

    def _cpu_lines(self) -> list[str]:
        if math.isnan(self.tracking_cpu_s):
            return []
        parts = [f"tracking thread {self.tracking_cpu_s:.1f}"]
        if self.worker_cpu_s:
            parts.append("extraction workers " + " + ".join(f"{c:.1f}" for c in self.worker_cpu_s))
        if not math.isnan(self.reader_cpu_s):
            parts.append(f"frame reader {self.reader_cpu_s:.1f}")
        parts.append(f"other threads {self.other_cpu_s:.1f}")
        by_cores, by_thread = self.realtime_bounds()
        return [
            "CPU seconds by thread: " + ", ".join(parts),
            f"at this CPU time the real-time factor is at most {by_cores:.2f} on {self.cores} "
            f"core(s) and {by_thread:.2f} for the tracking thread",
        ]

    def _place_lines(self) -> list[str]:
        if not self.place_db:
            return []
        loops = [e for e in self.places if e.kind == PlaceKind.LOOP]
        moved = [e for e in loops if e.correction_m > 0 or e.correction_deg > 0]
        refused = [e for e in loops if e.refused]
        n_reloc = sum(1 for e in self.places if e.kind == PlaceKind.RELOCALIZATION)
        n_merge = sum(1 for e in self.places if e.kind == PlaceKind.MERGE)
        d = self.place_db
        gate = f", {len(refused)} refused by the gate" if refused else ""
        return [
            f"places: {len(loops)} loop(s) recognised ({len(moved)} corrected{gate}), {n_reloc} "
            f"relocalization(s), {n_merge} merge(s); database {d['keyframes']:.0f} keyframes, "
            f"{d['memory_mb']:.1f} MB ({d['memory_kb_per_keyframe']:.1f} kB each), query "
            f"{d['query_ms_mean']:.2f} ms, verification {d['verify_ms_mean']:.1f} ms (mean)"
        ]

    def _map_lines(self) -> list[str]:
        m = self.prior_map
        if not m:
            return []
        after = m.get("localized_after_s")
        return [
            f"map: {m['path']} ({m['keyframes']} keyframes, {m['landmarks']} landmarks, loaded "
            f"in {m['load_s']:.2f} s); "
            + (
                f"localized in it {after:.2f} s after the first frame"
                if isinstance(after, float)
                else "never recognised: this run is in its own frame"
            )
        ]

    def timing_table(self) -> list[tuple[str, int, float, float, float]]:
        """(stage, calls, median ms, total s, share of wall time)."""
        rows = []
        for stage, v in self.timings_ms.items():
            a = np.asarray(v)
            rows.append(
                (
                    stage,
                    a.size,
                    float(np.median(a)),
                    float(a.sum()) / 1e3,
                    float(a.sum()) / 1e3 / self.wall_s if self.wall_s else 0.0,
                )
            )
        return rows

    def to_dict(self) -> dict[str, object]:
        return {
            "sequence": self.sequence,
            "mode": self.mode,
            "frames": self.frames,
            "frames_with_pose": self.frames_with_pose,
            "coverage": round(self.coverage, 4),
            "keyframes": self.keyframes,
            "landmarks": self.landmarks,
            "landmarks_reused": self.landmarks_reused,
            "segments": self.segments,
            "resets": [{"t_ns": t, "reason": r} for t, r in self.resets],
            "init_modes": self.init_modes,
            "imu_check": [
                {
                    "ratio": _finite(c.ratio),
                    "accel_scale": round(c.accel_scale, 3),
                    "ratio_after": _finite(c.ratio_after),
                }
                for c in self.imu_checks
            ],
            "state_frames": self.state_frames,
            "places": {
                **{
                    name: [e.to_dict() for e in self.places if e.kind == kind]
                    for name, kind in _PLACE_LISTS
                },
                "database": {k: round(v, 3) for k, v in self.place_db.items()},
            },
            "prior_map": self.prior_map,
            "track_paths": self.track_paths,
            "duration_s": round(self.duration_s, 3),
            "wall_s": round(self.wall_s, 3),
            "cpu_s": round(self.cpu_s, 3),
            "peak_rss_mb": _finite(self.peak_rss_mb),
            "worker_peak_rss_mb": [_finite(m) for m in self.worker_peak_rss_mb],
            "cpu_by_thread": {
                "tracking": _finite(self.tracking_cpu_s),
                "extraction_workers": [_finite(c) for c in self.worker_cpu_s],
                "reader": _finite(self.reader_cpu_s),
                "other": _finite(self.other_cpu_s),
            },
            "cores": self.cores,
            "realtime_bounds": dict(
                zip(("cores", "tracking_thread"), map(_finite, self.realtime_bounds()), strict=True)
            ),
            "realtime_factor": round(self.realtime_factor, 3),
            "timings": {
                s: {
                    "calls": n,
                    "median_ms": round(m, 3),
                    "total_s": round(t, 3),
                    "share": round(sh, 4),
                }
                for s, n, m, t, sh in self.timing_table()
            },
        }

    def lines(self) -> list[str]:
        out = [
            f"{self.sequence}: {self.mode}, {self.frames} frames, pose for "
            f"{self.frames_with_pose} ({100 * self.coverage:.1f} %), {self.keyframes} keyframes, "
            f"{self.landmarks} landmarks ({self.landmarks_reused} re-found), "
            f"{self.segments} segment(s), {len(self.resets)} reset(s)",
            f"init: {', '.join(self.init_modes) or 'none'}; frames per state: "
            + ", ".join(f"{k} {v}" for k, v in sorted(self.state_frames.items())),
            "tracked by: "
            + (
                ", ".join(
                    f"{k} {self.track_paths[k]}"
                    for k in (p.value for p in TrackPath)
                    if k in self.track_paths
                )
                or "-"
            ),
            *self._place_lines(),
            *self._map_lines(),
            f"{self.duration_s:.1f} s of data in {self.wall_s:.1f} s wall "
            f"(real-time factor {self.realtime_factor:.2f}), {self.cpu_s:.1f} s CPU",
            f"peak memory {self.peak_rss_mb:.0f} MB"
            + (
                f" + {len(self.worker_peak_rss_mb)} extraction workers "
                + " + ".join(f"{m:.0f}" for m in self.worker_peak_rss_mb)
                + " MB"
                if self.worker_peak_rss_mb
                else ""
            ),
            *self._cpu_lines(),
        ]
        for c in self.imu_checks:
            if math.isnan(c.ratio):
                out.append("final batch: too few IMU or stereo factors to check the IMU")
                continue
            out.append(
                f"final batch: IMU residuals {c.ratio:.2f}x the stereo residuals (chi-square per "
                "redundancy)"
                + (
                    f"; accelerometer covariances scaled by {c.accel_scale:.1f}: "
                    f"{c.ratio_after:.2f}x"
                    if c.accel_scale != 1.0
                    else ""
                )
            )
        for t, r in self.resets:
            out.append(f"  reset at t={t} ns: {r}")
        out.append(f"  {'stage':<18}{'calls':>7}{'median ms':>11}{'total s':>9}{'share':>8}")
        for s, n, m, tot, sh in self.timing_table():
            out.append(f"  {s:<18}{n:>7}{m:>11.2f}{tot:>9.2f}{100 * sh:>7.1f}%")
        return out
