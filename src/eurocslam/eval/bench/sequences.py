"""Sequence folders for the runs: given folders as they are, synth specs rendered once.

A synth sequence is rendered where its runs execute: into `OUT/sequences/NAME` for local runs,
into a cache folder on each Ray worker's machine otherwise. Identical specs give byte-identical
sequences, so the runs see the same data wherever it was rendered. Concurrent tasks on one
machine render a spec once (a lock file); a folder rendered from another spec or by another
generator revision is rendered again.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from eurocslam.dataset.kitti_files import is_kitti_sequence, poses_path_of
from eurocslam.errors import ConfigError
from eurocslam.eval.bench.plan import SYNTH_PATH_KEYS, BenchPlan
from eurocslam.eval.loaders import groundtruth_csv_of

logger = logging.getLogger(__name__)

SPEC_FILE = "bench_synth_spec.json"


def _spec_text(synth: dict[str, Any]) -> str:
    from eurocslam.synth.sequence import GENERATOR_REVISION

    return json.dumps({"spec": synth, "generator_revision": GENERATOR_REVISION}, sort_keys=True)


def synth_key(synth: dict[str, Any]) -> str:
    """What identifies a rendering: the spec and the generator's revision."""
    return hashlib.sha256(_spec_text(synth).encode()).hexdigest()[:12]


def synth_cache_name(name: str, synth: dict[str, Any]) -> str:
    """A folder name for a spec in a shared cache: the name and its `synth_key`."""
    return f"{name}-{synth_key(synth)}"


def check_synth_spec(name: str, synth: dict[str, Any]) -> None:
    """A spec that SynthSpec does not take is an error before anything runs."""
    import dataclasses

    from eurocslam.synth import SynthSpec

    known = {f.name for f in dataclasses.fields(SynthSpec)}
    bad = sorted(set(synth) - known)
    if bad:
        raise ConfigError(
            f"sequence '{name}': unknown synth key(s) {bad} (known: {', '.join(sorted(known))})"
        )


def ensure_synth(name: str, synth: dict[str, Any], dest: Path, progress: bool | None) -> Path:
    """Render `synth` into `dest` unless it already holds exactly that rendering."""
    from eurocslam.synth import SynthSpec, synthesize

    want = _spec_text(synth)
    spec_file = dest / SPEC_FILE
    dest.parent.mkdir(parents=True, exist_ok=True)
    with open(dest.parent / f".{dest.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another task on this machine may be rendering it
        if spec_file.exists() and spec_file.read_text() == want:
            return dest
        kw: dict[str, Any] = {
            k: (Path(v) if k in SYNTH_PATH_KEYS and v else v) for k, v in synth.items()
        }
        try:
            spec = SynthSpec(**kw)
        except TypeError as e:
            raise ConfigError(f"sequence '{name}': bad synth spec: {e}") from None
        logger.info(f"eurocslam bench: generating synthetic sequence '{name}'")
        # one rendering process: the fork pool of synthesize() was seen to deadlock when
        # started from a process that already runs threads (reported); bench
        # parallelises over runs anyway
        synthesize(spec, dest, progress, workers=1, overwrite=True)
        spec_file.write_text(want)
    return dest


def check_sequence_folder(name: str, path: Path) -> str | None:
    """Why `path` cannot be benched (None: it can)."""
    if not path.exists():
        return f"{path} does not exist"
    if is_kitti_sequence(path):
        if not poses_path_of(path).is_file():
            return f"{path}: a KITTI sequence without {poses_path_of(path)} to evaluate against"
        return None
    if groundtruth_csv_of(path) is None:
        return (
            f"{path} has no ground truth (mav0/state_groundtruth_estimate0 or mocap0) to "
            "evaluate against"
        )
    return None


def prepare_local(plan: BenchPlan, out_dir: Path, progress: bool | None) -> dict[str, Path]:
    """Folder of every sequence on this machine; synth sequences rendered under OUT/sequences."""
    paths: dict[str, Path] = {}
    for s in plan.sequences:
        if s.path is not None:
            why = check_sequence_folder(s.name, s.path)
            if why:
                raise ConfigError(f"sequence '{s.name}': {why}")
            paths[s.name] = s.path
    for s in plan.sequences:
        if s.synth is not None:
            check_synth_spec(s.name, s.synth)
            paths[s.name] = ensure_synth(s.name, s.synth, out_dir / "sequences" / s.name, progress)
    return paths
