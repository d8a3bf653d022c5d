"""One world for several flights of one place: `synth --trajectory GT --world-from GT1 GT2 ...`.

EuRoC's five Machine Hall flights share the hall's (Leica) frame, and the V1_* and V2_* flights
share their Vicon rooms' frames. A replica of each in its own world gets its own room; testing
multi-session SLAM (a map made in one session, reused in another) needs every session to fly
through the same room, with ground truths in one frame.

The shared world is a function of the `--world-from` ground truths and the seed only: the room
encloses the union of their positions and obstacles keep their clearance from every one of them.
The flights are put in a canonical order (by a digest of their poses, duplicates dropped), so
the order they are given in does not matter; the crop (`--start`/`--end`) and the rendered
`--trajectory` do not enter it. Rendering session A with `--trajectory A --world-from A B` and
session B with `--trajectory B --world-from A B` therefore gives the same room, obstacles and
textures (the same `World.digest()`), and each ground truth stays in its file's frame.

The rendered flight must stay inside that world: every camera centre inside the room and at least
`MIN_OBSTACLE_M` from every obstacle (a flight that is one of `--world-from` always is).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.errors import DatasetError, EurocSlamError
from eurocslam.geometry import F64
from eurocslam.synth.spec import Marker
from eurocslam.synth.world import World, build_world

WORLD_POINTS_PER_FLIGHT = 4000  # positions per flight the world is laid out around (as one flight)
MIN_ROOM_MARGIN_M = 0.05  # a camera centre at least this far inside the room's faces
MIN_OBSTACLE_M = 0.3  # ... and this far from every obstacle (the world keeps 0.6 m from flights)


@dataclass(frozen=True)
class WorldFlight:
    """A ground truth the shared world is built around."""

    path: Path
    digest: str  # of its stamps and positions
    positions: F64  # the (subsampled) positions the world encloses


@dataclass(frozen=True)
class SharedWorld:
    """What a shared world was built from: its flights (canonical order) and the seed."""

    flights: tuple[WorldFlight, ...]
    seed: int

    def names(self) -> list[str]:
        """The flights' file names, sorted (for people; the build order is the digests')."""
        return sorted(f.path.name for f in self.flights)

    def describe(self) -> str:
        return f"--world-from {' '.join(self.names())}"


def read_flight(path: Path) -> WorldFlight:
    """One `--world-from` ground truth (EuRoC ASL CSV or TUM); errors name the file and row."""
    from eurocslam.synth.trajectory import read_groundtruth_file

    try:
        gt = read_groundtruth_file(Path(path))
    except EurocSlamError as e:
        raise DatasetError(f"--world-from {e}") from None
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(gt.t_ns, dtype=np.int64).tobytes())
    h.update(np.ascontiguousarray(gt.p, dtype=np.float64).tobytes())
    step = max(1, len(gt.p) // WORLD_POINTS_PER_FLIGHT)
    return WorldFlight(Path(path), h.hexdigest(), np.ascontiguousarray(gt.p[::step]))


def read_flights(paths: tuple[Path, ...] | list[Path]) -> tuple[WorldFlight, ...]:
    """The flights in canonical order (by digest), each once."""
    if not paths:
        raise DatasetError("--world-from: give at least one ground-truth file")
    by_digest: dict[str, WorldFlight] = {}
    for p in paths:
        f = read_flight(p)
        by_digest.setdefault(f.digest, f)
    return tuple(by_digest[d] for d in sorted(by_digest))


def build_shared_world(
    paths: tuple[Path, ...] | list[Path], seed: int, *, marker: Marker | None = None
) -> tuple[World, SharedWorld]:
    """The world enclosing every given flight (see the module docstring)."""
    flights = read_flights(paths)
    union = np.vstack([f.positions for f in flights])
    world = build_world(union, seed, floor_z=None, marker=marker)
    return world, SharedWorld(flights, seed)


def check_flight_inside(
    world: World, shared: SharedWorld, centres: F64, t_s: F64, name: str
) -> None:
    """Raise a one-line error at the first camera centre (N, 3; `t_s`: its time in seconds after
    the flight's first pose) outside the room or too close to an obstacle."""
    inside, near = world.free_space(centres)
    bad = (inside < MIN_ROOM_MARGIN_M) | (near < MIN_OBSTACLE_M)
    if not np.any(bad):
        return
    k = int(np.flatnonzero(bad)[0])
    if inside[k] < MIN_ROOM_MARGIN_M:
        where = _room_position(world, centres[k])
    else:
        where = f"{near[k]:.2f} m from an obstacle (at least {MIN_OBSTACLE_M} m)"
    raise DatasetError(
        f"--trajectory {name}: at {t_s[k]:.2f} s a camera is {where} in the world built from "
        f"{shared.describe()}, which encloses those flights only: add the trajectory to "
        "--world-from (the same list for every session)"
    )


def _room_position(world: World, c: F64) -> str:
    """Where a point near or beyond the room's boundary is, in words."""
    d = np.concatenate([c - world.room_lo, world.room_hi - c])  # lo x, y, z, hi x, y, z
    face = int(np.argmin(d))
    name = {2: "the floor", 5: "the ceiling"}.get(face, "a wall")
    if d[face] < 0:
        side = "below" if face == 2 else ("above" if face == 5 else "beyond")
        return f"{-d[face]:.3f} m {side} {name}"
    return f"{d[face]:.2f} m from {name} (at least {MIN_ROOM_MARGIN_M} m)"
