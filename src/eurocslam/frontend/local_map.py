"""The tracker's local map: landmarks with persistent int64 ids, kept sorted by id, and the
archive of landmarks culled for going unseen (map reuse finds them again).

The tracker changes the map through its methods (`add`, `mark_visible`, `mark_found`,
`move_all`, `set_positions`, `set_keyframe_view`, `cull`, `restart`, `retire`, `revive`) and
only reads its arrays. Positions are in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64

I64 = NDArray[np.int64]
ARCHIVE_KEEP = 0.9  # an archive over its capacity drops its least found rows down to this share


_FIELDS = ("ids", "xyz", "desc", "octave", "n_visible", "n_found", "last_seen", "kf_uv")
_ARCHIVED = ("ids", "xyz", "desc", "octave", "n_visible", "n_found")


class LandmarkArchive:
    """Landmarks culled for going unseen, kept so they can be re-found (map reuse).

    Rows are appended to arrays grown by doubling and marked dead when revived or dropped, so
    retiring and reviving cost what they move, not the archive's size. Read `live` with the
    arrays up to `n`. Over `capacity` live rows, the least found are dropped (down to
    `ARCHIVE_KEEP`)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self.n = 0  # rows used, live or dead
        self.n_live = 0
        self.ids: I64 = np.zeros(0, np.int64)
        self.xyz: F64 = np.zeros((0, 3))
        self.desc: NDArray[np.uint8] = np.zeros((0, 32), np.uint8)
        self.octave: NDArray[np.int32] = np.zeros(0, np.int32)
        self.n_visible: I64 = np.zeros(0, np.int64)
        self.n_found: I64 = np.zeros(0, np.int64)
        self.live: NDArray[np.bool_] = np.zeros(0, bool)

    def __len__(self) -> int:
        return self.n_live

    def add(self, rows: dict[str, np.ndarray]) -> None:
        k = int(rows["ids"].size)
        if k == 0:
            return
        if self.n + k > self.live.size:
            if self.n_live < self.n // 2:  # mostly dead rows: compact instead of growing
                self._keep(np.nonzero(self.live[: self.n])[0])
            if self.n + k > self.live.size:
                size = max(1024, 2 * (self.n + k))
                for name in (*_ARCHIVED, "live"):
                    a = getattr(self, name)
                    grown = np.zeros((size, *a.shape[1:]), a.dtype)
                    grown[: self.n] = a[: self.n]
                    setattr(self, name, grown)
        sl = slice(self.n, self.n + k)
        for name in _ARCHIVED:
            getattr(self, name)[sl] = rows[name]
        self.live[sl] = True
        self.n += k
        self.n_live += k
        if self.n_live > self.capacity:
            live = np.nonzero(self.live[: self.n])[0]
            order = np.argsort(-self.n_found[live], kind="stable")
            self.live[live[order[int(ARCHIVE_KEEP * self.capacity) :]]] = False
            self.n_live = int(self.live[: self.n].sum())

    def take(self, rows: NDArray[np.intp]) -> dict[str, np.ndarray]:
        """Rows (live, distinct) out of the archive."""
        out = {name: getattr(self, name)[rows] for name in _ARCHIVED}
        self.live[rows] = False
        self.n_live -= int(rows.size)
        return out

    def clear(self) -> None:
        self.live[: self.n] = False
        self.n = self.n_live = 0

    def _keep(self, rows: NDArray[np.intp]) -> None:
        for name in (*_ARCHIVED, "live"):
            a = getattr(self, name)
            a[: rows.size] = a[rows]
        self.n = self.n_live = int(rows.size)


