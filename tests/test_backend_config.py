"""Run configuration: strict loading, shipped defaults, round trip."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from eurocslam.config import RunConfig, config_from_dict, load_config
from eurocslam.errors import ConfigError
from eurocslam.frontend.config import FrontendConfig

REPO = Path(__file__).resolve().parents[1]


def test_shipped_yaml_equals_dataclass_defaults() -> None:
    shipped = load_config(REPO / "configs" / "euroc.yaml")
    assert shipped == RunConfig()
    assert load_config(None) == shipped  # no --config: the shipped file


def test_resolved_config_round_trips(tmp_path: Path) -> None:
    cfg = config_from_dict({"backend": {"lag_s": 4}, "frontend": {"n_features": 800}})
    assert cfg.backend.lag_s == 4.0 and isinstance(cfg.backend.lag_s, float)
    p = tmp_path / "config.yaml"
    p.write_text(cfg.to_yaml())
    assert load_config(p) == cfg


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"backend": {"lag": 3}}, "backend.lag"),
        ({"bakend": {}}, "bakend"),
        ({"init": {"mode": "sometimes"}}, "init.mode"),
        ({"health": {"max_speed": -1}}, "health.max_speed"),
        ({"backend": {"final_batch": "yes"}}, "backend.final_batch"),
        ({"imu": {"gravity": "g"}}, "imu.gravity"),
        ({"mode": "inertial"}, "mode"),
        ({"frontend": {"n_featurs": 800}}, "frontend.n_featurs"),
        ({"frontend": {"n_features": "many"}}, "frontend.n_features"),
        ({"frontend": {"n_features": 10}}, "frontend.n_features"),
        ({"frontend": {"min_depth_m": 0.2}}, "frontend.min_depth_m"),
        ({"frontend": {"track_radius_deg": 45.0}}, "frontend.track_radius_deg"),
        ({"init": {"visual_world": "up"}}, "init.visual_world"),
        ({"frontend": {"rectify_alpha": 2.0}}, "frontend.rectify_alpha"),
        ({"frontend": {"prefetch": 1}}, "frontend.prefetch"),
        ({"frontend": [1, 2]}, "frontend"),
        (
            {"frontend": {"min_fast_threshold": 30}},
            "frontend.min_fast_threshold' value 30 out of range",
        ),
        (
            {"backend": {"lag_s": float("nan")}},
            "backend.lag_s' value nan out of range",
        ),
        (
            {"places": {"loop_agree_m": 0}},
            "places.loop_agree_m' value 0.0 out of range",
        ),
    ],
)
def test_bad_keys_and_values_name_the_key(tmp_path: Path, data: dict, needle: str) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=needle.replace(".", r"\.")) as e:
        load_config(p)
    assert str(p) in str(e.value)


def test_missing_and_broken_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    p = tmp_path / "broken.yaml"
    p.write_text("backend: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(p)


def test_shipped_yaml_lists_every_frontend_tunable_at_its_default() -> None:
    """configs/euroc.yaml holds *all* tunables: the frontend section names every FrontendConfig
    field, at the dataclass default."""
    from eurocslam.frontend.config import FrontendConfig

    text = yaml.safe_load((REPO / "configs" / "euroc.yaml").read_text())
    assert set(text) == {f.name for f in dataclasses.fields(RunConfig)}
    shipped = text["frontend"]
    assert set(shipped) == {f.name for f in dataclasses.fields(FrontendConfig)}
    assert config_from_dict({"frontend": shipped}).frontend == FrontendConfig()


def test_unknown_key_error_lists_the_allowed_keys(tmp_path: Path) -> None:
    p = tmp_path / "typo.yaml"
    p.write_text("frontend:\n  n_featurs: 800\n")
    with pytest.raises(ConfigError) as e:
        load_config(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: unknown key 'frontend.n_featurs'")
    assert "n_features" in msg and "reuse_map" in msg  # the allowed keys


def test_mode_is_resolved_against_the_sequence() -> None:
    from eurocslam.config import STEREO_INERTIAL, VISUAL_ONLY, resolve_mode

    assert resolve_mode(RunConfig(), has_imu=True).mode == STEREO_INERTIAL
    assert resolve_mode(RunConfig(), has_imu=False).mode == VISUAL_ONLY  # a stereo-only rig
    vo = RunConfig(mode=VISUAL_ONLY)
    assert resolve_mode(vo, has_imu=False) is vo
    with pytest.raises(ConfigError, match="seq: no IMU data"):
        resolve_mode(RunConfig(mode=STEREO_INERTIAL), has_imu=False, where="seq")
    with pytest.raises(ConfigError, match="not resolved"):
        _ = RunConfig().inertial


def test_tracking_one_frame_in_n_needs_the_imu(tmp_path: Path) -> None:
    """`frontend.track_every` bridges the frames between with the IMU: a visual-only run (asked
    for, or a sequence without an IMU) cannot have it; 0 is out of range."""
    from eurocslam.config import STEREO_INERTIAL, VISUAL_ONLY, resolve_mode

    every2 = RunConfig(frontend=FrontendConfig(track_every=2))
    assert resolve_mode(every2, has_imu=True).mode == STEREO_INERTIAL
    for cfg, has_imu in ((every2, False), (dataclasses.replace(every2, mode=VISUAL_ONLY), True)):
        with pytest.raises(ConfigError, match=r"'frontend\.track_every' value 2: .* visual-only"):
            resolve_mode(cfg, has_imu=has_imu)
    p = tmp_path / "c.yaml"
    p.write_text("frontend:\n  track_every: 0\n")
    with pytest.raises(ConfigError, match=r"'frontend\.track_every' value 0 out of range"):
        load_config(p)


def test_fast_preset_is_the_defaults_with_track_every_2() -> None:
    """configs/fast.yaml (README, docs/commands.md): keys it leaves out take the defaults, so it
    is the default configuration but for tracking every second frame, which needs the IMU."""
    from eurocslam.config import STEREO_INERTIAL, resolve_mode

    fast = load_config(REPO / "configs" / "fast.yaml")
    assert fast.frontend.track_every == 2
    default = RunConfig()
    expected = dataclasses.replace(
        default, frontend=dataclasses.replace(default.frontend, track_every=2)
    )
    assert fast == expected
    assert resolve_mode(fast, has_imu=True).mode == STEREO_INERTIAL
    with pytest.raises(ConfigError, match="track_every"):
        resolve_mode(fast, has_imu=False)


def test_fisheye_preset_is_the_defaults_with_map_reuse_for_a_short_focal() -> None:
    """configs/fisheye.yaml (README, docs/commands.md): the defaults but for map reuse's pixel
    floor and the re-found landmark's stereo anchor."""
    fisheye = load_config(REPO / "configs" / "fisheye.yaml")
    default = RunConfig()
    expected = dataclasses.replace(
        default,
        frontend=dataclasses.replace(default.frontend, reuse_radius_min_px=6.0),
        backend=dataclasses.replace(default.backend, refound_prior_stereo=True),
    )
    assert fisheye == expected


def test_a_limit_names_its_rule() -> None:
    """One line: the key, the value, and the bound it breaks (a number or another key)."""
    with pytest.raises(ConfigError) as e:
        config_from_dict({"frontend": {"min_fast_threshold": 30}})
    assert str(e.value) == (
        "<config>: key 'frontend.min_fast_threshold' value 30 out of range "
        "(must be <= fast_threshold)"
    )
    with pytest.raises(
        ConfigError, match=r"'backend\.lag_s' value 0\.0 out of range \(must be > 0"
    ):
        config_from_dict({"backend": {"lag_s": 0}})
