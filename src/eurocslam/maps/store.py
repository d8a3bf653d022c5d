"""A run's map on disk (`OUT/map/`): what a later session needs to localize in it and map on.

Layout (format version `FORMAT_VERSION`), numpy arrays without pickles, loaded in one read each:

* `map.json`: format tag and version, the vocabulary id the keyframes' bag-of-words vectors
  were made with, the rig the map was built with (cameras and IMU extrinsics, as numbers), the
  mode, counts, and the sessions that made it (name, keyframes, landmarks).
* `keyframes.npz`: per keyframe `key`, `t_ns`, `session`, `T_world_body` (N, 4, 4); its stereo
  observations concatenated over keyframes with `obs_offset` (N + 1): `uv` (uL, uR, v
  rectified pixels), `desc` (ORB, 32 bytes), `landmark_id` (-1: none), `octave`, `p_body`
  (the stereo point in the body frame); its bag-of-words vector with `bow_offset`: `bow_word`,
  `bow_weight`.
* `landmarks.npz`: `id`, `xyz` (world), `desc`, `octave` of every landmark of the map.

Every pose and point is in the map's world frame (the first session's; gravity-aligned on a
stereo-inertial map). A folder that is not such a map, a truncated array or another version is
a one-line `MapError` naming the file.
"""

from __future__ import annotations

import json
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from eurocslam.dataset.calib import CameraCalib, StereoRig
from eurocslam.errors import MapError
from eurocslam.geometry import F64

FORMAT = "eurocslam-map"
FORMAT_VERSION = 1
_KF_ARRAYS: dict[str, tuple[type, tuple[int, ...]]] = {
    "key": (np.int64, ()),
    "t_ns": (np.int64, ()),
    "session": (np.int64, ()),
    "T_world_body": (np.float64, (4, 4)),
    "obs_offset": (np.int64, ()),
    "uv": (np.float64, (3,)),
    "desc": (np.uint8, (32,)),
    "landmark_id": (np.int64, ()),
    "octave": (np.int32, ()),
    "p_body": (np.float64, (3,)),
    "bow_offset": (np.int64, ()),
    "bow_word": (np.int32, ()),
    "bow_weight": (np.float64, ()),
}
_LM_ARRAYS: dict[str, tuple[type, tuple[int, ...]]] = {
    "id": (np.int64, ()),
    "xyz": (np.float64, (3,)),
    "desc": (np.uint8, (32,)),
    "octave": (np.int32, ()),
}
# calibrations that differ by less than this (pixels, metres, radians) are the same rig
RIG_TOLERANCE = 1e-6


@dataclass(frozen=True)
class MapKeyframe:
    """One keyframe of a saved map (arrays of its stereo observations)."""

    key: int
    t_ns: int
    session: int
    T_world_body: F64
    uv: F64
    desc: NDArray[np.uint8]
    landmark_id: NDArray[np.int64]
    octave: NDArray[np.int32]
    p_body: F64
    bow_word: NDArray[np.int32]
    bow_weight: F64


@dataclass(frozen=True)
class SavedMap:
    keyframes: list[MapKeyframe]
    landmark_id: NDArray[np.int64]
    landmark_xyz: F64
    landmark_desc: NDArray[np.uint8]
    landmark_octave: NDArray[np.int32]
    vocabulary_id: str
    rig: dict[str, Any]  # `rig_record`
    mode: str
    sessions: list[dict[str, Any]]

    @property
    def next_landmark_id(self) -> int:
        return int(self.landmark_id.max()) + 1 if self.landmark_id.size else 0

    @property
    def next_key(self) -> int:
        return max((kf.key for kf in self.keyframes), default=-1) + 1


# ---- the rig ----------------------------------------------------------------------------------
def _camera_record(c: CameraCalib) -> dict[str, Any]:
    return {
        "resolution": [c.width, c.height],
        "intrinsics": [c.fx, c.fy, c.cx, c.cy],
        "distortion_model": c.distortion_model,
        "distortion": list(c.distortion),
        "T_body_cam": np.asarray(c.T_body_cam).reshape(-1).tolist(),
    }


