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
`robot_bag.write_realsense_bag` writes a sequence as a robot's bag (realsense-ros topics, the
calibration only in CameraInfo and /tf_static).
"""

from typing import TYPE_CHECKING, Any

from eurocslam.synth.spec import DEFAULT_DURATION_S, TINY_DURATION_S, Marker, SynthSpec

if TYPE_CHECKING:
    from eurocslam.synth.sequence import Scene, synthesize

__all__ = [
    "DEFAULT_DURATION_S",
    "TINY_DURATION_S",
    "Marker",
    "Scene",
    "SynthSpec",
    "synthesize",
]

# the renderer (OpenCV, SciPy) loads on first use: the command line builds every command's
# arguments from `SynthSpec`'s defaults and must not pay for it
if not TYPE_CHECKING:  # (type checkers see the imports above)

    def __getattr__(name: str) -> Any:
        if name not in ("Scene", "synthesize"):
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        from eurocslam.synth import sequence

        return getattr(sequence, name)
