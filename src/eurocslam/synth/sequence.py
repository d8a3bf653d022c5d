"""Synthetic sequence assembly: spec -> motion + world + IMU -> rendered frames -> ASL folder."""

from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from eurocslam.dataset.bag.imu_union import unite_imu
from eurocslam.dataset.calib import StereoRig, calib_folder, default_rig, load_rig
from eurocslam.dataset.calib_sources import tumvi_kalibr_texts, tumvi_rig
from eurocslam.dataset.split_imu import SplitImu, write_split_imu
from eurocslam.errors import CalibrationError, DatasetError
from eurocslam.geometry import F64, inv_T, make_T, rot_to_quat_wxyz
from eurocslam.memory import usable_cores
from eurocslam.synth import writer
from eurocslam.synth.imu import (
    ImuStream,
    read_real_imu,
    real_imu_stream,
    simulate_accelerometer,
    simulate_imu,
)
from eurocslam.synth.render import CameraModel, camera_model, cast_and_shade
from eurocslam.synth.shared_world import SharedWorld, build_shared_world, check_flight_inside
from eurocslam.synth.spec import DEFAULT_DURATION_S, SynthSpec
from eurocslam.synth.trajectory import (
    BUILTIN_T0_NS,
    Motion,
    builtin_motion,
    motion_from_groundtruth,
    read_groundtruth_file,
    reexpress,
)
from eurocslam.synth.world import World, build_world
from eurocslam.timebase import NS_PER_S, ns_to_s, s_to_ns

# bump whenever the same spec would give different files (caches compare it)
GENERATOR_REVISION = 5
# sensor model constants (documented in docs/synthetic.md)
READ_NOISE_DN = 1.5  # read noise sigma [DN]
SHOT_NOISE_GAIN = 0.05  # shot-noise variance per DN of signal
EXPOSURE_SPREAD = 0.15  # log-gain amplitude of the slow exposure changes
BLUR_EXPOSURE_S = 0.008  # exposure window for motion blur
BLUR_SUBFRAMES = 4  # renders besides the one at the frame time


def scene_rig(spec: SynthSpec) -> StereoRig:
    """The rig a spec renders: EuRoC's (built in, or `calib`'s), TUM-VI's fisheye or the
    RealSense-like pair."""
    from eurocslam.synth.rigs import realsense_rig

    if spec.rig in ("tumvi", "realsense"):
        if spec.calib is not None:
            raise DatasetError(f"--calib with --rig {spec.rig}: the rig is built in")
        return tumvi_rig() if spec.rig == "tumvi" else realsense_rig()
    if spec.rig != "euroc":
        raise DatasetError(f"rig '{spec.rig}' unknown (known: euroc, tumvi, realsense)")
    return load_rig(Path(spec.calib)) if spec.calib is not None else default_rig()