def rig_record(rig: StereoRig) -> dict[str, Any]:
    """The numbers of a rig that a map depends on (cameras; the IMU's extrinsics)."""
    rec: dict[str, Any] = {"cam0": _camera_record(rig.cam0), "cam1": _camera_record(rig.cam1)}
    if rig.imu is not None:
        rec["imu0"] = {"T_body_imu": np.asarray(rig.imu.T_body_imu).reshape(-1).tolist()}
    return rec


def rig_mismatch(saved: dict[str, Any], rig: StereoRig) -> str | None:
    """What differs between the rig a map was built with and `rig` (None: the same cameras).
    The IMU may be absent on either side: a stereo-only session can localize in a
    stereo-inertial map and the other way round."""
    now = rig_record(rig)
    for cam in ("cam0", "cam1"):
        a, b = saved.get(cam), now[cam]
        if not isinstance(a, dict):
            return f"no {cam} in the map's rig"
        model_a = a.get("distortion_model")  # maps saved before it was recorded lack it
        if model_a is not None and model_a != b["distortion_model"]:
            return f"{cam} distortion model '{model_a}' in the map, '{b['distortion_model']}' here"
        for key in ("resolution", "intrinsics", "distortion", "T_body_cam"):
            va = np.asarray(a.get(key, []), dtype=np.float64)
            vb = np.asarray(b[key], dtype=np.float64)
            if va.shape != vb.shape or np.abs(va - vb).max(initial=0.0) > RIG_TOLERANCE:
                return f"{cam} {key} {_short(va)} in the map, {_short(vb)} here"
    return None


def _short(v: NDArray[np.float64]) -> str:
    return (
        "[" + ", ".join(f"{x:.6g}" for x in v.reshape(-1)[:4]) + (", ...]" if v.size > 4 else "]")
    )


