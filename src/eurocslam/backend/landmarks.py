"""Landmark keys of one segment: frontend ids <-> GTSAM keys, positions, the smoother window.

A landmark gets a key L(i) when the smoother first takes it. When the fixed-lag smoother has
marginalised it and it is seen again, it gets a fresh key (the smoother must not see a key
again), while the segment's global graph keeps using its first key (`gkey`): so the final batch
has one variable per landmark, and a landmark re-found after a while (map reuse) ties the
keyframes then to those now.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import cast

import numpy as np
from numpy.typing import NDArray

from eurocslam.geometry import F64


def landmark_indices(keys: Iterable[int]) -> NDArray[np.int64]:
    """The indices of the landmark symbols L(i) among gtsam keys, in the keys' order."""
    k = np.asarray(keys, dtype=np.uint64)
    is_l = (k >> np.uint64(56)) == np.uint64(ord("l"))
    return cast(NDArray[np.int64], (k[is_l] & np.uint64((1 << 56) - 1)).astype(np.int64))


class LandmarkKeys:
    """Per landmark key index: latest position, frontend id, whether it is in the smoother
    window, its key in the global graph, and (per global key) its observations and, where kept,
    their information."""

    def __init__(self) -> None:
        self.key_of: dict[int, int] = {}  # frontend landmark id -> current key index
        self.n = 0  # key indices used
        self.pos = np.zeros((1024, 3))
        self.fid = np.zeros(1024, np.int64)
        self.active = np.zeros(1024, bool)
        self.smoothed = np.zeros(1024, bool)  # the key was in the smoother window (pos smoothed)
        self.first_kf = np.zeros(1024, np.int64)  # the keyframe that first saw the landmark
        self.gkey = np.zeros(1024, np.int64)  # the landmark's key in the global graph
        self.nobs = np.zeros(1024, np.int64)  # per global key: observations in the segment
        # per global key: the information (3, 3, world) of the stereo observations the smoother
        # took, where `backend.refound_prior_views` keeps it (else zeros)
        self.info = np.zeros((1024, 3, 3))

    def is_active(self, fid: int) -> bool:
        k = self.key_of.get(fid)
        return k is not None and bool(self.active[k])

    def was_smoothed(self, fid: int) -> bool:
        """The landmark has been in the smoother window (under its current key)."""
        k = self.key_of.get(fid)
        return k is not None and bool(self.smoothed[k])

    def new_key(self, fid: int, kf: int) -> int:
        """A fresh key index for frontend landmark `fid` (active), seen at keyframe `kf`; its
        global key is its first key's."""
        key_i = self.n
        self.n += 1
        if key_i >= self.pos.shape[0]:
            n = 2 * self.pos.shape[0]
            self.pos = np.resize(self.pos, (n, 3))
            self.fid = np.resize(self.fid, n)
            self.gkey = np.resize(self.gkey, n)
            self.nobs = np.pad(self.nobs, (0, n - self.nobs.size))  # zeros
            self.info = np.concatenate([self.info, np.zeros((n - len(self.info), 3, 3))])
            self.active = np.pad(self.active, (0, n - self.active.size))  # False
            self.smoothed = np.pad(self.smoothed, (0, n - self.smoothed.size))
            self.first_kf = np.resize(self.first_kf, n)
        old = self.key_of.get(fid)
        self.gkey[key_i] = key_i if old is None else self.gkey[old]
        self.first_kf[key_i] = kf
        self.key_of[fid] = key_i
        self.fid[key_i] = fid
        self.active[key_i] = True
        return key_i

    def set_window(self, idx: NDArray[np.int64], pts: F64) -> None:
        """The smoother's estimate: exactly the key indices `idx` are in its window, at `pts`."""
        self.active[: self.n] = False
        if idx.size:
            self.pos[idx] = pts
            self.active[idx] = True
            self.smoothed[idx] = True

    def move_window_out(self, T_new_old: F64) -> None:
        """The smoother that held the window is gone (a loop moved the estimate): its landmarks
        move rigidly with the estimate and leave the window (they come back under new keys)."""
        act = np.nonzero(self.active[: self.n])[0]
        self.pos[act] = self.pos[act] @ T_new_old[:3, :3].T + T_new_old[:3, 3]
        self.active[:] = False

    def move_with_keyframes(self, T_new_old: dict[int, F64]) -> None:
        """Every landmark moved with the correction of the keyframe that first saw it
        (keyframe index -> correction; landmarks of other keyframes stay)."""
        for key in range(self.n):
            C = T_new_old.get(int(self.first_kf[key]))
            if C is not None:
                self.pos[key] = C[:3, :3] @ self.pos[key] + C[:3, 3]

    def positions(self, fids: NDArray[np.int64]) -> F64:
        """The latest positions (N, 3) of landmarks by frontend id (NaN: unknown here)."""
        keys = np.array([self.key_of.get(int(i), -1) for i in fids], dtype=np.int64)
        out = np.full((len(keys), 3), np.nan)
        ok = keys >= 0
        out[ok] = self.pos[keys[ok]]
        return out

    def in_window(self) -> tuple[NDArray[np.int64], F64]:
        """Frontend ids and world positions of the landmarks in the smoother window."""
        act = np.nonzero(self.active[: self.n])[0]
        return self.fid[act].copy(), self.pos[act].copy()