class LocalMap:
    """Landmarks with persistent int64 ids, kept sorted by id.

    `archive` holds the reliable landmarks culled because they went unseen (`retire`);
    `revive` moves re-found ones back under their old ids."""

    def __init__(self, first_id: int = 0, archive_capacity: int = 0) -> None:
        self.next_id = int(first_id)
        self.ids: I64 = np.zeros(0, np.int64)
        self.xyz: F64 = np.zeros((0, 3))  # world frame
        self.desc: NDArray[np.uint8] = np.zeros((0, 32), np.uint8)
        self.octave: NDArray[np.int32] = np.zeros(0, np.int32)
        self.n_visible: I64 = np.zeros(0, np.int64)  # predicted inside the image
        self.n_found: I64 = np.zeros(0, np.int64)  # matched as a pose inlier
        self.last_seen: I64 = np.zeros(0, np.int64)  # t_ns of the last inlier match
        self.kf_uv: F64 = np.zeros((0, 2))  # pixel position at the last keyframe (NaN: unseen)
        self.archive = LandmarkArchive(archive_capacity)

    def __len__(self) -> int:
        return int(self.ids.size)

    def add(
        self, xyz: F64, desc: NDArray[np.uint8], octave: NDArray[np.int32], uv: F64, t_ns: int
    ) -> I64:
        n = xyz.shape[0]
        ids = np.arange(self.next_id, self.next_id + n, dtype=np.int64)
        self.next_id += n
        self._append(
            {
                "ids": ids,
                "xyz": xyz,
                "desc": desc,
                "octave": octave.astype(np.int32),
                "n_visible": np.ones(n, np.int64),
                "n_found": np.ones(n, np.int64),
                "last_seen": np.full(n, t_ns, np.int64),
                "kf_uv": uv,
            }
        )
        return ids

    def keep(self, mask: NDArray[np.bool_] | NDArray[np.intp]) -> None:
        """Keep the rows `mask` selects (a boolean mask or row indices, in their order)."""
        for name in _FIELDS:
            setattr(self, name, getattr(self, name)[mask])

    def clear(self) -> None:
        self.keep(np.zeros(len(self), dtype=bool))
        self.archive.clear()

    def retire(self, mask: NDArray[np.bool_]) -> None:
        """Move rows `mask` out of the map into the archive."""
        if not mask.any():
            return
        self.archive.add({name: getattr(self, name)[mask] for name in _ARCHIVED})
        self.keep(~mask)

    def revive(
        self,
        rows: NDArray[np.intp],
        xyz: F64,
        desc: NDArray[np.uint8],
        octave: NDArray[np.int32],
        uv: F64,
        t_ns: int,
    ) -> I64:
        """Move archive rows back into the map under their ids, as seen now: position,
        descriptor, octave and pixel of the sighting that re-found them."""
        back = self.archive.take(rows)
        n = int(rows.size)
        back.update(
            xyz=xyz,
            desc=desc,
            octave=octave.astype(np.int32),
            kf_uv=uv,
            last_seen=np.full(n, t_ns, np.int64),
            n_visible=back["n_visible"] + 1,
            n_found=back["n_found"] + 1,
        )
        self._append(back)
        return back["ids"]

    def positions(self, ids: I64) -> F64:
        """World positions (N, 3) of landmark ids; NaN rows for ids no longer in the map."""
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        rows = self.index_of(ids)
        out = np.full((ids.size, 3), np.nan)
        ok = rows >= 0
        out[ok] = self.xyz[rows[ok]]
        return out

    def mark_visible(self, in_view: NDArray[np.bool_]) -> None:
        """The rows `in_view` were predicted inside this frame's image."""
        self.n_visible[in_view] += 1

    def mark_found(self, rows: NDArray[np.intp], t_ns: int, desc: NDArray[np.uint8]) -> None:
        """The rows were matched as pose inliers at `t_ns`, by keypoints with descriptors `desc`
        (the landmarks take them: the latest look)."""
        self.n_found[rows] += 1
        self.last_seen[rows] = t_ns
        self.desc[rows] = desc

    def set_keyframe_view(self, ids: I64, uv: F64) -> None:
        """Where the landmarks `ids` are seen at the new keyframe (pixels, rows aligned); every
        other landmark is unseen there."""
        self.kf_uv[:] = np.nan
        self.kf_uv[self.index_of(ids)] = uv

    def move_all(self, T_new_old: F64) -> None:
        """Move every landmark rigidly (`T_new_old`: old world -> new world); a landmark whose
        moved position is not finite stays."""
        if not len(self):
            return
        moved = self.xyz @ T_new_old[:3, :3].T + T_new_old[:3, 3]
        ok = np.all(np.isfinite(moved), axis=1)
        self.xyz[ok] = moved[ok]

    def set_positions(self, ids: I64, xyz: F64) -> None:
        """New world positions of landmarks by id; unknown ids and non-finite rows are ignored."""
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        rows = self.index_of(ids)
        ok = (rows >= 0) & np.all(np.isfinite(xyz), axis=1)
        self.xyz[rows[ok]] = xyz[ok]

    def restart(self, archive_min_found: int | None) -> None:
        """Empty the map for a new one; with `archive_min_found`, the landmarks found at least
        that often wait in the archive (map reuse finds them again where the new map meets the
        old one), the rest go."""
        if archive_min_found is not None and len(self):
            self.retire(self.n_found >= archive_min_found)
        self.keep(np.zeros(len(self), dtype=bool))

    def cull(self, t_ns: int, rules: CullRules) -> None:
        """Drop the landmarks unseen for longer than `rules.max_unseen_ns`, those found too
        rarely where they were predicted visible, and beyond `rules.max_landmarks` the least
        recently seen; with `rules.archive_min_found`, the reliable ones among those unseen wait
        in the archive."""
        if len(self) == 0:
            return
        keep = (t_ns - self.last_seen) <= rules.max_unseen_ns
        ratio_bad = (self.n_visible >= rules.min_visible_for_ratio) & (
            self.n_found < rules.min_found_ratio * self.n_visible
        )
        keep &= ~ratio_bad
        if keep.sum() > rules.max_landmarks:
            # keep the most recently seen
            idx = np.nonzero(keep)[0]
            order = np.argsort(-self.last_seen[idx], kind="stable")
            keep[:] = False
            keep[idx[order[: rules.max_landmarks]]] = True
        if keep.all():
            return
        if rules.archive_min_found is not None:  # reliable landmarks that went unseen wait
            retire = ~keep & ~ratio_bad & (self.n_found >= rules.archive_min_found)
            self.retire(retire)
            keep = keep[~retire]
        self.keep(keep)

    def _append(self, rows: dict[str, np.ndarray]) -> None:
        if rows["ids"].size == 0:
            return
        tail_sorted = not len(self) or rows["ids"].min() > self.ids[-1]
        for name in _FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), rows[name]]))
        if not (tail_sorted and np.all(np.diff(rows["ids"]) > 0)):
            self.keep(np.argsort(self.ids, kind="stable"))

    def index_of(self, ids: I64) -> NDArray[np.intp]:
        """Row of each id, -1 when the id is not (or no longer) in the map."""
        ids = np.asarray(ids, dtype=np.int64)
        pos = np.searchsorted(self.ids, ids)
        pos = np.clip(pos, 0, max(len(self) - 1, 0))
        found = (len(self) > 0) & (self.ids[pos] == ids) if len(self) else np.zeros(ids.shape, bool)
        return np.where(found, pos, -1)


@dataclass(frozen=True)
class CullRules:
    """When `LocalMap.cull` drops a landmark (see there)."""

    max_unseen_ns: int
    min_visible_for_ratio: int
    min_found_ratio: float
    max_landmarks: int
    archive_min_found: int | None  # None: no archive (map reuse off)
