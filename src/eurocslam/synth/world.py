"""A textured 3D world that encloses a trajectory: a box room plus boxes and pillars.

Everything is an axis-aligned box (the room is seen from inside, obstacles from outside), so ray
casting is an exact slab test and occlusion is exact. Each face carries its own procedural
texture (dead-leaves shapes at power-law sizes, text-like marks, smooth shading and grain: many
non-repeating corners at every ORB pyramid level, nothing periodic), packed with its mip levels
into one atlas per level for fast bilinear lookups (`cv2.remap`).

Face ids: room faces are `2 * axis + side` (side 1 = the face at the box's upper coordinate);
obstacle b has faces `6 + 6 * b + 2 * axis + side`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import cast

import cv2
import numpy as np

from eurocslam.geometry import F64
from eurocslam.synth.spec import Marker

TEXELS_PER_M = 200.0  # 5 mm texels
MAX_TEX = 4096  # texels per face side (larger faces get coarser texels)
MIP_LEVELS = 6  # levels 0..5
ALIGN = 1 << (MIP_LEVELS - 1)
GUTTER = ALIGN  # replicated border around each texture in the atlas (1 texel at the top level)
ATLAS_WIDTH = 8192
# texture-plane axes (s, t) for a face whose normal is along axis a
ST_AXES = ((1, 2), (0, 2), (0, 1))


@dataclass
class World:
    room_lo: F64
    room_hi: F64
    box_lo: F64  # (B, 3)
    box_hi: F64  # (B, 3)
    kinds: list[str]  # per box: 'box', 'pillar', 'marker'
    # per-face tables (index = face id)
    face_axis: np.ndarray
    org_s: F64
    org_t: F64
    k_s: F64  # texels per metre along s
    k_t: F64
    tex_w: np.ndarray  # level-0 texture size in texels
    tex_h: np.ndarray
    off_x: np.ndarray  # level-0 atlas offsets (multiples of ALIGN)
    off_y: np.ndarray
    atlas: list[np.ndarray]  # uint8 atlas per mip level
    texels_per_m: float = TEXELS_PER_M  # texel density of every face (texels per metre)

    @property
    def n_faces(self) -> int:
        return int(self.face_axis.shape[0])

    def describe(self) -> str:
        size = self.room_hi - self.room_lo
        nb = sum(k == "box" for k in self.kinds)
        npil = sum(k == "pillar" for k in self.kinds)
        texels = int(np.sum(self.tex_w.astype(np.int64) * self.tex_h))
        return (
            f"room {size[0]:.1f} x {size[1]:.1f} x {size[2]:.1f} m, {nb} boxes, {npil} pillars, "
            f"{texels / 1e6:.1f} Mtexel"
        )

    def digest(self) -> str:
        """A content digest (hex) of everything the renderer reads: room, obstacles, face
        tables, texel density and every atlas level. Two worlds with the same digest render the
        same pixels from the same pose."""
        h = hashlib.blake2b(digest_size=16)
        for a in (self.room_lo, self.room_hi, self.box_lo, self.box_hi, self.org_s, self.org_t):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        for a in (self.k_s, self.k_t):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        for a in (self.face_axis, self.tex_w, self.tex_h, self.off_x, self.off_y):
            h.update(np.ascontiguousarray(a, dtype=np.int64).tobytes())
        h.update(",".join(self.kinds).encode())
        h.update(np.float64(self.texels_per_m).tobytes())
        for level in self.atlas:
            h.update(np.int64(level.shape[1]).tobytes())
            h.update(np.ascontiguousarray(level).data)
        return h.hexdigest()

    def atlas_bytes(self) -> int:
        """Memory held by the texture atlases (every mip level)."""
        return int(sum(level.nbytes for level in self.atlas))

    def free_space(self, points: F64) -> tuple[F64, F64]:
        """For each point (N, 3): how far inside the room it is (negative: outside) and its
        distance to the nearest obstacle (inf without obstacles), in metres."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        inside = np.minimum(pts - self.room_lo, self.room_hi - pts).min(axis=1)
        near = np.full(pts.shape[0], np.inf)
        for lo, hi in zip(self.box_lo, self.box_hi, strict=True):
            near = np.minimum(near, _aabb_distance(pts, lo, hi))
        return inside, near


# ---- procedural textures --------------------------------------------------------------------
_GLYPHS = "ABCDEFGHJKLMNPQRSTUVWXYZ0123456789#%&@"


