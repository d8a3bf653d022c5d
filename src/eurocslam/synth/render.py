"""Vectorised stereo renderer: exact ray casting through the rig's camera model (the real
pinhole + radial-tangential of EuRoC, or a fisheye: every pixel's own ray, never a warped
pinhole image) into the axis-aligned world of `world.py`.

Per camera, once: every output pixel's ray (inverse distortion solved to 1e-9 px by Newton
iterations, checked against `cv2.projectPoints`; other models: `CameraCalib.model.unproject`,
checked against its `project`), the solid angle a pixel covers (for mip selection) and the
vignetting map. Per frame: rotate the rays into the world, intersect the room
analytically (3 slabs), then each obstacle only over the pixels its projection can cover (a
bounding box found through the distortion model; for a fisheye, which sees behind its image plane,
the box's bounding cone projected by the model), keep the nearest hit (exact occlusion), and look
the texture up with trilinear mip-mapping (`cv2.remap` on per-level atlases) so distant surfaces do
not alias. Optional: z-depth per pixel (for tests), sensor noise, vignetting, exposure gain and
motion blur (average of sub-frame renders across the exposure).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from eurocslam.dataset.calib import CameraCalib
from eurocslam.geometry import F64
from eurocslam.synth.world import MIP_LEVELS, ST_AXES, World

F32 = np.float32
NEAR = 0.02


def distort(cam: CameraCalib, x: F64, y: F64) -> tuple[F64, F64]:
    """Normalised image coordinates -> pixel coordinates (radial-tangential, OpenCV order)."""
    k1, k2, p1, p2 = (list(cam.distortion) + [0.0] * 4)[:4]
    k3 = cam.distortion[4] if len(cam.distortion) > 4 else 0.0
    r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return cam.fx * xd + cam.cx, cam.fy * yd + cam.cy


def undistort_pixels(cam: CameraCalib, u: F64, v: F64, iters: int = 20) -> tuple[F64, F64]:
    """Pixel -> normalised coordinates, Newton on the distortion model (numeric Jacobian)."""
    pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2).astype(np.float64)
    n: F64 = np.asarray(cv2.undistortPoints(pts, cam.K, cam.D), dtype=np.float64).reshape(-1, 2)
    x, y = n[:, 0].copy(), n[:, 1].copy()
    uu, vv = u.ravel().astype(np.float64), v.ravel().astype(np.float64)
    h = 1e-7
    for _ in range(iters):
        pu, pv = distort(cam, x, y)
        eu, ev = pu - uu, pv - vv
        if max(np.abs(eu).max(), np.abs(ev).max()) < 1e-10:
            break
        ax, ay = distort(cam, x + h, y)
        bx, by = distort(cam, x, y + h)
        j11, j21 = (ax - pu) / h, (ay - pv) / h
        j12, j22 = (bx - pu) / h, (by - pv) / h
        det = j11 * j22 - j12 * j21
        x -= (j22 * eu - j12 * ev) / det
        y -= (-j21 * eu + j11 * ev) / det
    return x.reshape(u.shape), y.reshape(u.shape)


@dataclass
class CameraModel:
    """Per-camera precomputation for rendering."""

    calib: CameraCalib
    rays: np.ndarray  # (3, H, W) float32 unit rays in the camera frame
    pix_ang: np.ndarray  # (H, W) float32, angular size of a pixel [rad]
    vignette: np.ndarray  # (H, W) float32 in (0, 1]
    xn_bounds: tuple[float, float, float, float]  # x min, x max, y min, y max (normalised)
    monotone: bool  # distortion is one-to-one over the image: projected bboxes are valid
    # pixels with a ray (None: all of them); a fisheye's pixels beyond its model's valid region
    # are rendered black
    valid: np.ndarray | None = None

    @classmethod
    def build(cls, cam: CameraCalib, vignette_strength: float = 0.35) -> CameraModel:
        if not cam.model.perspective:
            return cls._build_by_model(cam, vignette_strength)
        H, W = cam.height, cam.width
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        x, y = undistort_pixels(cam, u, v)
        pu, pv = distort(cam, x, y)
        err = max(np.abs(pu - u).max(), np.abs(pv - v).max())
        if not err < 1e-6:
            raise ValueError(f"{cam.name}: inverse distortion did not converge ({err:.2e} px)")
        r = np.stack([x, y, np.ones_like(x)])
        r /= np.linalg.norm(r, axis=0, keepdims=True)
        # pixel angular size: geometric mean of the ray steps along u and v
        du = np.linalg.norm(np.gradient(r, axis=2), axis=0)
        dv = np.linalg.norm(np.gradient(r, axis=1), axis=0)
        pix_ang = np.sqrt(du * dv)
        # the distortion is one-to-one if its Jacobian keeps its sign over (a margin around)
        # the image's normalised footprint
        x0, x1, y0, y1 = float(x.min()), float(x.max()), float(y.min()), float(y.max())
        gx, gy = np.meshgrid(
            np.linspace(x0 * 1.1, x1 * 1.1, 80), np.linspace(y0 * 1.1, y1 * 1.1, 60)
        )
        h = 1e-6
        au, av = distort(cam, gx, gy)
        bu, bv = distort(cam, gx + h, gy)
        cu, cv_ = distort(cam, gx, gy + h)
        det = (bu - au) * (cv_ - av) - (cu - au) * (bv - av)
        monotone = bool(np.all(det > 0))
        rho = np.hypot((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy)
        rho /= rho.max()
        vig = 1.0 - vignette_strength * rho**2
        return cls(
            calib=cam,
            rays=r.astype(F32),
            pix_ang=pix_ang.astype(F32),
            vignette=vig.astype(F32),
            xn_bounds=(x0, x1, y0, y1),
            monotone=monotone,
        )

    @classmethod
    def _build_by_model(cls, cam: CameraCalib, vignette_strength: float) -> CameraModel:
        """Rays of every pixel through `cam.model` (a fisheye: rays beyond 90 degrees too)."""
        H, W = cam.height, cam.width
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        uv = np.column_stack([u.ravel(), v.ravel()])
        b = cam.model.unproject(uv)
        valid = np.isfinite(b).all(axis=1)
        back = cam.model.project(b[valid])
        err = float(np.abs(back - uv[valid]).max(initial=0.0))
        if not err < 1e-6:
            raise ValueError(f"{cam.name}: the model's unprojection is off by {err:.2e} px")
        b[~valid] = [0.0, 0.0, 1.0]
        r = b.T.reshape(3, H, W)
        du = np.linalg.norm(np.gradient(r, axis=2), axis=0)
        dv = np.linalg.norm(np.gradient(r, axis=1), axis=0)
        rho = np.hypot((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy)
        rho /= rho.max()
        mask = valid.reshape(H, W)
        return cls(
            calib=cam,
            rays=r.astype(F32),
            pix_ang=np.sqrt(du * dv).astype(F32),
            vignette=(1.0 - vignette_strength * rho**2).astype(F32),
            xn_bounds=(-np.inf, np.inf, -np.inf, np.inf),
            monotone=False,
            valid=None if mask.all() else mask,
        )

    def pixel_bbox(self, R_cw: F64, o_w: F64, lo: F64, hi: F64) -> tuple[int, int, int, int] | None:
        """Pixel rows/cols (r0, r1, c0, c1) that can see the box [lo, hi]; None if none can."""
        cam = self.calib
        if not cam.model.perspective:
            return self._cone_bbox(R_cw, o_w, lo, hi)
        corners = np.array(
            [
                [lo[0] if i & 1 else hi[0], lo[1] if i & 2 else hi[1], lo[2] if i & 4 else hi[2]]
                for i in range(8)
            ]
        )
        pc = (corners - o_w) @ R_cw.T
        z = pc[:, 2]
        if np.all(z < NEAR):
            return None
        pts = [pc[z >= NEAR]]
        if np.any(z < NEAR):  # clip the box's edges against the near plane
            for i in range(8):
                for b in (1, 2, 4):
                    j = i ^ b
                    if j > i and (z[i] < NEAR) != (z[j] < NEAR):
                        s = (NEAR - z[i]) / (z[j] - z[i])
                        pts.append((pc[i] + s * (pc[j] - pc[i]))[None])
        q = np.concatenate(pts)
        xn, yn = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
        bx0, bx1, by0, by1 = self.xn_bounds
        x0, x1 = max(xn.min(), bx0), min(xn.max(), bx1)
        y0, y1 = max(yn.min(), by0), min(yn.max(), by1)
        if x0 > x1 or y0 > y1:
            return None
        H, W = cam.height, cam.width
        if not self.monotone:
            return 0, H, 0, W
        s = np.linspace(0.0, 1.0, 24)
        ex = np.concatenate(
            [x0 + (x1 - x0) * s, np.full(24, x1), x1 - (x1 - x0) * s, np.full(24, x0)]
        )
        ey = np.concatenate(
            [np.full(24, y0), y0 + (y1 - y0) * s, np.full(24, y1), y1 - (y1 - y0) * s]
        )
        pu, pv = distort(cam, ex, ey)
        c0, c1 = int(np.floor(pu.min())) - 2, int(np.ceil(pu.max())) + 3
        r0, r1 = int(np.floor(pv.min())) - 2, int(np.ceil(pv.max())) + 3
        c0, c1, r0, r1 = max(c0, 0), min(c1, W), max(r0, 0), min(r1, H)
        if c0 >= c1 or r0 >= r1:
            return None
        return r0, r1, c0, c1

    def _cone_bbox(self, R_cw: F64, o_w: F64, lo: F64, hi: F64) -> tuple[int, int, int, int] | None:
        """A fisheye's pixels that can see the box: the box's bounding sphere seen as a cone of
        rays; the model maps that cap of the unit sphere one to one onto a region of the image
        bounded by the projection of its rim, so the rim's pixel bounding box (64 rays, a 3 px
        margin for the curve between them) holds every pixel of the box."""
        cam = self.calib
        H, W = cam.height, cam.width
        centre = 0.5 * (np.asarray(lo) + np.asarray(hi))
        radius = 0.5 * float(np.linalg.norm(np.asarray(hi) - np.asarray(lo)))
        d = R_cw @ (centre - o_w)
        dist = float(np.linalg.norm(d))
        if dist <= radius + NEAR:
            return 0, H, 0, W
        axis = d / dist
        half = float(np.arcsin(radius / dist))
        off_axis = float(np.arccos(np.clip(axis[2], -1.0, 1.0)))
        if off_axis + half >= cam.model.max_angle:
            return 0, H, 0, W  # the cone reaches where the model ends: no bound from its rim
        e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        phi = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
        rim = np.cos(half) * axis + np.sin(half) * (
            np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
        )
        uv = cam.model.project(rim)
        if not np.isfinite(uv).all():
            return 0, H, 0, W
        c0, c1 = int(np.floor(uv[:, 0].min())) - 3, int(np.ceil(uv[:, 0].max())) + 4
        r0, r1 = int(np.floor(uv[:, 1].min())) - 3, int(np.ceil(uv[:, 1].max())) + 4
        c0, c1, r0, r1 = max(c0, 0), min(c1, W), max(r0, 0), min(r1, H)
        if c0 >= c1 or r0 >= r1:
            return None
        return r0, r1, c0, c1


_MODEL_CACHE: dict[tuple[object, ...], CameraModel] = {}


def camera_model(cam: CameraCalib) -> CameraModel:
    """`CameraModel.build`, cached per intrinsics (the inverse distortion map takes ~0.4 s)."""
    key = (
        cam.width,
        cam.height,
        cam.fx,
        cam.fy,
        cam.cx,
        cam.cy,
        tuple(cam.distortion),
        cam.distortion_model,
    )
    model = _MODEL_CACHE.get(key)
    if model is None:
        if len(_MODEL_CACHE) > 8:
            _MODEL_CACHE.clear()
        model = _MODEL_CACHE[key] = CameraModel.build(cam)
    # the extrinsics are not part of the model; keep the caller's calibration object
    return model if model.calib is cam else replace(model, calib=cam)


@dataclass(frozen=True)
class RenderOutput:
    radiance: np.ndarray  # (H, W) float32, 0..255 scale, before sensor effects
    depth: np.ndarray | None  # (H, W) float32 z-depth in the camera frame [m]
    face: np.ndarray | None  # (H, W) int32 face id hit by each pixel


class _Hits:
    """Nearest hit so far per pixel: distance, atlas coordinates (level-0 texel centres),
    incidence-stretched distance (for the mip level), face id (only when asked)."""

    def __init__(
        self,
        t: np.ndarray,
        X: np.ndarray,
        Y: np.ndarray,
        foot: np.ndarray,
        fid: np.ndarray | None,
    ) -> None:
        self.t, self.X, self.Y, self.foot, self.fid = t, X, Y, foot, fid


def _face_xy(
    world: World, f: int, o: F64, t: np.ndarray, dk: np.ndarray, axis: int
) -> tuple[np.ndarray, np.ndarray]:
    """Atlas coordinates of hits at distance t on face f: (o + t d - org) k + off - 0.5."""
    sa, ta = ST_AXES[axis]
    k = world.texels_per_m
    # rays that miss the face carry t = inf; inf * 0 for rays parallel to an axis gives NaN
    # coordinates that the nearest-hit selection discards: no warning for them
    with np.errstate(invalid="ignore"):
        X = t * dk[sa]
        X += F32((o[sa] - world.org_s[f]) * k + world.off_x[f] - 0.5)
        Y = t * dk[ta]
        Y += F32((o[ta] - world.org_t[f]) * k + world.off_y[f] - 0.5)
    return X, Y


def cast_and_shade(
    world: World, model: CameraModel, T_world_cam: F64, *, want_depth: bool = False
) -> RenderOutput:
    """Render one camera view (no sensor effects)."""
    R_wc = np.asarray(T_world_cam[:3, :3], dtype=np.float64)
    o = np.asarray(T_world_cam[:3, 3], dtype=np.float64)
    H, W = model.calib.height, model.calib.width
    # einsum: single-threaded and faster than BLAS for a 3x3 times 3xN product
    d = np.einsum("ij,jn->in", R_wc.astype(F32), model.rays.reshape(3, -1)).reshape(3, H, W)
    dk = d * F32(world.texels_per_m)
    with np.errstate(divide="ignore"):
        # +-inf where a ray is parallel to an axis: the slab tests below stay correct (the
        # camera is never exactly on a face plane)
        inv = F32(1.0) / d
    # incidence stretch per axis: 1 / sqrt(cos(angle to the face normal)), the geometric mean of
    # the along/across footprint stretch (mip selection)
    g = np.abs(d)
    np.maximum(g, F32(0.02), out=g)
    np.sqrt(g, out=g)
    np.divide(F32(1.0), g, out=g)
    # room, seen from inside: per axis the wall the ray heads for; faces differ per side only
    # by their atlas offset, so one pass per axis serves both sides
    hits: _Hits | None = None
    for a in range(3):
        lo_f, hi_f = 2 * a, 2 * a + 1
        ta = np.maximum(
            F32(world.room_hi[a] - o[a]) * inv[a], F32(world.room_lo[a] - o[a]) * inv[a]
        )
        pos = d[a] > 0
        X, Y = _face_xy(world, lo_f, o, ta, dk, a)
        dx = F32(world.off_x[hi_f] - world.off_x[lo_f])
        dy = F32(world.off_y[hi_f] - world.off_y[lo_f])
        if dx:
            X += pos * dx
        if dy:
            Y += pos * dy
        foot = ta * g[a]
        fid = (lo_f + pos).astype(np.int32) if want_depth else None
        if hits is None:
            hits = _Hits(ta, X, Y, foot, fid)
            continue
        closer = ta < hits.t
        np.copyto(hits.t, ta, where=closer)
        np.copyto(hits.X, X, where=closer)
        np.copyto(hits.Y, Y, where=closer)
        np.copyto(hits.foot, foot, where=closer)
        if fid is not None and hits.fid is not None:
            np.copyto(hits.fid, fid, where=closer)
    assert hits is not None
    # obstacles: slab test over the pixels their projection can cover
    R_cw = R_wc.T
    for b in range(world.box_lo.shape[0]):
        lo, hi = world.box_lo[b], world.box_hi[b]
        bb = model.pixel_bbox(R_cw, o, lo, hi)
        if bb is None:
            continue
        r0, r1, c0, c1 = bb
        ii = inv[:, r0:r1, c0:c1]
        tn = tf = ax = None
        for a in range(3):
            t1 = F32(lo[a] - o[a]) * ii[a]
            t2 = F32(hi[a] - o[a]) * ii[a]
            tmin = np.minimum(t1, t2)
            tmax = np.maximum(t1, t2)
            if tn is None:
                tn, tf, ax = tmin, tmax, np.zeros(tmin.shape, np.int8)
            else:
                assert tf is not None and ax is not None
                np.copyto(ax, a, where=tmin > tn)
                tn = np.maximum(tn, tmin)
                tf = np.minimum(tf, tmax)
        assert tn is not None and tf is not None and ax is not None
        tsub = hits.t[r0:r1, c0:c1]
        hit = (tn <= tf) & (tn > 0) & (tn < tsub)
        if not hit.any():
            continue
        dd = d[:, r0:r1, c0:c1]
        dks = dk[:, r0:r1, c0:c1]
        for a in range(3):
            m = hit & (ax == a)
            if not m.any():
                continue
            # entering through the lower face when moving along +axis
            neg = dd[a] < 0
            lo_f = 6 + 6 * b + 2 * a
            X, Y = _face_xy(world, lo_f, o, tn, dks, a)
            X += neg * F32(world.off_x[lo_f + 1] - world.off_x[lo_f])
            Y += neg * F32(world.off_y[lo_f + 1] - world.off_y[lo_f])
            np.copyto(hits.X[r0:r1, c0:c1], X, where=m)
            np.copyto(hits.Y[r0:r1, c0:c1], Y, where=m)
            np.copyto(hits.foot[r0:r1, c0:c1], tn * g[a, r0:r1, c0:c1], where=m)
            if hits.fid is not None:
                np.copyto(hits.fid[r0:r1, c0:c1], (lo_f + neg).astype(np.int32), where=m)
        np.copyto(tsub, tn, where=hit)
    # footprint in texels per pixel = distance * pixel angle * texel density * stretch
    hits.foot *= model.pix_ang
    hits.foot *= F32(world.texels_per_m)
    out = _sample_trilinear(world, hits.X, hits.Y, hits.foot)
    if model.valid is not None:  # a fisheye's pixels without a ray
        out[~model.valid] = 0.0
    depth = (hits.t * model.rays[2]) if want_depth else None
    return RenderOutput(out, depth, hits.fid)


def _remap_subset(atlas: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookups at arbitrary (x, y); remap wants 2D maps < 32767 per side, so the
    samples are laid out in rows of 1024."""
    n = x.shape[0]
    pad = (-n) % 1024
    if pad:
        x = np.concatenate([x, np.zeros(pad, F32)])
        y = np.concatenate([y, np.zeros(pad, F32)])
    out = cv2.remap(atlas, x.reshape(-1, 1024), y.reshape(-1, 1024), cv2.INTER_LINEAR)
    return out.reshape(-1)[:n]


