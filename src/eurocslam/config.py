"""Run configuration: typed frozen dataclasses loaded from `configs/*.yaml`.

Every tunable of `eurocslam run` lives here with its default; `configs/euroc.yaml` lists them all
with comments. Loading is strict: an unknown key, a wrong type or an out-of-range value raises
`ConfigError` naming the file and the dotted key. A field's range stands beside it (`limited`:
without one, a number must be >= 0); one function checks them (`eurocslam.limits`). The
resolved configuration (defaults merged with the file) is written next to the outputs
(`OUT/config.yaml`), so a run can be reproduced.

Every section, the frontend's (`eurocslam.frontend.config.FrontendConfig`) included, goes through
the one loader here, so a config is checked completely before a run touches anything on disk.

`mode` (top level) is `auto`, `stereo-inertial` or `visual-only`; `auto` is resolved once, against
the sequence (`resolve_mode`), before a run starts: every stage then reads the concrete mode.
"""

from __future__ import annotations

import dataclasses
import logging
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from eurocslam.errors import ConfigError
from eurocslam.frontend.config import FrontendConfig
from eurocslam.limits import check_limits, limited

logger = logging.getLogger(__name__)

STEREO_INERTIAL = "stereo-inertial"
VISUAL_ONLY = "visual-only"
MODES = ("auto", STEREO_INERTIAL, VISUAL_ONLY)


@dataclass(frozen=True)
class ImuConfig:
    gravity: float = limited(9.81, gt=0)  # m/s^2, world z up
    # multipliers on the sensor.yaml noise densities (datasheet values are optimistic)
    gyro_noise_scale: float = limited(1.0, gt=0)
    accel_noise_scale: float = limited(1.0, gt=0)
    # multipliers on the sensor.yaml bias random walks (1: the datasheet's, as ORB-SLAM3 uses
    # on EuRoC); a real IMU that disagrees more is caught by the final batch's IMU check
    # (benchmarks/RESULTS.md, "The IMU's bias random walk")
    gyro_bias_walk_scale: float = limited(1.0, gt=0)
    accel_bias_walk_scale: float = limited(1.0, gt=0)
    integration_sigma: float = limited(1e-4, gt=0)  # continuous-time position integration noise
    # longer gaps between IMU samples count as an IMU dropout
    max_gap_s: float = limited(0.05, gt=0)
    # noise figures that replace the calibration's (None: the calibration's; a bag calibrated
    # by its CameraInfo and /tf_static carries none, `dataset/imu_noise.py`)
    gyroscope_noise_density: float | None = limited(None, gt=0)  # rad/s/sqrt(Hz)
    gyroscope_random_walk: float | None = limited(None, gt=0)  # rad/s^2/sqrt(Hz)
    accelerometer_noise_density: float | None = limited(None, gt=0)  # m/s^2/sqrt(Hz)
    accelerometer_random_walk: float | None = limited(None, gt=0)  # m/s^3/sqrt(Hz)


@dataclass(frozen=True)
class InitConfig:
    mode: str = "auto"  # auto | static | dynamic
    # IMU window centred on the first frame to test for stillness
    static_window_s: float = limited(0.6, gt=0)
    static_gyro_std_max: float = 0.02  # rad/s: above this the platform is moving
    static_accel_std_max: float = 0.15  # m/s^2
    static_accel_norm_tol: float = 0.4  # | |a| - g | below this while still
    # stereo VO span aligned with the IMU for a moving start
    dynamic_window_s: float = limited(1.5, gt=0)
    # visual-only: the world's first attitude (nothing measures gravity): camera_level (cam0
    # level, looking along world x: z up if the camera is held level) or body (the first body
    # frame)
    visual_world: str = "camera_level"
    dynamic_min_keyframes: int = 5
    # priors at initialisation (stddev)
    # rad: the first yaw is the gauge (nothing observes it)
    prior_yaw_sigma: float = limited(0.01, gt=0)
    # rad: roll/pitch from the still IMU's mean
    prior_tilt_sigma_static: float = limited(0.01, gt=0)
    # rad: roll/pitch from the VO/IMU alignment
    prior_tilt_sigma_dynamic: float = limited(0.01, gt=0)
    prior_pos_sigma: float = limited(0.001, gt=0)  # m
    prior_vel_sigma_static: float = limited(0.01, gt=0)  # m/s
    prior_vel_sigma_dynamic: float = limited(0.1, gt=0)  # m/s
    prior_gyro_bias_sigma: float = limited(0.005, gt=0)  # rad/s
    prior_accel_bias_sigma: float = limited(0.1, gt=0)  # m/s^2


