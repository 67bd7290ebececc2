"""Vectorised renderer of the procedural tree: per-primitive screen-space rasterisation with a z-buffer.

For each view, every primitive's 3D bounding box is projected to a pixel rectangle; all (primitive, pixel)
pairs inside those rectangles are enumerated at once (``repeat_interleave``), the exact ray/primitive
intersection is computed for each pair, and a z-buffer (``scatter_reduce`` amin on a packed depth+index key)
keeps the nearest surface per pixel. The ground plane z = 0 and the sky fill the rest. Shading: Lambertian sun
+ ambient, a crown-depth darkening, and procedural value-noise textures anchored to the world (multi-view
consistent). Runs on CPU or CUDA (torch), float32; deterministic on a given device.
"""

from __future__ import annotations

import contextlib
from typing import Iterator, NamedTuple

import numpy as np
import torch

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.geometry import T_OPENGL_OPTICAL
from fruitnerfpp_ros.core.synthetic.scene import Scene

__all__ = ['ViewRender', 'Renderer', 'value_noise']

_NEAR = 1e-3
_DEPTH_SCALE = float(2 ** 16)   # depth quantisation of the z-buffer key (1/65536 m)
_INDEX_BITS = 24
_INDEX_MASK = (1 << _INDEX_BITS) - 1
_MAX_PAIRS = 1 << 21            # (primitive, pixel) pairs per chunk
_SUN = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])


class ViewRender(NamedTuple):
    """One rendered view.

    Attributes:
        rgb: [H, W, 3] uint8.
        instance: [H, W] uint16 fruit ids (0 = background).
        depth: [H, W] float32 depth along the optical axis, metres (inf = sky).
    """

    rgb: np.ndarray
    instance: np.ndarray
    depth: np.ndarray


def _hash(ix: torch.Tensor, seed: int) -> torch.Tensor:
    """Integer hash of int64 lattice coordinates [..., D] to floats in [0, 1) (identical on CPU and CUDA)."""
    primes = (73856093, 19349663, 83492791)
    h = torch.full(ix.shape[:-1], seed * 2654435761 % (1 << 32), dtype=torch.int64, device=ix.device)
    for k in range(ix.shape[-1]):
        h = (h ^ ((ix[..., k] * primes[k]) & 0xFFFFFFFF)) & 0xFFFFFFFF
        h = ((h ^ (h >> 15)) * 0x2C1B3C6D) & 0xFFFFFFFF
        h = ((h ^ (h >> 12)) * 0x297A2D39) & 0xFFFFFFFF
        h = h ^ (h >> 15)
    return (h & 0xFFFFFF).to(torch.float32) / float(1 << 24)


