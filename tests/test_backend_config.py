"""Run configuration: strict loading, shipped defaults, round trip."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from eurocslam.config import RunConfig, config_from_dict, load_config
from eurocslam.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def test_shipped_yaml_equals_dataclass_defaults() -> None:
    shipped = load_config(REPO / "configs" / "euroc.yaml")
    # the frontend section (a plain mapping here) is checked against FrontendConfig below
    assert dataclasses.replace(shipped, frontend={}) == RunConfig()
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

    shipped = yaml.safe_load((REPO / "configs" / "euroc.yaml").read_text())["frontend"]
    assert set(shipped) == {f.name for f in dataclasses.fields(FrontendConfig)}
    assert FrontendConfig.from_dict(shipped) == FrontendConfig()
