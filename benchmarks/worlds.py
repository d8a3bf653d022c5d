"""The worlds the accuracy benchmarks fly in: a development set and a held-out set.

A replica is a real EuRoC motion rendered in a world built from a seed (`eurocslam synth
--trajectory GT --seed N`): the seed picks the room's layout and textures, the image noise and
the IMU noise. A rule that helps in the worlds it was tuned in and not in others was fitted to
those worlds, so:

* **development worlds** (`DEV_SEEDS`): look at them, tune on them, as often as needed;
* **held-out worlds** (`HELDOUT_SEEDS`): only measure. A default changes only when the held-out
  set holds: every replica (the eleven EuRoC motions), every held-out world, both modes
  (stereo-inertial and visual-only), final and online ATE, no worse on the mean and no
  replica's mean (over the worlds) worse by more than `GATE_REPLICA_WORSE`
  (`bench_seeds.py --set heldout` prints the verdict).

The shipped place-recognition vocabulary was trained on built-in flights in worlds 1-20
(`places/train.py`), not on replicas of the EuRoC motions, so neither set's rooms were seen by
it; the held-out seeds are far from every seed used for tuning before.

`PROTOCOL_DURATION_S`: the protocol runs each replica's first 60 s (the MH replicas include the
drone's pick-up: a dynamic start), 66 runs per variant and set; full-length replicas are 2.3x
longer and 1.6-2.6 GB each.
"""

from __future__ import annotations

DEV_SEEDS: tuple[int, ...] = (0, 1, 2)
HELDOUT_SEEDS: tuple[int, ...] = (100, 101, 102)
SETS: dict[str, tuple[int, ...]] = {"dev": DEV_SEEDS, "heldout": HELDOUT_SEEDS}
PROTOCOL_DURATION_S = 60.0
# the gate: a replica whose mean over the worlds is worse than this fraction fails it
GATE_REPLICA_WORSE = 0.10