@dataclass
class Scene:
    """Everything needed to render any frame of a spec: motion, world, camera models, clock, IMU.
    Forked rendering workers share it; spawned ones rebuild it from the spec."""

    spec: SynthSpec
    rig: StereoRig
    motion: Motion
    world: World
    models: tuple[CameraModel, CameraModel]
    cam_t_ns: np.ndarray
    imu: ImuStream
    notes: list[str] = field(default_factory=list)
    shared: SharedWorld | None = None  # what a `world_from` world was built from
    split: SplitImu | None = None  # accelerometer and gyroscope apart (`spec.accel_rate_hz`)

    # ---- construction ---------------------------------------------------------------------
    @classmethod
    def build(cls, spec: SynthSpec) -> Scene:
        rig = _rig(spec)
        assert rig.imu is not None
        imu_calib = rig.imu
        cam_rate, imu_rate = rig.cam0.rate_hz, imu_calib.rate_hz
        ratio = imu_rate / cam_rate
        # the cameras share the IMU's stamps when its rate is a whole multiple of theirs (EuRoC),
        # else they run on their own clock (a RealSense: 30 Hz images, a 200/400 Hz IMU)
        shared_clock = abs(ratio - round(ratio)) <= 1e-6 and round(ratio) >= 1
        if not shared_clock and spec.imu is not None:
            raise DatasetError(
                f"--imu: real IMU rows need a camera rate ({cam_rate:g} Hz) that the IMU rate "
                f"({imu_rate:g} Hz) is a whole multiple of"
            )
        ratio_i = round(ratio)
        if spec.world_from is not None:
            if spec.trajectory is None:
                raise DatasetError(
                    "--world-from needs --trajectory (the flight to render in the shared world)"
                )
            if spec.imu is not None:
                raise DatasetError(
                    "--world-from with --imu: a real-IMU replica turns its world onto that IMU's "
                    "gravity, so sessions would not share a frame; use simulated IMUs"
                )
        if spec.trajectory is None:
            if spec.imu is not None:
                raise DatasetError("--imu needs --trajectory (the real motion the IMU measured)")
            dur = DEFAULT_DURATION_S if spec.duration_s is None else float(spec.duration_s)
            motion = builtin_motion(
                dur, spec.seed, max_speed=spec.max_speed, max_yaw_rate=spec.max_yaw_rate
            )
            floor_z: float | None = 0.0
        else:
            gt_euroc = gt = read_groundtruth_file(Path(spec.trajectory))
            if spec.rig != "euroc":
                if spec.imu is not None:
                    raise DatasetError(
                        f"--imu with --rig {spec.rig}: real IMU rows belong to EuRoC's rig"
                    )
                # the rig's cam0 where EuRoC's cam0 flies (the world stays EuRoC's)
                gt = reexpress(gt, default_rig().cam0.T_body_cam @ inv_T(rig.cam0.T_body_cam))
            end = spec.end_s
            if spec.duration_s is not None:
                start = spec.start_s or 0.0
                end = start + spec.duration_s if end is None else min(end, start + spec.duration_s)
            real_rows = None
            if spec.imu is not None:
                # the motion the real IMU measured (high frequency) on the ground truth (low)
                span = 2 * 10**9  # read_real_imu needs rows in range; the fit takes what it needs
                real_rows = read_real_imu(Path(spec.imu), gt.t_ns[0] - span, gt.t_ns[-1] + span)
            crop = {"start_s": spec.start_s, "end_s": end, "knot_dt": spec.knot_dt_s}
            motion = motion_from_groundtruth(gt, **crop, imu=real_rows)  # type: ignore[arg-type]
            # the world is built around EuRoC's body path, so rigs share it
            world_motion = (
                motion if gt is gt_euroc else motion_from_groundtruth(gt_euroc, **crop)  # type: ignore[arg-type]
            )
            floor_z = None
        t_lo = motion.t0_ns + s_to_ns(motion.t_start_s)
        t_hi = motion.t0_ns + int(np.floor(motion.t_end_s * NS_PER_S))
        if spec.imu is not None:
            t_imu, g, a = read_real_imu(Path(spec.imu), t_lo, t_hi)
            imu = real_imu_stream(t_imu, g, a, motion.bias_source)
        else:
            period = round(NS_PER_S / imu_rate)
            n = (t_hi - t_lo) // period + 1
            t_imu = t_lo + period * np.arange(n, dtype=np.int64)
            imu = simulate_imu(
                motion.spline,
                motion.t0_ns,
                t_imu,
                imu_calib,
                spec.seed,
                noise=spec.imu_noise,
                bias=spec.imu_bias,
            )
        split = None
        if spec.accel_rate_hz is not None:
            t_acc = t_lo + np.round(
                np.arange(int((t_hi - t_lo) * spec.accel_rate_hz // NS_PER_S) + 1)
                * NS_PER_S  # exact either way: whole nanoseconds below 2**53
                / spec.accel_rate_hz
            ).astype(np.int64)
            acc = simulate_accelerometer(
                motion.spline, motion.t0_ns, t_acc, imu, imu_calib, spec.accel_rate_hz,
                spec.seed, noise=spec.imu_noise,
            )  # fmt: skip
            split = SplitImu(t_acc, acc, imu.t_ns.copy(), imu.gyro.copy())
            united = unite_imu(t_acc, acc, imu.t_ns, imu.gyro)
            k = slice(united.dropped_before, imu.t_ns.size - united.dropped_after)
            imu = ImuStream(united.imu.t_ns, united.imu.gyro, united.imu.accel, imu.bg[k],
                            imu.ba[k])  # fmt: skip
        if shared_clock:
            cam_t = imu.t_ns[::ratio_i].copy()
        else:
            cam_period = NS_PER_S / cam_rate
            n_cam = int((int(imu.t_ns[-1]) - t_lo) // cam_period) + 1
            cam_t = t_lo + np.round(np.arange(n_cam) * cam_period).astype(np.int64)
        if cam_t.size < 2:
            raise DatasetError("the sequence is too short: fewer than 2 camera frames")
        models = (camera_model(rig.cam0), camera_model(rig.cam1))
        if spec.world_from is not None:
            world, shared = build_shared_world(spec.world_from, spec.seed, marker=spec.marker)
            st = motion.spline.evaluate(ns_to_s(cam_t - motion.t0_ns))
            centres = np.vstack(
                [st.p + st.R @ cam.T_body_cam[:3, 3] for cam in (rig.cam0, rig.cam1)]
            )
            t_rel = np.tile(ns_to_s(cam_t - gt.t_ns[0]), 2)
            check_flight_inside(world, shared, centres, t_rel, str(spec.trajectory))
            return cls(spec, rig, motion, world, models, cam_t, imu, shared=shared, split=split)
        path = motion.spline.positions(ns_to_s(cam_t - motion.t0_ns))
        if spec.trajectory is not None:
            # the world encloses the whole recorded flight, so every crop of a sequence flies
            # through the same room
            path = world_motion.spline.positions(ns_to_s(cam_t - world_motion.t0_ns))
            step = max(1, len(gt_euroc.p) // 4000)
            p_all = gt_euroc.p[::step]
            if motion.world_R is not None:
                p_all = p_all @ motion.world_R.T
            path = np.vstack([path, p_all])
        world = build_world(path, spec.seed, floor_z=floor_z, marker=spec.marker)
        return cls(spec, rig, motion, world, models, cam_t, imu, split=split)

    # ---- rendering ------------------------------------------------------------------------
    def t_s(self, t_ns: int | np.ndarray) -> F64:
        return ns_to_s((np.asarray(t_ns, dtype=np.int64) - self.motion.t0_ns).astype(np.float64))

    def T_world_body(self, t_s: float) -> F64:
        st = self.motion.spline.evaluate(np.array([t_s]))
        return make_T(st.R[0], st.p[0])

    def gain(self, t_s: float) -> float:
        """Slow, smooth exposure changes (deterministic per seed)."""
        if not self.spec.exposure:
            return 1.0
        rng = np.random.default_rng([self.spec.seed, 0xE4])
        f = rng.uniform(0.03, 0.2, 3) * 2 * np.pi
        ph = rng.uniform(0, 2 * np.pi, 3)
        return float(np.exp(EXPOSURE_SPREAD * np.mean(np.sin(f * t_s + ph)) * 1.5))

    def radiance(self, k: int, cam: int, want_depth: bool = False) -> tuple[np.ndarray, Any]:
        """Scene radiance of frame k in camera `cam` (0/1), plus the render output for depth."""
        t = float(self.t_s(self.cam_t_ns[k]))
        T_body_cam = self.rig.cam0.T_body_cam if cam == 0 else self.rig.cam1.T_body_cam
        model = self.models[cam]
        out = cast_and_shade(
            self.world, model, self.T_world_body(t) @ T_body_cam, want_depth=want_depth
        )
        rad = out.radiance
        if self.spec.motion_blur:
            acc = rad.astype(np.float64)
            offs = (np.arange(BLUR_SUBFRAMES) + 0.5) / BLUR_SUBFRAMES - 0.5
            for off in offs[offs != 0.0]:
                o2 = cast_and_shade(
                    self.world, model, self.T_world_body(t + off * BLUR_EXPOSURE_S) @ T_body_cam
                )
                acc += o2.radiance
            rad = (acc / (1 + np.count_nonzero(offs != 0.0))).astype(np.float32)
        return rad, out

    def image(self, k: int, cam: int, want_depth: bool = False) -> tuple[np.ndarray, Any]:
        """Frame k of camera `cam` as 8-bit mono, with the sensor effects of the spec."""
        rad, out = self.radiance(k, cam, want_depth)
        if self.spec.in_blackout(self.t_s(self.cam_t_ns[k])):
            return np.zeros(rad.shape, np.uint8), out
        t = float(self.t_s(self.cam_t_ns[k]))
        scale = self.gain(t)
        if self.spec.vignetting:
            rad = rad * (self.models[cam].vignette * np.float32(scale))
        elif scale != 1.0:
            rad = rad * np.float32(scale)
        if self.spec.image_noise:
            rng = np.random.default_rng([self.spec.seed, int(self.cam_t_ns[k]) % (1 << 62), cam])
            sigma = np.sqrt(np.float32(READ_NOISE_DN**2) + np.float32(SHOT_NOISE_GAIN) * rad)
            rad = rad + sigma * rng.standard_normal(rad.shape, dtype=np.float32)
        img = np.clip(rad + np.float32(0.5), 0, 255).astype(np.uint8)
        return img, out


def _rig(spec: SynthSpec) -> StereoRig:
    """`scene_rig`, at `imu_rate_hz` when given; it must have an IMU."""
    from dataclasses import replace

    from eurocslam.dataset.calib_yaml import imu_yaml_text

    rig = scene_rig(spec)
    if rig.imu is None:
        raise CalibrationError(
            f"{calib_folder(Path(str(spec.calib)))}/imu0/sensor.yaml: file not found "
            "(a synthetic sequence has an IMU: the calibration needs one)"
        )
    for name, rate in (("imu", spec.imu_rate_hz), ("accel", spec.accel_rate_hz)):
        if rate is not None and not 1.0 <= rate <= 10000.0:
            raise DatasetError(f"--{name}-rate {rate:g}: expected 1 to 10000 Hz")
    if spec.imu_rate_hz is not None:
        imu = replace(rig.imu, rate_hz=float(spec.imu_rate_hz))
        texts = dict(rig.yaml_texts)
        texts["imu0"] = imu_yaml_text(imu, f"{rig.imu.rate_hz:g} Hz IMU at {imu.rate_hz:g} Hz")
        rig = replace(rig, imu=imu, yaml_texts=tuple(sorted(texts.items())))
    return rig


# ---- parallel frame writing -----------------------------------------------------------------
_SCENE: Scene | None = None
_STAGE: Path | None = None
# PNGs as EuRoC stores them: real EuRoC images (sensor noise) are 362 KB, the size of the raw
# pixels, and decode in 1.7-1.9 ms; deflate level 0 gives the rendered ones the same size and
# decode time (Huffman coding made them 212 KB but 3.3 ms to decode, so replicas over-stated
# the reading cost of the real dataset by 2x)
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 0]


def _render_frames(indices: list[int]) -> tuple[int, float]:
    scene, stage = _SCENE, _STAGE
    assert scene is not None and stage is not None
    t0 = time.process_time()
    for k in indices:
        t_ns = int(scene.cam_t_ns[k])
        for cam, name in ((0, "cam0"), (1, "cam1")):
            img, _ = scene.image(k, cam)
            path = writer.image_path(stage, name, t_ns)
            if not cv2.imwrite(str(path), img, PNG_PARAMS):
                raise OSError(f"{path}: cv2.imwrite failed")
    return len(indices), time.process_time() - t0


def _init_worker(spec: SynthSpec, stage: Path) -> None:
    """Worker of a fresh (spawned) process: rebuild the scene from the spec (deterministic,
    so the frames are the same as a forked worker's)."""
    global _SCENE, _STAGE
    cv2.setNumThreads(1)
    _SCENE, _STAGE = Scene.build(spec), stage


def _pool(scene: Scene, stage: Path, workers: int):  # type: ignore[no-untyped-def]
    """A process pool sharing the scene. Forking shares the world's textures for free (OpenCV
    is set to one thread in the parent first: reconfiguring it in a forked child deadlocks).
    Where fork is unavailable, workers start fresh and rebuild the scene from the spec
    (deterministic, so the frames are the same)."""
    if "fork" in mp.get_all_start_methods():
        return mp.get_context("fork").Pool(workers)
    return mp.get_context("spawn").Pool(
        workers, initializer=_init_worker, initargs=(scene.spec, stage)
    )


def render_all(scene: Scene, stage: Path, workers: int, show_progress: bool | None) -> float:
    """Render and write every frame; returns the CPU seconds spent rendering."""
    from eurocslam.progress import bar

    global _SCENE, _STAGE
    _SCENE, _STAGE = scene, stage
    n = scene.cam_t_ns.size
    chunks = [list(range(i, min(i + 4, n))) for i in range(0, n, 4)]
    cpu = 0.0
    # one OpenCV thread per process; set in the parent *before* forking (changing OpenCV's
    # thread pool inside a forked child deadlocks)
    old_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    pool = _pool(scene, stage, workers) if workers > 1 and n >= 8 else None
    # the bar (and its monitor thread) only after the fork
    pb = bar(total=n, desc="synth: rendering", unit="pair", enabled=show_progress)
    try:
        if pool is None:
            for ch in chunks:
                done, c = _render_frames(ch)
                cpu += c
                pb.update(done)
        else:
            for done, c in pool.imap_unordered(_render_frames, chunks):
                cpu += c
                pb.update(done)
            pool.close()
    except OSError as e:
        from eurocslam.errors import OutputError

        raise OutputError(f"{stage}: cannot write images: {e}") from None
    finally:
        if pool is not None:
            pool.terminate()
            pool.join()
        cv2.setNumThreads(old_threads)
        pb.close()
        _SCENE = _STAGE = None
    return cpu


def synthesize(
    spec: SynthSpec,
    out_dir: Path | str,
    progress: bool | None = None,
    *,
    workers: int | None = None,
    overwrite: bool = False,
) -> Path:
    """Write the sequence described by `spec` as an EuRoC ASL folder at `out_dir`; returns it.

    `progress`: show a progress bar (None: only on a terminal). `workers`: processes that render
    (default: all available cores; the output does not depend on it).
    """
    out = Path(out_dir)
    stage = writer.prepare_folder(
        out, overwrite, spec.rig if spec.rig in writer.FOLDERS else "euroc"
    )
    try:
        scene = Scene.build(spec)
        nw = usable_cores() if workers is None else max(1, int(workers))
        t_render = time.perf_counter()
        cpu = render_all(scene, stage, nw, progress)
        render_wall = time.perf_counter() - t_render
        imu = scene.imu
        st = scene.motion.spline.evaluate(scene.t_s(imu.t_ns))
        keep = ~spec.in_blackout(scene.t_s(imu.t_ns))
        summary = _summary(scene, st, render_wall, cpu, nw)
        if spec.rig == "tumvi":
            writer.write_tumvi_tables(
                stage,
                tumvi_kalibr_texts(),
                scene.cam_t_ns,
                imu.t_ns,
                imu.gyro,
                imu.accel,
                keep,
                st.p,
                rot_to_quat_wxyz(st.R),
                summary,
            )
            return writer.finish(stage, out)
        writer.write_tables(
            stage,
            scene.rig,
            scene.cam_t_ns,
            imu.t_ns,
            imu.gyro,
            imu.accel,
            keep,
            st.p,
            rot_to_quat_wxyz(st.R),
            st.v,
            imu.bg,
            imu.ba,
            summary,
        )
        if scene.split is not None:
            sp = scene.split
            ka = ~spec.in_blackout(scene.t_s(sp.accel_t_ns))
            kg = ~spec.in_blackout(scene.t_s(sp.gyro_t_ns))
            write_split_imu(
                stage / "mav0",
                SplitImu(sp.accel_t_ns[ka], sp.accel[ka], sp.gyro_t_ns[kg], sp.gyro[kg]),
            )
    except BaseException:
        import shutil

        shutil.rmtree(stage, ignore_errors=True)
        raise
    return writer.finish(stage, out)


def _summary(scene: Scene, st: Any, render_wall: float, cpu: float, workers: int) -> dict[str, Any]:
    from eurocslam import __version__

    speed = np.linalg.norm(st.v, axis=1)
    rate = np.linalg.norm(st.w_body, axis=1)
    n = int(scene.cam_t_ns.size)
    shared: dict[str, Any] = {}
    world = scene.world.describe()
    if scene.shared is not None:
        # identify the world, so two sessions can be seen to share it (same id)
        digest = scene.world.digest()
        names = ", ".join(scene.shared.names())
        world += f", id {digest[:12]} (built from {names}; seed {scene.spec.seed})"
        shared = {
            "world_id": digest,
            "world_from": [{"file": f.path.name, "digest": f.digest} for f in scene.shared.flights],
            "world_atlas_bytes": scene.world.atlas_bytes(),
        }
    return {
        "generator": f"eurocslam {__version__} synth",
        "generator_revision": GENERATOR_REVISION,
        "spec": scene.spec.to_json(),
        "motion": scene.motion.description,
        "fit_rms_m": scene.motion.fit_rms_m,
        "fit_rms_deg": scene.motion.fit_rms_deg,
        "world": world,
        **shared,
        "frames": n,
        "imu_samples": int(scene.imu.t_ns.size),
        "imu": "real rows" if scene.imu.real else "simulated",
        **_split_summary(scene),
        "t_first_ns": int(scene.cam_t_ns[0]),
        "t_last_ns": int(scene.cam_t_ns[-1]),
        "duration_s": float(ns_to_s(scene.cam_t_ns[-1] - scene.cam_t_ns[0])),
        "path_length_m": float(np.sum(np.linalg.norm(np.diff(st.p, axis=0), axis=1))),
        "max_speed_mps": float(speed.max()),
        "max_rate_radps": float(rate.max()),
        "render_wall_s": render_wall,
        "render_cpu_ms_per_pair": 1000.0 * cpu / max(n, 1),
        "workers": workers,
        "builtin_t0_ns": BUILTIN_T0_NS if scene.spec.trajectory is None else None,
    }


def _split_summary(scene: Scene) -> dict[str, Any]:
    """synth.json keys of an accelerometer sampled apart (none otherwise: old summaries stay)."""
    sp = scene.split
    if sp is None:
        return {}
    return {
        "imu_split": {
            "accel_hz": scene.spec.accel_rate_hz,
            "gyro_hz": scene.rig.imu.rate_hz if scene.rig.imu is not None else None,
            "accel_samples": int(sp.accel_t_ns.size),
            "gyro_samples": int(sp.gyro_t_ns.size),
        }
    }