def value_noise(x: torch.Tensor, seed: int = 0, octaves: int = 1) -> torch.Tensor:
    """Smooth value noise in [0, 1] at points ``x`` [P, D] (D = 2 or 3), summed over ``octaves`` (fBm)."""
    total = torch.zeros(x.shape[0], dtype=torch.float32, device=x.device)
    weight_sum = 0.0
    for octave in range(octaves):
        p = x * (2.0 ** octave)
        base = torch.floor(p)
        f = p - base
        f = f * f * (3.0 - 2.0 * f)
        ib = base.to(torch.int64)
        value = torch.zeros_like(total)
        d = x.shape[1]
        for corner in range(1 << d):
            offset = torch.tensor([(corner >> k) & 1 for k in range(d)], device=x.device)
            w = torch.prod(torch.where(offset.bool(), f, 1.0 - f), dim=1)
            value = value + w * _hash(ib + offset, seed + octave)
        amp = 0.5 ** octave
        total = total + amp * value
        weight_sum += amp
    return total / weight_sum


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[N, 8, 3] corners of the axis-aligned boxes [lo, hi] ([N, 3] each)."""
    box = np.stack([lo, hi], axis=1)
    return np.stack([np.stack([box[:, k & 1, 0], box[:, (k >> 1) & 1, 1], box[:, (k >> 2) & 1, 2]], axis=1)
                     for k in range(8)], axis=1)


class _Rays(NamedTuple):
    origin: torch.Tensor   # [3]
    dirs: torch.Tensor     # [P, 3], optical z component scaled to 1 (t = optical depth)


class Renderer:
    """Renders views of one :class:`Scene` on a torch device.

    Args:
        scene: the procedural tree.
        device: torch device (``resolve_device`` it first).
    """

    def __init__(self, scene: Scene, device: torch.device) -> None:
        self.scene = scene
        self.device = device

        def t(a: np.ndarray, dtype: torch.dtype = torch.float32) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)

        e, lv, c = scene.ellipsoids, scene.leaves, scene.cylinders
        self.e_center, self.e_rot, self.e_radii = t(e.center), t(e.rotation), t(e.radii)
        self.e_albedo, self.e_blush, self.e_amount = t(e.albedo), t(e.blush), t(e.blush_amount)
        self.e_instance = t(e.instance, torch.int64)
        self.l_center, self.l_u, self.l_v, self.l_n = t(lv.center), t(lv.axis_u), t(lv.axis_v), t(lv.normal)
        self.l_half, self.l_albedo = t(lv.half_size), t(lv.albedo)
        u_a, v_b = lv.axis_u / lv.half_size[:, :1], lv.axis_v / lv.half_size[:, 1:]
        self.l_plane = t(np.concatenate([lv.normal, np.sum(lv.normal * lv.center, 1, keepdims=True),
                                         u_a, np.sum(u_a * lv.center, 1, keepdims=True),
                                         v_b, np.sum(v_b * lv.center, 1, keepdims=True)], axis=1).reshape(-1, 12))
        self.c_p0, self.c_p1, self.c_r, self.c_albedo = t(c.p0), t(c.p1), t(c.radius), t(c.albedo)
        self.n_e, self.n_l, self.n_c = len(e.center), len(lv.center), len(c.p0)
        self.ground_index = self.n_e + self.n_l + self.n_c
        self.sky_index = self.ground_index + 1
        if self.sky_index > _INDEX_MASK:
            raise ValueError('too many primitives for the z-buffer key')
        # Points whose convex hull holds each primitive [N, C, 3] (float64), projected to find its pixels:
        # corners of the axis-aligned box (ellipsoids, cylinders), corners of the leaf's own rectangle (leaves).
        half_e = np.sqrt(np.einsum('nij,nj->ni', e.rotation ** 2, e.radii ** 2))
        r_c = c.radius[:, None]
        lu, lv_ = lv.axis_u * lv.half_size[:, :1], lv.axis_v * lv.half_size[:, 1:]
        self.hulls = [
            _box_corners(e.center - half_e, e.center + half_e),
            np.stack([lv.center + su * lu + sv * lv_ for su in (-1, 1) for sv in (-1, 1)], axis=1),
            _box_corners(np.minimum(c.p0, c.p1) - r_c, np.maximum(c.p0, c.p1) + r_c),
        ]
        self.offsets = [0, self.n_e, self.n_e + self.n_l]
        self.crown_center = t(scene.crown_center)
        self.crown_radii = t(scene.crown_radii)
        self.sun = t(_SUN)

    # ------------------------------------------------------------------ intersections (pairs of ray, primitive)
    def _hit_ellipsoid(self, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        R, r = self.e_rot[idx], self.e_radii[idx]
        ol = torch.einsum('pji,pj->pi', R, o - self.e_center[idx]) / r
        dl = torch.einsum('pji,pj->pi', R, d) / r
        a = (dl * dl).sum(1)
        b = (ol * dl).sum(1)
        c = (ol * ol).sum(1) - 1.0
        disc = b * b - a * c
        t = (-b - torch.sqrt(torch.clamp(disc, min=0.0))) / a
        return torch.where((disc >= 0) & (t > _NEAR), t, torch.inf)

    def _hit_leaf(self, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        # One gather of the packed leaf plane [n, n.c, u/a, u.c/a, v/b, v.c/b] (12 floats per leaf).
        q = self.l_plane[idx]
        n = q[:, 0:3]
        denom = (d * n).sum(1)
        t = (q[:, 3] - (o * n).sum(-1)) / torch.where(denom.abs() < 1e-12, torch.full_like(denom, 1e-12), denom)
        p = o + t[:, None] * d
        x = (p * q[:, 4:7]).sum(1) - q[:, 7]
        y = (p * q[:, 8:11]).sum(1) - q[:, 11]
        inside = (x.abs() <= 1.0) & (y.abs() <= 1.0 - x * x)
        return torch.where(inside & (t > _NEAR), t, torch.inf)

    def _hit_cylinder(self, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        p0, p1, r = self.c_p0[idx], self.c_p1[idx], self.c_r[idx]
        axis = p1 - p0
        length = torch.linalg.norm(axis, dim=1)
        axis = axis / length[:, None]
        oc = o - p0
        d_perp = d - (d * axis).sum(1, keepdim=True) * axis
        oc_perp = oc - (oc * axis).sum(1, keepdim=True) * axis
        a = (d_perp * d_perp).sum(1)
        b = (d_perp * oc_perp).sum(1)
        c = (oc_perp * oc_perp).sum(1) - r * r
        disc = b * b - a * c
        t = (-b - torch.sqrt(torch.clamp(disc, min=0.0))) / torch.clamp(a, min=1e-20)
        s = ((oc + t[:, None] * d) * axis).sum(1)
        ok = (disc >= 0) & (a > 1e-20) & (t > _NEAR) & (s >= 0) & (s <= length)
        return torch.where(ok, t, torch.inf)

    def _hit(self, kind: int, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return (self._hit_ellipsoid, self._hit_leaf, self._hit_cylinder)[kind](o, d, idx)

    # ------------------------------------------------------------------ rays
    def _pixel_rays(self, T_world_camera: np.ndarray, K: CameraIntrinsics) -> tuple[_Rays, np.ndarray]:
        T_world_optical = np.asarray(T_world_camera, dtype=np.float64) @ T_OPENGL_OPTICAL
        R = torch.as_tensor(T_world_optical[:3, :3], dtype=torch.float32, device=self.device)
        origin = torch.as_tensor(T_world_optical[:3, 3], dtype=torch.float32, device=self.device)
        v, u = torch.meshgrid(torch.arange(K.h, device=self.device, dtype=torch.float32),
                              torch.arange(K.w, device=self.device, dtype=torch.float32), indexing='ij')
        d_opt = torch.stack([(u.reshape(-1) + 0.5 - K.cx) / K.fl_x, (v.reshape(-1) + 0.5 - K.cy) / K.fl_y,
                             torch.ones(K.w * K.h, device=self.device)], dim=1)
        return _Rays(origin, d_opt @ R.T), T_world_optical

    def _pixel_boxes(self, kind: int, T_world_optical: np.ndarray, K: CameraIntrinsics) -> np.ndarray:
        """[N, 4] inclusive pixel rectangles (x0, y0, x1, y1) holding primitive ``kind``'s projection."""
        corners = self.hulls[kind]
        if len(corners) == 0:
            return np.zeros((0, 4), dtype=np.int64)
        T_opt_world = np.linalg.inv(T_world_optical)
        p = corners @ T_opt_world[:3, :3].T + T_opt_world[:3, 3]
        z = p[..., 2]
        in_front = z > _NEAR
        zc = np.where(in_front, z, 1.0)
        u = K.fl_x * p[..., 0] / zc + K.cx
        v = K.fl_y * p[..., 1] / zc + K.cy
        rect = np.stack([np.ceil(u.min(1) - 0.5 - 1e-3), np.ceil(v.min(1) - 0.5 - 1e-3),
                         np.floor(u.max(1) - 0.5 + 1e-3), np.floor(v.max(1) - 0.5 + 1e-3)], axis=1)
        partial = ~in_front.all(1) & in_front.any(1)
        rect[partial] = [0, 0, K.w - 1, K.h - 1]
        rect[~in_front.any(1)] = [1, 1, 0, 0]  # empty
        rect[:, [0, 2]] = np.clip(rect[:, [0, 2]], -1, K.w)
        rect[:, [1, 3]] = np.clip(rect[:, [1, 3]], -1, K.h)
        rect[:, 0] = np.maximum(rect[:, 0], 0)
        rect[:, 1] = np.maximum(rect[:, 1], 0)
        rect[:, 2] = np.minimum(rect[:, 2], K.w - 1)
        rect[:, 3] = np.minimum(rect[:, 3], K.h - 1)
        return rect.astype(np.int64)

    # ------------------------------------------------------------------ rendering
    def render(self, T_world_camera: np.ndarray, K: CameraIntrinsics) -> ViewRender:
        """Render one view: camera-to-world pose (OpenGL axes, 4x4) and intrinsics (top-left-corner cx, cy)."""
        with self._one_cpu_thread(), torch.no_grad():
            return self._render(T_world_camera, K)

    @contextlib.contextmanager
    def _one_cpu_thread(self) -> Iterator[None]:
        """On the CPU, render with one torch thread: intra-op threading of these per-view tensors costs more
        than it gains, and on a busy machine (other jobs, CI) it is up to 10x slower. Restores the thread count
        afterwards."""
        threads = torch.get_num_threads()
        if self.device.type == 'cpu':
            torch.set_num_threads(1)
        try:
            yield
        finally:
            torch.set_num_threads(threads)

    def _render(self, T_world_camera: np.ndarray, K: CameraIntrinsics) -> ViewRender:
        rays, T_world_optical = self._pixel_rays(T_world_camera, K)
        o, dirs = rays
        n_pix = K.w * K.h
        # Ground plane (z = 0) and sky initialise the z-buffer.
        t_ground = torch.where(dirs[:, 2] < -1e-9, -o[2] / torch.clamp(dirs[:, 2], max=-1e-9), torch.inf)
        sky_key = torch.iinfo(torch.int64).max
        keys = torch.where(torch.isfinite(t_ground),
                           (t_ground * _DEPTH_SCALE).to(torch.int64) * (1 << _INDEX_BITS) + self.ground_index,
                           torch.full_like(t_ground, 0, dtype=torch.int64) + sky_key)
        for kind in range(3):
            rect = self._pixel_boxes(kind, T_world_optical, K)
            w = np.maximum(rect[:, 2] - rect[:, 0] + 1, 0)
            h = np.maximum(rect[:, 3] - rect[:, 1] + 1, 0)
            area = w * h
            live = np.flatnonzero(area > 0)
            if len(live) == 0:
                continue
            cum = np.cumsum(area[live])
            start = 0
            while start < len(live):
                base = cum[start - 1] if start else 0
                stop = max(start + 1, int(np.searchsorted(cum, base + _MAX_PAIRS, side='right')))
                sel = live[start:stop]
                self._rasterise_chunk(kind, sel, rect[sel], area[sel], w[sel], rays, K.w, keys)
                start = stop
        winner = keys & _INDEX_MASK
        winner = torch.where(keys == sky_key, torch.full_like(winner, self.sky_index), winner)
        rgb, instance, depth = self._shade(winner, rays, t_ground, n_pix)
        return ViewRender(rgb.reshape(K.h, K.w, 3).cpu().numpy(), instance.reshape(K.h, K.w).cpu().numpy(),
                          depth.reshape(K.h, K.w).cpu().numpy())

    def _rasterise_chunk(self, kind: int, sel: np.ndarray, rect: np.ndarray, area: np.ndarray, w: np.ndarray,
                         rays: _Rays, width: int, keys: torch.Tensor) -> None:
        dev = self.device
        # Per primitive: first pixel index and rectangle width; per pair: offset k inside the rectangle (int32).
        counts = torch.as_tensor(area, device=dev)
        prim_local = torch.repeat_interleave(torch.arange(len(sel), dtype=torch.int32, device=dev), counts)
        start = (np.cumsum(area) - area).astype(np.int32)
        first_pix = (rect[:, 1] * width + rect[:, 0]).astype(np.int32)
        per_prim = torch.as_tensor(np.stack([start, first_pix, w.astype(np.int32)], axis=1), device=dev)[prim_local]
        k = torch.arange(int(area.sum()), dtype=torch.int32, device=dev) - per_prim[:, 0]
        row = torch.div(k, per_prim[:, 2], rounding_mode='floor')
        pix = (per_prim[:, 1] + row * (width - per_prim[:, 2]) + k).long()
        idx = torch.as_tensor(sel, device=dev)[prim_local]
        t = self._hit(kind, rays.origin, rays.dirs[pix], idx)
        hit = torch.isfinite(t)
        if not bool(hit.any()):
            return
        key = (t[hit] * _DEPTH_SCALE).to(torch.int64) * (1 << _INDEX_BITS) + (idx[hit] + self.offsets[kind])
        keys.scatter_reduce_(0, pix[hit], key, reduce='amin', include_self=True)

    def _shade(self, winner: torch.Tensor, rays: _Rays, t_ground: torch.Tensor,
               n_pix: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        dev = self.device
        o, dirs = rays
        rgb = torch.zeros((n_pix, 3), dtype=torch.float32, device=dev)
        depth = torch.full((n_pix,), torch.inf, dtype=torch.float32, device=dev)
        instance = torch.zeros(n_pix, dtype=torch.int64, device=dev)
        # Sky: a gradient with the ray's elevation.
        sky = winner == self.sky_index
        if bool(sky.any()):
            elev = torch.clamp(dirs[sky, 2] / torch.linalg.norm(dirs[sky], dim=1), 0.0, 1.0)[:, None]
            rgb[sky] = (1 - elev) * torch.tensor([0.80, 0.87, 0.95], device=dev) \
                + elev * torch.tensor([0.45, 0.62, 0.88], device=dev)
        # Ground: grass/soil texture, darker under the crown.
        ground = winner == self.ground_index
        if bool(ground.any()):
            t = t_ground[ground]
            p = o + t[:, None] * dirs[ground]
            xy = p[:, :2]
            n1 = value_noise(xy * 3.0, seed=11, octaves=3)
            n2 = value_noise(xy * 40.0, seed=12, octaves=2)
            grass = torch.tensor([0.30, 0.42, 0.16], device=dev)
            soil = torch.tensor([0.42, 0.34, 0.24], device=dev)
            mix = torch.clamp((n1 - 0.35) * 2.5, 0.0, 1.0)[:, None]
            albedo = (mix * grass + (1 - mix) * soil) * (0.75 + 0.5 * n2)[:, None]
            shadow_center = self.crown_center[:2] - self.sun[:2] / self.sun[2] * self.crown_center[2]
            r2 = ((xy - shadow_center) ** 2).sum(1) / (self.crown_radii[0] ** 2)
            shade = 0.38 + 0.62 * self.sun[2] * (1.0 - 0.6 * torch.exp(-r2 * r2))
            rgb[ground] = albedo * shade[:, None]
            depth[ground] = t
        for kind in range(3):
            lo = self.offsets[kind]
            hi = lo + (self.n_e, self.n_l, self.n_c)[kind]
            mask = (winner >= lo) & (winner < hi)
            if not bool(mask.any()):
                continue
            idx = winner[mask] - lo
            d = dirs[mask]
            t = self._hit(kind, o, d, idx)
            p = o + t[:, None] * d
            depth[mask] = t
            if kind == 0:
                albedo, normal, inst = self._ellipsoid_surface(p, idx)
                instance[mask] = inst
            elif kind == 1:
                albedo, normal = self._leaf_surface(p, idx)
            else:
                albedo, normal = self._cylinder_surface(p, idx)
            # Face the camera (two-sided leaves), Lambert + ambient, darker deep inside the crown.
            normal = torch.where(((normal * d).sum(1, keepdim=True) > 0), -normal, normal)
            lambert = torch.clamp((normal * self.sun).sum(1), min=0.0)
            rel = (p - self.crown_center) / self.crown_radii
            radial = torch.linalg.norm(rel, dim=1)
            ao = torch.clamp(0.45 + 0.55 * radial, 0.45, 1.0)
            rgb[mask] = albedo * ((0.38 + 0.62 * lambert) * ao)[:, None]
        rgb8 = torch.clamp(rgb * 255.0 + 0.5, 0.0, 255.0).to(torch.uint8)
        return rgb8, instance.to(torch.int32), depth

    def _ellipsoid_surface(self, p: torch.Tensor, idx: torch.Tensor
                           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        R, r = self.e_rot[idx], self.e_radii[idx]
        local = torch.einsum('pji,pj->pi', R, p - self.e_center[idx])
        normal = torch.einsum('pij,pj->pi', R, local / (r * r))
        normal = normal / torch.linalg.norm(normal, dim=1, keepdim=True)
        unit = local / r
        blotch = value_noise(unit * 1.6 + idx[:, None].to(torch.float32) * 7.31, seed=21, octaves=2)
        amount = self.e_amount[idx]
        blend = torch.clamp((blotch - (1.0 - amount)) * 4.0 + amount * 0.3, 0.0, 1.0)[:, None]
        fine = value_noise(p * 180.0, seed=22)[:, None]
        albedo = ((1 - blend) * self.e_albedo[idx] + blend * self.e_blush[idx]) * (0.92 + 0.16 * fine)
        inst = self.e_instance[idx]
        bark = inst == 0
        if bool(bark.any()):
            albedo[bark] = self.e_albedo[idx[bark]] * (0.7 + 0.6 * value_noise(p[bark] * 60.0, seed=31))[:, None]
        return albedo, normal, inst

    def _leaf_surface(self, p: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        rel = p - self.l_center[idx]
        half = self.l_half[idx]
        x = (rel * self.l_u[idx]).sum(1) / half[:, 0]
        y = (rel * self.l_v[idx]).sum(1) / half[:, 1]
        edge = torch.clamp(1.0 - x * x, min=1e-3)
        vein = torch.exp(-(y / edge / 0.08) ** 2)   # midrib
        side = 0.9 + 0.1 * torch.cos(18.0 * (x + 0.5 * y.abs() / edge))  # side veins
        tone = 0.85 + 0.3 * value_noise(p * 90.0, seed=41)
        albedo = self.l_albedo[idx] * (tone * side * (1.0 - 0.25 * vein) + 0.0)[:, None] \
            + 0.15 * vein[:, None] * torch.tensor([0.6, 0.7, 0.3], device=self.device)
        return albedo, self.l_n[idx]

    def _cylinder_surface(self, p: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        p0, p1 = self.c_p0[idx], self.c_p1[idx]
        axis = p1 - p0
        axis = axis / torch.linalg.norm(axis, dim=1, keepdim=True)
        rel = p - p0
        s = (rel * axis).sum(1, keepdim=True)
        radial = rel - s * axis
        normal = radial / torch.clamp(torch.linalg.norm(radial, dim=1, keepdim=True), min=1e-12)
        # Bark: noise stretched along the axis (world-anchored, so consistent across views).
        stretched = p * 70.0 - 55.0 * s * axis
        albedo = self.c_albedo[idx] * (0.65 + 0.7 * value_noise(stretched, seed=51, octaves=2))[:, None]
        return albedo, normal

    # ------------------------------------------------------------------ ray casting (tests, visibility)
    def first_hit(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Brute-force ray cast (all rays x all primitives, chunked; for few rays only).

        Args:
            origins: [R, 3] ray origins, metres. dirs: [R, 3] directions (any length).

        Returns:
            (t [R] distance in units of ``dirs`` (inf = nothing or the ground/sky), instance [R] fruit id of the
            first primitive hit, 0 when it is not a fruit).
        """
        with self._one_cpu_thread(), torch.no_grad():
            o_all = torch.as_tensor(origins, dtype=torch.float32, device=self.device)
            d_all = torch.as_tensor(dirs, dtype=torch.float32, device=self.device)
            n_rays = len(o_all)
            best_t = torch.full((n_rays,), torch.inf, device=self.device)
            best_inst = torch.zeros(n_rays, dtype=torch.int64, device=self.device)
            for kind, n in enumerate((self.n_e, self.n_l, self.n_c)):
                if n == 0:
                    continue
                step = max(1, _MAX_PAIRS // n)
                for r0 in range(0, n_rays, step):
                    ray = torch.arange(r0, min(n_rays, r0 + step), device=self.device)
                    ray_p = ray.repeat_interleave(n)
                    idx = torch.arange(n, device=self.device).repeat(len(ray))
                    t = self._hit(kind, o_all[ray_p], d_all[ray_p], idx).reshape(len(ray), n)
                    t_min, arg = t.min(dim=1)
                    better = t_min < best_t[ray]
                    best_t[ray] = torch.where(better, t_min, best_t[ray])
                    inst = self.e_instance[arg] if kind == 0 else torch.zeros_like(arg)
                    best_inst[ray] = torch.where(better, inst, best_inst[ray])
            return best_t.cpu().numpy(), best_inst.cpu().numpy()