@dataclass(frozen=True)
class BackendConfig:
    smoother: str = "fixed_lag"  # fixed_lag | isam2 (isam2 keeps every state: slower, no marginals)
    lag_s: float = limited(3.0, gt=0)  # fixed-lag smoother horizon
    relinearize_threshold: float = 0.01
    relinearize_skip: int = limited(1, gt=0)
    stereo_sigma_px: float = limited(1.0, gt=0)
    huber_k: float = limited(1.345, gt=0)  # Huber threshold in units of sigma
    # stereo observations with less disparity are left out (1 px: 48 m on EuRoC, 386 m on
    # KITTI; a far point still constrains the rotation through its stereo error in pixels)
    min_disparity_px: float = 1.0
    min_obs_without_imu: int = 10  # a keyframe without an IMU factor needs this many points
    # a landmark re-found after the smoother let it go (map reuse) is anchored at its last
    # smoothed position with this sigma (m; 0: not), so the online estimate returns to the map
    # it revisits instead of drifting away from it (benchmarks/RESULTS.md)
    refound_prior_sigma_m: float = 0.02
    # that anchor as a robust measurement (Huber at `huber_k` sigmas, as the stereo factors): a
    # re-found landmark far from where it was archived (a wrong match, a far point's depth, a
    # landmark mapped before the estimate's tilt settled) pulls with a bounded force, not a
    # quadratic one
    refound_prior_huber: bool = False
    # an anchor only where the archived position and the re-finding stereo point agree within
    # their covariances (the anchor's sigma and the stereo triangulation's), chi-square 3 DoF
    # (11.34: 99 %; 0: always), as a loop must agree with the estimator's
    refound_prior_gate_chi2: float = limited(0.0, ge=0)
    # that anchor's covariance: the anchor's sigma plus the re-finding stereo point's
    # triangulation covariance (what this rig measures at that depth: on a short-focal fisheye a
    # point 3 m away is known to decimetres along its ray, not to the 2 cm sigma alone)
    refound_prior_stereo: bool = False
    # the anchor's covariance adds the archived position's own: the inverse of the information
    # of every stereo observation the smoother took of the landmark (its views' parallax and
    # count, not one pair's depth; the poses' uncertainty is the sigma's part)
    refound_prior_views: bool = False
    # a pose found by place recognition (relocalization prior, loop edge): sigmas (rad, m)
    place_rot_sigma: float = limited(0.01, gt=0)
    place_pos_sigma: float = limited(0.02, gt=0)
    # visual-only: a keyframe with too few mapped landmarks is tied to the last one by the
    # frontend's motion with these sigmas (rad, m)
    vo_bridge_rot_sigma: float = limited(0.02, gt=0)
    vo_bridge_pos_sigma: float = limited(0.05, gt=0)
    max_landmarks_per_keyframe: int = limited(100, gt=0)
    # visual-only: vision alone holds the keyframes
    max_landmarks_per_keyframe_no_imu: int = limited(150, gt=0)
    min_keyframe_interval_s: float = 0.2  # frontend keyframes closer than this are skipped
    # force a keyframe after this long (bounds IMU spans)
    max_keyframe_interval_s: float = limited(0.5, gt=0)
    correct_landmarks: bool = True  # push smoothed landmark positions back to the frontend
    correct_whole_map: bool = True  # move the rest of the frontend map with the keyframe
    final_batch: bool = True  # one full Levenberg-Marquardt over each segment at the end
    # Levenberg-Marquardt iterations of the final batch, and again after the IMU rounds (one
    # iteration each); it starts from the smoother: converges fast
    final_batch_max_iterations: int = 3
    # stereo observations per keyframe the final batch takes, the smoother's included (it runs
    # once: no per-frame cost); at most the smoother's cap: the smoother's alone
    final_max_landmarks_per_keyframe: int = 250
    # final batch: when the IMU factors' chi-square per redundancy exceeds the stereo factors'
    # by more than this ratio, the accelerometer's covariances are scaled by it and the batch
    # goes on (variance-component rounds; 0: never)
    final_imu_reweight_above: float = 2.0


@dataclass(frozen=True)
class HealthConfig:
    # m/s, faster than the platform can move: stereo-inertial, a smoothed velocity above it is
    # a divergence; visual-only, a tracked pose this far (per second) from the last is wrong
    max_speed: float = limited(50.0, gt=0)
    max_gyro_bias: float = limited(0.3, gt=0)  # rad/s
    max_accel_bias: float = limited(1.5, gt=0)  # m/s^2
    max_lost_s: float = limited(2.0, gt=0)  # IMU-only bridging longer than this resets
    max_lost_s_no_imu: float = 0.3  # no IMU and no tracking: reset sooner
    # stereo-inertial: the tracked pose may be this far from the IMU's prediction
    max_prediction_error_m: float = limited(1.0, gt=0)
    # after a loss past the prediction, the tracker's own search (no prior) must find this many
    # inliers (ORB-SLAM's relocalization bar)
    recover_min_inliers: int = 50