# ---- save -------------------------------------------------------------------------------------
def save_map(folder: Path | str, m: SavedMap) -> Path:
    """Write `m` into `folder` (created); returns the folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    kfs = m.keyframes
    n_obs = np.array([kf.uv.shape[0] for kf in kfs], dtype=np.int64)
    n_bow = np.array([kf.bow_word.size for kf in kfs], dtype=np.int64)

    def cat(name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        parts: list[np.ndarray] = [
            np.asarray(getattr(kf, name), dtype=dtype).reshape(-1, *shape) for kf in kfs
        ]
        return np.concatenate(parts) if parts else np.zeros((0, *shape), dtype)

    arrays = {
        "key": np.array([kf.key for kf in kfs], dtype=np.int64),
        "t_ns": np.array([kf.t_ns for kf in kfs], dtype=np.int64),
        "session": np.array([kf.session for kf in kfs], dtype=np.int64),
        "T_world_body": np.array([kf.T_world_body for kf in kfs], dtype=np.float64).reshape(
            -1, 4, 4
        ),
        "obs_offset": np.concatenate([[0], np.cumsum(n_obs)]).astype(np.int64),
        "uv": cat("uv", (3,), np.float64),
        "desc": cat("desc", (32,), np.uint8),
        "landmark_id": cat("landmark_id", (), np.int64).reshape(-1),
        "octave": cat("octave", (), np.int32).reshape(-1),
        "p_body": cat("p_body", (3,), np.float64),
        "bow_offset": np.concatenate([[0], np.cumsum(n_bow)]).astype(np.int64),
        "bow_word": cat("bow_word", (), np.int32).reshape(-1),
        "bow_weight": cat("bow_weight", (), np.float64).reshape(-1),
    }
    np.savez(folder / "keyframes.npz", **arrays)  # type: ignore[arg-type]
    np.savez(
        folder / "landmarks.npz",
        id=np.asarray(m.landmark_id, np.int64),
        xyz=np.asarray(m.landmark_xyz, np.float64).reshape(-1, 3),
        desc=np.asarray(m.landmark_desc, np.uint8).reshape(-1, 32),
        octave=np.asarray(m.landmark_octave, np.int32),
    )
    meta = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "vocabulary_id": m.vocabulary_id,
        "mode": m.mode,
        "keyframes": len(kfs),
        "landmarks": int(m.landmark_id.size),
        "sessions": m.sessions,
        "rig": m.rig,
    }
    (folder / "map.json").write_text(json.dumps(meta, indent=1) + "\n")
    return folder


# ---- load -------------------------------------------------------------------------------------
def load_map(folder: Path | str) -> SavedMap:
    """The map in `folder` (a `MapError` naming the file for anything that is not one)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise MapError(f"{folder}: no map folder (a run's OUT/map)")
    meta_path = folder / "map.json"
    try:
        meta = json.loads(meta_path.read_text())
    except FileNotFoundError:
        raise MapError(f"{meta_path}: missing: {folder} is not a saved map") from None
    except (OSError, ValueError) as e:
        raise MapError(f"{meta_path}: not readable as a map description ({e})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise MapError(f"{meta_path}: not an eurocslam map (format '{FORMAT}' expected)")
    if meta.get("version") != FORMAT_VERSION:
        raise MapError(
            f"{meta_path}: map format version {meta.get('version')}; this eurocslam reads "
            f"version {FORMAT_VERSION}"
        )
    for key, typ in (("vocabulary_id", str), ("rig", dict), ("mode", str), ("sessions", list)):
        if not isinstance(meta.get(key), typ):
            raise MapError(f"{meta_path}: key '{key}' missing or of the wrong type")
    kf = _arrays(folder / "keyframes.npz", _KF_ARRAYS)
    lm = _arrays(folder / "landmarks.npz", _LM_ARRAYS)
    n = kf["key"].size
    path = folder / "keyframes.npz"
    for name in ("t_ns", "session", "T_world_body"):
        if kf[name].shape[0] != n:
            raise MapError(f"{path}: '{name}' has {kf[name].shape[0]} rows for {n} keyframes")
    obs = kf["obs_offset"]
    bow = kf["bow_offset"]
    for name, off, cols in (
        ("obs_offset", obs, ("uv", "desc", "landmark_id", "octave", "p_body")),
        ("bow_offset", bow, ("bow_word", "bow_weight")),
    ):
        total = kf[cols[0]].shape[0]
        if (
            off.size != n + 1
            or off[0] != 0
            or np.any(np.diff(off) < 0)
            or off[-1] != total
            or any(kf[c].shape[0] != total for c in cols)
        ):
            raise MapError(f"{path}: '{name}' does not index its arrays (truncated or corrupt)")
    m = lm["id"].size
    if any(lm[c].shape[0] != m for c in _LM_ARRAYS):
        raise MapError(f"{folder / 'landmarks.npz'}: arrays of different lengths")
    if meta.get("keyframes") != n or meta.get("landmarks") != m:
        raise MapError(f"{meta_path}: counts do not match the arrays (a partial copy?)")
    keyframes = [
        MapKeyframe(
            int(kf["key"][i]),
            int(kf["t_ns"][i]),
            int(kf["session"][i]),
            kf["T_world_body"][i],
            kf["uv"][obs[i] : obs[i + 1]],
            kf["desc"][obs[i] : obs[i + 1]],
            kf["landmark_id"][obs[i] : obs[i + 1]],
            kf["octave"][obs[i] : obs[i + 1]],
            kf["p_body"][obs[i] : obs[i + 1]],
            kf["bow_word"][bow[i] : bow[i + 1]],
            kf["bow_weight"][bow[i] : bow[i + 1]],
        )
        for i in range(n)
    ]
    return SavedMap(
        keyframes,
        lm["id"],
        lm["xyz"],
        lm["desc"],
        lm["octave"],
        meta["vocabulary_id"],
        meta["rig"],
        meta["mode"],
        meta["sessions"],
    )


def _arrays(path: Path, spec: dict[str, tuple[type, tuple[int, ...]]]) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {}
            for name, (dtype, shape) in spec.items():
                if name not in z.files:
                    raise MapError(f"{path}: array '{name}' missing")
                a = z[name]
                if a.dtype != np.dtype(dtype) or a.shape[1:] != shape:
                    raise MapError(
                        f"{path}: array '{name}' is {a.dtype}{list(a.shape)}, expected "
                        f"{np.dtype(dtype)}[n{''.join(f', {s}' for s in shape)}]"
                    )
                out[name] = a
            return out
    except FileNotFoundError:
        raise MapError(f"{path}: missing") from None
    except MapError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise MapError(f"{path}: not readable ({type(e).__name__}: {e})") from None


def session_record(name: str, n_keyframes: int, n_landmarks: int) -> dict[str, Any]:
    return {
        "name": name,
        "saved": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "keyframes": n_keyframes,
        "landmarks": n_landmarks,
    }