def _sample_trilinear(world: World, X: np.ndarray, Y: np.ndarray, foot: np.ndarray) -> np.ndarray:
    """Trilinear mip-mapped lookup at level log2(footprint), blended between its two
    neighbours. X, Y are level-0 atlas coordinates of texel centres (remap convention).

    Levels that many pixels use are remapped over the whole frame (one vectorised call, reused
    by the neighbouring level); rare levels only over their pixels."""
    n = foot.size
    lvl = np.log2(np.maximum(foot, F32(1.0)))
    np.minimum(lvl, F32(MIP_LEVELS - 1 - 1e-3), out=lvl)
    l0 = lvl.astype(np.int8)
    counts = np.bincount(l0.reshape(-1), minlength=MIP_LEVELS)
    full: dict[int, np.ndarray] = {}

    def whole(lv: int) -> np.ndarray:
        if lv not in full:
            s0 = F32(1.0 / (1 << lv))
            c0 = F32(0.5 / (1 << lv) - 0.5)
            xs, ys = (X, Y) if lv == 0 else (X * s0 + c0, Y * s0 + c0)
            full[lv] = cv2.remap(world.atlas[lv], xs, ys, cv2.INTER_LINEAR).astype(F32)
        return full[lv]

    out = np.empty(X.shape, F32)
    flat_out = out.reshape(-1)
    for lv in range(MIP_LEVELS - 1):
        cnt = int(counts[lv])
        if cnt == 0:
            continue
        if cnt > n // 5:
            a, b = whole(lv), whole(lv + 1)
            blend = a + (lvl - F32(lv)) * (b - a)
            if cnt == n:
                return blend  # type: ignore[no-any-return]
            np.copyto(out, blend, where=l0 == lv)
            continue
        sel = np.flatnonzero(l0.reshape(-1) == lv)
        xs, ys = X.reshape(-1)[sel], Y.reshape(-1)[sel]
        fr = lvl.reshape(-1)[sel] - F32(lv)
        s0 = F32(1.0 / (1 << lv))
        c0 = F32(0.5 / (1 << lv) - 0.5)
        s1, c1 = F32(0.5) * s0, F32(0.25 / (1 << lv) - 0.5)
        a = _remap_subset(world.atlas[lv], xs * s0 + c0, ys * s0 + c0).astype(F32)
        b = _remap_subset(world.atlas[lv + 1], xs * s1 + c1, ys * s1 + c1).astype(F32)
        a += fr * (b - a)
        flat_out[sel] = a
    return out
