"""What a bench runs: sequences x configurations x runs, from a YAML list or the command line.

Sequence list (YAML)::

    runs: 3                        # optional; --runs overrides
    run_args: [--no-mcap]          # optional extra arguments for every run
    configs:                       # optional: a sweep; each name gets a column group
      base: ~                      # the built-in defaults (configs/euroc.yaml)
      mine: my_config.yaml         # a config file (relative to this YAML)
      n800: {frontend: {n_features: 800}}   # inline: these keys over the defaults
    sequences:
      - /data/euroc/MH_01_easy     # an EuRoC folder (name from the folder)
      - {name: V101, path: /data/euroc/V1_01_easy}
      - {name: synth_a, synth: {duration_s: 20, seed: 3}}   # eurocslam.synth.SynthSpec

Relative paths (sequences, config files, a synth spec's trajectory/imu/calib) are relative to the
YAML file. `--config NAME=FILE` on the command line adds configurations. Every configuration is
read and checked completely here, before anything runs; a run gets its configuration as text
(written beside its outputs), so workers need not see the user's config files.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from eurocslam.errors import ConfigError, EvalError

KNOWN_KEYS = {"runs", "run_args", "sequences", "configs"}
SEQ_KEYS = {"name", "path", "synth"}
SYNTH_PATH_KEYS = ("trajectory", "imu", "calib")
DEFAULT_CONFIG = "default"
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")


@dataclass(frozen=True)
class BenchSequence:
    name: str
    path: Path | None = None
    synth: dict[str, Any] | None = None


@dataclass(frozen=True)
class BenchConfig:
    """A configuration of the sweep. `text`: the YAML handed to `eurocslam run --config`
    (None: no --config, the built-in defaults); `source`: where it came from, for messages."""

    name: str
    text: str | None = None
    source: str = "built-in defaults"


@dataclass(frozen=True)
class BenchPlan:
    sequences: list[BenchSequence]
    runs: int | None = None
    run_args: list[str] = field(default_factory=list)
    configs: list[BenchConfig] = field(default_factory=list)

    @property
    def config_names(self) -> list[str]:
        return [c.name for c in self.configs] or [DEFAULT_CONFIG]

    def resolved_configs(self) -> list[BenchConfig]:
        """The configurations to run: the given ones, or the built-in defaults alone."""
        return list(self.configs) or [BenchConfig(DEFAULT_CONFIG)]


def check_config_text(text: str, origin: str) -> None:
    """Load a run configuration as `eurocslam run` will (every section), so a typo is reported
    before the bench starts, naming the file and key."""
    from eurocslam.config import config_from_dict

    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{origin}: not valid YAML: {' '.join(str(e).split())}") from None
    config_from_dict(data, origin)


def _check_name(name: str, where: str) -> str:
    if not _NAME_RE.match(name):
        raise ConfigError(
            f"{where}: configuration name {name!r} must be letters, digits, '_', '-', '.', '+' "
            "(it names folders and columns)"
        )
    return name


def config_from_file(name: str, path: Path, where: str) -> BenchConfig:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{where}: config file {path} not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{where}: cannot read config file {path}: {e}") from None
    check_config_text(text, str(path))
    return BenchConfig(_check_name(name, where), text, str(path))


def parse_config_arg(arg: str) -> BenchConfig:
    """`--config NAME=FILE` (or `--config FILE`: named after the file)."""
    name, sep, file = arg.partition("=")
    if not sep:
        name, file = Path(arg).stem, arg
    if not name or not file:
        raise ConfigError(f"--config {arg!r}: expected NAME=FILE")
    return config_from_file(name, Path(file), f"--config {arg}")


def _config_from_yaml(name: Any, value: Any, yaml_path: Path) -> BenchConfig:
    where = f"{yaml_path} (configs.{name})"
    name = _check_name(str(name), where)
    if value is None:
        return BenchConfig(name)
    if isinstance(value, str):
        p = Path(value)
        return config_from_file(name, p if p.is_absolute() else yaml_path.parent / p, where)
    if isinstance(value, dict):
        text = yaml.safe_dump(value, sort_keys=False)
        check_config_text(text, where)
        return BenchConfig(name, text, where)
    raise ConfigError(f"{where}: expected a config file, a mapping of overrides or ~ (defaults)")


def _synth_spec(item: dict[str, Any], where: str, base: Path) -> dict[str, Any]:
    spec = item["synth"]
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: 'synth' must be a mapping of SynthSpec fields")
    spec = dict(spec)
    for k in SYNTH_PATH_KEYS:  # files the generator reads: relative to the YAML, absolute here
        if isinstance(spec.get(k), str) and not Path(spec[k]).is_absolute():
            spec[k] = str((base / spec[k]).resolve())
    return spec


def load_plan(path: Path | str) -> BenchPlan:
    """Read a bench YAML (see module docstring). Unknown keys are errors."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"{path}: cannot read YAML: {e}") from None
    if isinstance(data, list):
        data = {"sequences": data}
    if not isinstance(data, dict) or "sequences" not in data:
        raise ConfigError(f"{path}: expected a mapping with a 'sequences' list")
    unknown = set(data) - KNOWN_KEYS
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {sorted(unknown)} (known: {sorted(KNOWN_KEYS)})")
    seqs = []
    for i, item in enumerate(data["sequences"] or []):
        where = f"{path} (sequences[{i}])"
        if isinstance(item, str):
            p = (path.parent / item).resolve() if not Path(item).is_absolute() else Path(item)
            seqs.append(BenchSequence(p.name, p))
            continue
        if not isinstance(item, dict):
            raise ConfigError(f"{where}: expected a path or a mapping")
        bad = set(item) - SEQ_KEYS
        if bad:
            raise ConfigError(f"{where}: unknown key(s) {sorted(bad)} (known: {sorted(SEQ_KEYS)})")
        if ("path" in item) == ("synth" in item):
            raise ConfigError(f"{where}: give exactly one of 'path' or 'synth'")
        if "path" in item:
            p = Path(str(item["path"]))
            p = p if p.is_absolute() else (path.parent / p).resolve()
            seqs.append(BenchSequence(str(item.get("name") or p.name), p))
        else:
            if "name" not in item:
                raise ConfigError(f"{where}: a synth sequence needs a 'name'")
            spec = _synth_spec(item, where, path.parent)
            seqs.append(BenchSequence(str(item["name"]), None, spec))
    if not seqs:
        raise ConfigError(f"{path}: 'sequences' is empty")
    names = [s.name for s in seqs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ConfigError(f"{path}: duplicate sequence name(s) {sorted(dup)}")
    for s in seqs:
        if "/" in s.name or s.name in (".", ".."):
            raise ConfigError(f"{path}: sequence name {s.name!r} cannot name a folder")
    runs = data.get("runs")
    if runs is not None and (not isinstance(runs, int) or runs < 1):
        raise ConfigError(f"{path}: 'runs' must be a positive integer, got {runs!r}")
    run_args = data.get("run_args") or []
    if not isinstance(run_args, list):
        raise ConfigError(f"{path}: 'run_args' must be a list of strings")
    configs_in = data.get("configs") or {}
    if not isinstance(configs_in, dict):
        raise ConfigError(f"{path}: 'configs' must be a mapping of names to config files or keys")
    configs = [_config_from_yaml(k, v, path) for k, v in configs_in.items()]
    return BenchPlan(seqs, runs, [str(a) for a in run_args], configs)


def plan_from_args(yaml_or_folders: list[Path]) -> BenchPlan:
    """A YAML file, or sequence folders given directly on the command line."""
    if len(yaml_or_folders) == 1 and yaml_or_folders[0].suffix.lower() in (".yaml", ".yml"):
        return load_plan(yaml_or_folders[0])
    seqs = []
    for p in yaml_or_folders:
        if not p.is_dir():
            raise EvalError(f"{p}: not a sequence folder (or give one .yaml sequence list)")
        seqs.append(BenchSequence(p.resolve().name, p.resolve()))
    names = [s.name for s in seqs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise EvalError(f"duplicate sequence name(s) {sorted(dup)}: give a YAML list with names")
    return BenchPlan(seqs)


def add_configs(plan: BenchPlan, extra: list[BenchConfig], no_mcap: bool) -> BenchPlan:
    """The plan with the command line's configurations (and --no-mcap) added."""
    configs = [*plan.configs, *extra]
    names = [c.name for c in configs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"configuration name(s) {dup} given twice (YAML 'configs' or --config)")
    run_args = list(plan.run_args)
    if no_mcap and "--no-mcap" not in run_args:
        run_args.append("--no-mcap")
    return replace(plan, configs=configs, run_args=run_args)
