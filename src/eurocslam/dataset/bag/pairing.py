"""Stereo pairing of a bag's camera messages: one entry per stamp, cam1 stamps snapped to the
nearest cam0 stamp when the cameras' stamps are not hardware-synchronised."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eurocslam.dataset.types import I64, SkipReport

SNAP_MAX_NS = 5_000_000  # 5 ms: the largest cam0/cam1 stamp difference snapped into a pair


@dataclass(frozen=True)
class BagEntry:
    """One stereo frame in the index: its stamp and which cameras have a message for it."""

    t_ns: int
    has_left: bool
    has_right: bool
    log_ns: int  # earliest log time of its messages


def camera_map(role: str, topic: str, t: I64, log_ns: I64, skips: SkipReport) -> dict[int, int]:
    """A camera's stamp -> log time (first message of a stamp kept, duplicates counted)."""
    if t.size > 1 and np.any(np.diff(t) < 0):
        skips.add("out-of-order timestamps (sorted)", topic)
    out: dict[int, int] = {}
    for ti, li in zip(t.tolist(), log_ns.tolist(), strict=True):
        if ti in out:
            skips.add(f"duplicate {role} timestamp (dropped)", f"{topic}: {ti}")
            continue
        out[ti] = li
    return out


def join_cameras(c0: dict[int, int], c1: dict[int, int], skips: SkipReport) -> list[BagEntry]:
    """Entries in stamp order for the stamps of either camera (frames in one camera counted)."""
    entries = []
    for t in sorted(c0.keys() | c1.keys()):
        if t not in c0:
            skips.add("frame in cam1 only", str(t))
        elif t not in c1:
            skips.add("frame in cam0 only", str(t))
        logs = [x for x in (c0.get(t), c1.get(t)) if x is not None]
        entries.append(BagEntry(t, t in c0, t in c1, min(logs)))
    return entries


def snap_cam1(
    c0: dict[int, int], c1: dict[int, int], rate_hz: float
) -> tuple[dict[int, int], dict[int, int], str | None]:
    """Pair cam1 stamps that match no cam0 stamp exactly with the nearest unmatched cam0
    stamp within min(5 ms, 0.2 frame periods): cameras without hardware-synchronised stamps,
    or log times (which always differ a little). The pair takes the cam0 stamp.

    Returns cam1's map re-keyed on the pairs' stamps, the aliases (cam1 stamp -> cam0 stamp) and
    a note saying what was snapped (None when nothing was)."""
    alias: dict[int, int] = {}
    un1 = sorted(c1.keys() - c0.keys())
    un0 = np.array(sorted(c0.keys() - c1.keys()), dtype=np.int64)
    if not un1 or un0.size == 0:
        return c1, alias, None
    tol = min(SNAP_MAX_NS, int(0.2e9 / rate_hz)) if rate_hz > 0 else SNAP_MAX_NS
    used: set[int] = set()
    worst = 0
    for t1 in un1:
        i = int(np.searchsorted(un0, t1))
        best = None
        for j in (i - 1, i):
            if 0 <= j < un0.size and int(un0[j]) not in used:
                d = abs(int(un0[j]) - t1)
                if d <= tol and (best is None or d < abs(best - t1)):
                    best = int(un0[j])
        if best is not None:
            alias[t1] = best
            used.add(best)
            worst = max(worst, abs(best - t1))
    if not alias:
        return c1, alias, None
    note = (
        f"{len(alias)} stereo pairs joined on the nearest stamp (cam0 and cam1 "
        f"differ by up to {worst / 1e6:.3f} ms; tolerance {tol / 1e6:.1f} ms); a pair takes "
        "the cam0 stamp"
    )
    return {alias.get(t, t): log for t, log in c1.items()}, alias, note
