"""benchmarks/bench_loops.py watches the place stage's `loop` from outside the pipeline; this
runs it on a built-in flight so a change of the stage's interface cannot leave it broken (it
was, from the stage's records refactor until stop 44)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.mark.slow
def test_bench_loops_measures_every_verified_loop_on_a_built_in_flight(tmp_path: Path) -> None:
    from eurocslam.pipeline import places as place_stage
    from eurocslam.synth import SynthSpec, synthesize

    seq = synthesize(SynthSpec(duration_s=30.0, seed=0), tmp_path / "flight")
    sys.path.insert(0, str(BENCH))
    try:
        spec = importlib.util.spec_from_file_location("bench_loops", BENCH / "bench_loops.py")
        assert spec is not None and spec.loader is not None
        bench = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(bench)
        loop = place_stage.PlaceStage.loop
        loops, ate = bench.run(seq, {})
    finally:
        sys.path.remove(str(BENCH))
    assert place_stage.PlaceStage.loop is loop  # put back
    assert loops, "the flight revisits its start: loops are verified"
    for row in loops:
        assert row["inliers"] >= 40 and isinstance(row["corrected"], bool)
        for k in ("err_deg", "err_m", "true_deg", "true_m", "meas_deg", "meas_m"):
            assert math.isfinite(row[k]) and row[k] >= 0, (k, row)
        assert row["err_m"] < 0.2, row  # a verified loop measures the drift to centimetres
    assert 0 < ate["final"] < 0.05 and 0 < ate["online"] < 0.1, ate