@dataclass(frozen=True)
class PlacesConfig:
    """Place recognition (places/): relocalization, loop closure and merging by appearance."""

    enabled: bool = True
    vocabulary: str = ""  # a vocabulary .npz (places.train); "": the one shipped
    candidates: int = limited(5, gt=0)  # best-scored keyframes verified per query
    min_score: float = 0.01  # appearance score below which a keyframe is not a candidate
    # verification: descriptor matches (Hamming, ratio test), PnP-RANSAC, refinement
    max_hamming: int = 60
    ratio: float = limited(0.8, gt=0)
    min_inliers: int = limited(40, gt=0)
    pnp_reprojection_px: float = limited(3.0, gt=0)
    pnp_iterations: int = limited(300, gt=0)
    # a candidate keyframe's own stereo points (where the map has no landmark) take part only
    # when closer than this many baselines (ORB-SLAM's close points): a far point's depth rests
    # on a few pixels of disparity, and a pose fitted to it is off by up to degrees (0: all)
    verify_max_depth_baselines: float = 40.0
    # loop closure: candidates at least this much older than the query (the recent past always
    # looks like the present), confirmed by this many consecutive keyframes whose corrections
    # agree within the tolerances; a correction smaller than the thresholds is left to the
    # projection re-finding of map reuse
    loop_min_age_s: float = 10.0
    loop_consistency: int = limited(2, gt=0)
    loop_agree_m: float = limited(0.05, gt=0)
    loop_agree_deg: float = limited(1.0, gt=0)
    loop_min_correction_m: float = 0.1
    loop_min_correction_deg: float = 1.0
    # the gate (pipeline/places.py `loop_gate`): a correction is applied only when the drift it
    # measures is one the estimator's uncertainty allows, given the match's own (chi-square, 6
    # DoF; 16.81: 99 %), and one the match tells from its own error (the same chi-square against
    # the match's covariance alone must exceed it, `loop_significance`); refused loops are
    # reported. The estimator's pose covariance is sampled
    # at a keyframe every `loop_covariance_every_s` (a marginal covariance costs about a fifth
    # of a smoother update) and at the query when a loop reaches the gate; a candidate between
    # samples takes the next one's (the larger: the stricter gate)
    loop_gate_chi2: float = limited(16.81, gt=0)
    # with an IMU, the significance test (the drift against the match's own error) judges the
    # correction that is applied (yaw and the move of the query's position, 4 DoF, at the
    # probability `loop_gate_chi2` has on 6), not the 6-DoF drift whose tilt the IMU rules out
    loop_significance_4dof: bool = False
    loop_covariance_every_s: float = limited(5.0, gt=0)
    # act on such a loop online: move the estimate onto the old map (the smoother restarts from
    # the moved state, the tracker's map moves with it) and give the final batch the loop edge;
    # off: loops are recognised and reported, and closed by map reuse in the final batch
    correct_loops_online: bool = True
    # relocalization: lost frames query the database; lost this long without a place: reset
    relocalize_max_s: float = limited(10.0, gt=0)
    # a new segment (after a reset) is merged into the frame of an earlier one it recognises
    merge: bool = True


@dataclass(frozen=True)
class OutputConfig:
    landmarks_every_n_keyframes: int = 1  # /slam/landmarks rate
    draw_features: bool = True  # tracked features on the cam0 image (annotations)
    groundtruth_overlay: bool = True  # ground truth aligned at the first pose (position + yaw)
    # the platform drawn on the estimate and the ground truth (/slam/drone, /groundtruth/drone):
    # `firefly` (EuRoC's Asctec Firefly), `none`, or `auto`: the Firefly where the rig is the
    # Firefly's VI-Sensor (EuRoC's camera placement), nothing on other rigs (a car, a handheld)
    drone_model: str = "auto"