def _power_sizes(rng: np.random.Generator, n: int, smin: float, smax: float, alpha: float) -> F64:
    """Sizes with density ~ s^-alpha on [smin, smax] (alpha > 1): many small, few large."""
    u = rng.random(n)
    e = 1.0 - alpha
    return cast(F64, (smin**e + u * (smax**e - smin**e)) ** (1.0 / e))


def make_texture(
    w: int, h: int, rng: np.random.Generator, *, mean: float, spread: float, density: float = 1.0
) -> np.ndarray:
    """A non-periodic, corner-rich uint8 texture of w x h texels."""
    # smooth shading (low-frequency noise) so no two places look alike
    low = rng.random((max(2, h // 160 + 2), max(2, w // 160 + 2))).astype(np.float32)
    low = np.asarray(cv2.resize(low, (w, h), interpolation=cv2.INTER_CUBIC), dtype=np.float32)
    img = np.full((h, w), mean, np.float32)
    canvas = np.zeros((h, w), np.uint8)
    canvas[:] = int(np.clip(mean, 0, 255))
    # density 1 gives about 2x the FAST corners of a real EuRoC frame (V1_01), ORB its full
    # 2000 keypoints and ~1,300 rectified stereo matches per pair (real: ~815)
    n = int(w * h / 700 * density)
    smax = max(8.0, min(w, h) / 3)
    sizes = np.sort(_power_sizes(rng, n, 3.0, smax, 2.0))[::-1]  # large first, small on top
    xs = rng.random(n) * w
    ys = rng.random(n) * h
    vals = np.clip(rng.normal(mean, spread, n), 5, 250).astype(int)
    kinds = rng.integers(0, 10, n)
    angles = rng.random(n) * np.pi
    aspects = rng.uniform(0.25, 1.0, n)
    for i in range(n):
        x, y, s, v, k = float(xs[i]), float(ys[i]), float(sizes[i]), int(vals[i]), int(kinds[i])
        if k <= 3:  # axis-aligned rectangle
            a = aspects[i]
            cv2.rectangle(canvas, (int(x), int(y)), (int(x + s), int(y + s * a)), v, -1)
        elif k <= 5:  # rotated rectangle
            c, sn = np.cos(angles[i]) * s / 2, np.sin(angles[i]) * s / 2
            a = aspects[i]
            pts = np.array(
                [
                    [x + c - sn * a, y + sn + c * a],
                    [x - c - sn * a, y - sn + c * a],
                    [x - c + sn * a, y - sn - c * a],
                    [x + c + sn * a, y + sn - c * a],
                ],
                dtype=np.int32,
            )
            cv2.fillConvexPoly(canvas, pts, v)
        elif k <= 7:  # disc / ellipse
            cv2.ellipse(
                canvas,
                (int(x), int(y)),
                (max(1, int(s / 2)), max(1, int(s * aspects[i] / 2))),
                float(np.degrees(angles[i])),
                0,
                360,
                v,
                -1,
            )
        elif k == 8 and s > 6:  # text-like marks
            txt = "".join(rng.choice(list(_GLYPHS), size=int(rng.integers(2, 7))))
            scale = s / 30.0
            cv2.putText(
                canvas,
                txt,
                (int(x), int(y)),
                int(rng.integers(0, 8)),
                scale,
                v,
                max(1, int(scale * 2)),
                cv2.LINE_AA,
            )
        else:  # line / strip
            c, sn = np.cos(angles[i]) * s, np.sin(angles[i]) * s
            cv2.line(
                canvas,
                (int(x), int(y)),
                (int(x + c), int(y + sn)),
                v,
                max(1, int(s * aspects[i] / 6)),
                cv2.LINE_AA,
            )
    img = canvas.astype(np.float32) * (0.7 + 0.5 * low)
    img += rng.normal(0.0, 3.0, (h, w)).astype(np.float32)  # grain
    img = np.asarray(cv2.GaussianBlur(img, (0, 0), 0.6), dtype=np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def make_marker_texture(
    w: int, h: int, center: tuple[float, float], radius_texels: float
) -> np.ndarray:
    """Dark texture with a white disc at `center` (continuous texel coordinates: texel j covers
    [j, j + 1)), drawn 8x supersampled."""
    big = np.zeros((h * 8, w * 8), np.uint8)
    # big-pixel index coordinates of the centre, with 4 fractional bits
    c = (round((center[0] * 8 - 0.5) * 16), round((center[1] * 8 - 0.5) * 16))
    cv2.circle(big, c, round(radius_texels * 8 * 16), 255, -1, cv2.LINE_AA, shift=4)
    return np.maximum(
        np.full((h, w), 20, np.uint8), cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    )


# ---- layout ---------------------------------------------------------------------------------
def _aabb_distance(points: F64, lo: F64, hi: F64) -> F64:
    """Distance from each point (N, 3) to the box [lo, hi] (0 inside)."""
    d = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    return cast(F64, np.linalg.norm(d, axis=1))


def _place_obstacles(
    rng: np.random.Generator, path: F64, room_lo: F64, room_hi: F64, clearance: float
) -> tuple[list[F64], list[F64], list[str]]:
    area = float(np.prod(room_hi[:2] - room_lo[:2]))
    want = int(np.clip(area / 4.0, 4, 40))
    los: list[F64] = []
    his: list[F64] = []
    kinds: list[str] = []
    floor, ceil = room_lo[2], room_hi[2]
    for _ in range(want * 40):
        if len(los) >= want:
            break
        pillar = rng.random() < 0.3
        if pillar:
            size = np.array([*rng.uniform(0.2, 0.5, 2), 0.0])
        else:
            size = np.array([*rng.uniform(0.3, 1.2, 2), rng.uniform(0.3, 1.6)])
        # near the path (parallax) most of the time, anywhere otherwise
        if rng.random() < 0.7:
            anchor = path[rng.integers(0, path.shape[0]), :2]
            ang = rng.uniform(0, 2 * np.pi)
            c = anchor + rng.uniform(clearance + 0.5, clearance + 3.0) * np.array(
                [np.cos(ang), np.sin(ang)]
            )
        else:
            c = rng.uniform(room_lo[:2], room_hi[:2])
        lo = np.array([c[0] - size[0] / 2, c[1] - size[1] / 2, floor])
        hi = np.array([c[0] + size[0] / 2, c[1] + size[1] / 2, ceil if pillar else floor + size[2]])
        if np.any(lo[:2] < room_lo[:2] + 0.05) or np.any(hi[:2] > room_hi[:2] - 0.05):
            continue
        if np.min(_aabb_distance(path, lo, hi)) < clearance:
            continue
        if any(
            np.all(lo[:2] < h2[:2] + 0.1) and np.all(hi[:2] > l2[:2] - 0.1)
            for l2, h2 in zip(los, his, strict=False)
        ):
            continue
        los.append(lo)
        his.append(hi)
        kinds.append("pillar" if pillar else "box")
    return los, his, kinds


def build_world(
    path: F64,
    seed: int,
    *,
    floor_z: float | None = None,
    clearance: float = 0.6,
    marker: Marker | None = None,
    texels_per_m: float = TEXELS_PER_M,
) -> World:
    """A room enclosing `path` (N, 3 camera/body positions) with obstacles >= `clearance` m from
    every path point. Deterministic for a given path and seed."""
    rng = np.random.default_rng([seed, 0x00D])
    pmin, pmax = path.min(axis=0), path.max(axis=0)
    margin = rng.uniform(1.5, 3.0, size=4)
    fz = float(pmin[2] - 0.12) if floor_z is None else float(floor_z)
    room_lo = np.array([pmin[0] - margin[0], pmin[1] - margin[1], fz])
    room_hi = np.array([pmax[0] + margin[2], pmax[1] + margin[3], pmax[2] + rng.uniform(0.9, 1.6)])
    los, his, kinds = _place_obstacles(rng, path, room_lo, room_hi, clearance)
    if marker is not None:
        c = np.array(marker.center, dtype=np.float64)
        half = np.full(3, marker.size / 2)
        half[marker.axis] = 0.005
        shift = np.zeros(3)
        shift[marker.axis] = 0.005 if marker.side == 0 else -0.005
        los.append(c - half + shift)
        his.append(c + half + shift)
        kinds.append("marker")
    box_lo = np.array(los).reshape(-1, 3)
    box_hi = np.array(his).reshape(-1, 3)

    # faces: (axis, s-extent, t-extent, s-origin, t-origin, style)
    faces: list[tuple[int, float, float, float, float, str]] = []
    for b_lo, b_hi, style in [
        (room_lo, room_hi, "room"),
        *zip(box_lo, box_hi, kinds, strict=False),
    ]:
        for axis in range(3):
            sa, ta = ST_AXES[axis]
            for side in range(2):
                fstyle = style
                if style == "room":
                    fstyle = (
                        "floor"
                        if (axis == 2 and side == 0)
                        else ("ceiling" if axis == 2 else "wall")
                    )
                if style == "marker":
                    assert marker is not None
                    disc_side = marker.side
                    fstyle = "disc" if (axis == marker.axis and side == disc_side) else "plate"
                faces.append(
                    (axis, b_hi[sa] - b_lo[sa], b_hi[ta] - b_lo[ta], b_lo[sa], b_lo[ta], fstyle)
                )
    n = len(faces)
    face_axis = np.array([f[0] for f in faces], dtype=np.int64)
    org_s = np.array([f[3] for f in faces])
    org_t = np.array([f[4] for f in faces])
    tex_w = np.zeros(n, np.int64)
    tex_h = np.zeros(n, np.int64)
    k_s = np.zeros(n)
    k_t = np.zeros(n)
    textures: list[np.ndarray] = []
    palette = {
        "floor": (115.0, 55.0),
        "wall": (160.0, 60.0),
        "ceiling": (185.0, 45.0),
        "box": (140.0, 70.0),
        "pillar": (150.0, 65.0),
    }
    # one texel density for the whole world (the renderer relies on it): 5 mm, coarser only when
    # the largest face would exceed MAX_TEX texels
    largest = max(max(f[1], f[2]) for f in faces)
    k = min(texels_per_m, (MAX_TEX - ALIGN) / largest)
    for i, (_axis, es, et, _os, _ot, style) in enumerate(faces):
        # textures cover the face (rounded up to whole ALIGN blocks), never stretched
        w = int(np.ceil(es * k / ALIGN)) * ALIGN
        h = int(np.ceil(et * k / ALIGN)) * ALIGN
        tex_w[i], tex_h[i] = w, h
        k_s[i], k_t[i] = k, k
        if style == "disc" and marker is not None:
            textures.append(
                make_marker_texture(w, h, (es * k / 2, et * k / 2), marker.disc_radius * k)
            )
        elif style == "plate":
            textures.append(np.full((h, w), 20, np.uint8))
        else:
            m, sp = palette[style]
            m *= rng.uniform(0.85, 1.15)
            textures.append(make_texture(w, h, rng, mean=m, spread=sp))
    # each texture sits in a slot with a GUTTER-texel replicated border, so bilinear lookups at
    # any mip level never read a neighbour (no per-pixel clamping needed when rendering)
    slot_x, slot_y, aw, ah = _pack(tex_w + 2 * GUTTER, tex_h + 2 * GUTTER)
    off_x, off_y = slot_x + GUTTER, slot_y + GUTTER
    atlas = [np.zeros((ah >> lv, aw >> lv), np.uint8) for lv in range(MIP_LEVELS)]
    for i, tex in enumerate(textures):
        level = tex
        for lv in range(MIP_LEVELS):
            g = GUTTER >> lv
            y0, x0 = int(slot_y[i]) >> lv, int(slot_x[i]) >> lv
            padded = cv2.copyMakeBorder(level, g, g, g, g, cv2.BORDER_REPLICATE)
            atlas[lv][y0 : y0 + padded.shape[0], x0 : x0 + padded.shape[1]] = padded
            if lv + 1 < MIP_LEVELS:
                level = cv2.resize(
                    level,
                    (level.shape[1] // 2, level.shape[0] // 2),
                    interpolation=cv2.INTER_AREA,
                )
    return World(
        room_lo=room_lo,
        room_hi=room_hi,
        box_lo=box_lo,
        box_hi=box_hi,
        kinds=list(kinds),
        face_axis=face_axis,
        org_s=org_s,
        org_t=org_t,
        k_s=k_s,
        k_t=k_t,
        tex_w=tex_w,
        tex_h=tex_h,
        off_x=off_x,
        off_y=off_y,
        atlas=atlas,
        texels_per_m=float(k),
    )


def _pack(w: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Shelf packing of rectangles (multiples of ALIGN) into an atlas ATLAS_WIDTH wide."""
    order = np.argsort(-h, kind="stable")
    ox = np.zeros_like(w)
    oy = np.zeros_like(h)
    x = y = shelf = 0
    width = max(ATLAS_WIDTH, int(w.max()))
    for i in order:
        if x + w[i] > width:
            y += shelf
            x = shelf = 0
        ox[i], oy[i] = x, y
        x += int(w[i])
        shelf = max(shelf, int(h[i]))
    height = y + shelf
    if height > 32000:
        raise ValueError(f"texture atlas too large ({width} x {height}); lower texels_per_m")
    return ox, oy, width, height
