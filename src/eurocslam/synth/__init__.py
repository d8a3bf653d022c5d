"""Synthetic and semi-real EuRoC sequences.

`synthesize(SynthSpec(...), out_dir)` writes a complete EuRoC ASL folder (stereo PNGs rendered
through the real camera model, 200 Hz IMU, 17-column ground truth, sensor.yaml files) that every
eurocslam command reads. The motion is a built-in drone flight or a given ground truth (a
"semi-real replica" of a real EuRoC sequence); the IMU is simulated or the real rows.

    from eurocslam.synth import SynthSpec, synthesize
    seq = synthesize(SynthSpec.tiny(seed=3), tmp_path / "seq")   # ~2 s, a few seconds to make

`Scene.build(spec)` gives the same world without writing files (render single frames, with
depth maps, for tests). `SynthSpec(trajectory=A, world_from=(A, B))` and
`SynthSpec(trajectory=B, world_from=(A, B))` fly through one shared world (`shared_world.py`).
"""

from eurocslam.synth.sequence import (
    DEFAULT_DURATION_S,
    TINY_DURATION_S,
    Scene,
    SynthSpec,
    synthesize,
)
from eurocslam.synth.world import Marker

__all__ = [
    "DEFAULT_DURATION_S",
    "TINY_DURATION_S",
    "Marker",
    "Scene",
    "SynthSpec",
    "synthesize",
]