@dataclass(frozen=True)
class RunConfig:
    mode: str = "auto"  # auto | stereo-inertial | visual-only (auto: by the sequence's IMU)
    imu: ImuConfig = field(default_factory=ImuConfig)
    init: InitConfig = field(default_factory=InitConfig)
    backend: BackendConfig = field(default_factory=BackendConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    places: PlacesConfig = field(default_factory=PlacesConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)

    @property
    def inertial(self) -> bool:
        """Stereo-inertial (True) or visual-only; the mode must have been resolved."""
        if self.mode not in (STEREO_INERTIAL, VISUAL_ONLY):
            raise ConfigError(f"mode {self.mode!r} not resolved (resolve_mode) before the run")
        return self.mode == STEREO_INERTIAL

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


_CHOICES = {
    "mode": MODES,
    "init.mode": ("auto", "static", "dynamic"),
    "init.visual_world": ("camera_level", "body"),
    "backend.smoother": ("fixed_lag", "isam2"),
    "output.drone_model": ("auto", "firefly", "none"),
    "frontend.rectify_size": ("image", "focal"),
}


def _coerce(value: Any, typ: Any, key: str, origin: str) -> Any:
    args = typing.get_args(typ)
    if type(None) in args:  # an optional value: null, or one of the other type
        if value is None:
            return None
        (typ,) = (a for a in args if a is not type(None))
    if typ is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{origin}: key '{key}' must be true or false, got {value!r}")
        return value
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{origin}: key '{key}' must be an integer, got {value!r}")
        return value
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{origin}: key '{key}' must be a number, got {value!r}")
        return float(value)
    if typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"{origin}: key '{key}' must be a string, got {value!r}")
        if key in _CHOICES and value not in _CHOICES[key]:
            raise ConfigError(
                f"{origin}: key '{key}' must be one of {', '.join(_CHOICES[key])}, got {value!r}"
            )
        return value
    raise ConfigError(f"{origin}: key '{key}' has an unsupported type")  # pragma: no cover


def _section(cls: type, data: Any, prefix: str, origin: str) -> Any:
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{origin}: key '{prefix}' must be a mapping")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    for k in data:
        if k not in names:
            raise ConfigError(f"{origin}: unknown key '{prefix}.{k}' (known: {', '.join(names)})")
    kw = {k: _coerce(v, hints[k], f"{prefix}.{k}", origin) for k, v in data.items()}
    obj = cls(**kw)
    check_limits(obj, prefix, origin)
    return obj


def config_from_dict(data: Any, origin: str = "<config>") -> RunConfig:
    """Build a `RunConfig` from a mapping (missing keys take their defaults)."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{origin}: top level must be a mapping of sections")
    sections = {
        "imu": ImuConfig,
        "init": InitConfig,
        "backend": BackendConfig,
        "health": HealthConfig,
        "output": OutputConfig,
        "places": PlacesConfig,
        "frontend": FrontendConfig,
    }
    known = ["mode", *sections]
    for k in data:
        if k not in known:
            raise ConfigError(f"{origin}: unknown section '{k}' (known: {', '.join(known)})")
    kw: dict[str, Any] = {k: _section(cls, data.get(k), k, origin) for k, cls in sections.items()}
    if "mode" in data:
        kw["mode"] = _coerce(data["mode"], str, "mode", origin)
    return RunConfig(**kw)


def resolve_mode(cfg: RunConfig, has_imu: bool, where: str = "the sequence") -> RunConfig:
    """The config with a concrete mode: `auto` is stereo-inertial where the sequence has an
    IMU, visual-only (with a note) where it has none. Stereo-inertial asked for without IMU data
    is an error naming `where`."""
    if cfg.mode == "auto":
        mode = STEREO_INERTIAL if has_imu else VISUAL_ONLY
        if not has_imu:
            logger.info("note: %s has no IMU data: running visual-only", where)
        cfg = dataclasses.replace(cfg, mode=mode)
    if cfg.mode == STEREO_INERTIAL and not has_imu:
        raise ConfigError(
            f"{where}: no IMU data for mode stereo-inertial (mode: auto runs it visual-only)"
        )
    if cfg.mode == VISUAL_ONLY and cfg.frontend.track_every > 1:
        raise ConfigError(
            f"key 'frontend.track_every' value {cfg.frontend.track_every}: the frames between "
            "tracked ones need the IMU, and this run is visual-only (use 1)"
        )
    return cfg


def load_config(path: Path | str | None = None) -> RunConfig:
    """Load a YAML config; `None` loads the shipped `configs/euroc.yaml` defaults."""
    if path is None:
        return config_from_dict(yaml.safe_load(default_config_text()), "<built-in euroc.yaml>")
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{p}: cannot read: {e}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{p}: not valid YAML: {e}") from None
    return config_from_dict(data, str(p))


def default_config_text() -> str:
    """The commented `configs/euroc.yaml` of the source tree, or "" when installed without it
    (the dataclass defaults are the same values; a test keeps them in step)."""
    repo = Path(__file__).resolve().parents[2] / "configs" / "euroc.yaml"
    return repo.read_text() if repo.exists() else ""
