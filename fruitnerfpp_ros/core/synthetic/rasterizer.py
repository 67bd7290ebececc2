"""Vectorised renderer of the procedural tree: per-primitive screen-space rasterisation with a z-buffer.

For each view, every primitive's 3D bounding hull is projected (pinhole) to a rectangle of the undistorted image
plane; all (primitive, pixel) pairs whose pixel ray falls inside those rectangles are enumerated at once
(``repeat_interleave``), the exact ray/primitive intersection is computed for each pair (``intersect.py``), and
a z-buffer (``scatter_reduce`` amin on a packed depth+index key) keeps the nearest surface per pixel. The ground
plane z = 0 and the sky fill the rest; ``shading.py`` colours the winners. Runs on CPU or CUDA (torch), float32;
deterministic on a given device.

Without lens distortion a pixel's ray falls inside a rectangle exactly when the pixel does, so the pairs are
the pixels of the rectangle. With distortion (``lens.py``) each pixel has its own ray through its distorted
centre: pixels are binned by where their ray meets the undistorted image plane (unit bins), and the pairs of a
rectangle are the pixels of its bins (:class:`_PixelBins`), so image and instance mask come from the same rays.
"""

from __future__ import annotations

import contextlib
from typing import Iterator, NamedTuple

import numpy as np
import torch

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.geometry import T_OPENGL_OPTICAL
from fruitnerfpp_ros.core.synthetic.appearance import DEFAULT_APPEARANCE, Appearance
from fruitnerfpp_ros.core.synthetic.intersect import NEAR_M, SceneTensors
from fruitnerfpp_ros.core.synthetic.lens import is_distorted, undistorted_pixel_grid
from fruitnerfpp_ros.core.synthetic.primitives import Scene
from fruitnerfpp_ros.core.synthetic.shading import Shader, value_noise
from fruitnerfpp_ros.errors import SynthError

__all__ = ['ViewRender', 'Renderer', 'value_noise', 'SURFACE_FRUIT', 'SURFACE_LEAF', 'SURFACE_WOOD', 'SURFACE_GROUND',
           'SURFACE_SKY']

#: What a pixel shows (``ViewRender.surface``): the primitive kinds in their index order, then ground and sky.
SURFACE_FRUIT, SURFACE_LEAF, SURFACE_WOOD, SURFACE_GROUND, SURFACE_SKY = range(5)

_DEPTH_SCALE = float(2 ** 16)   # depth quantisation of the z-buffer key (1/65536 m)
_INDEX_BITS = 24
_INDEX_MASK = (1 << _INDEX_BITS) - 1
_MAX_PAIRS = 1 << 21            # (primitive, pixel) pairs per chunk


class ViewRender(NamedTuple):
    """One rendered view.

    Attributes:
        rgb: [H, W, 3] uint8.
        instance: [H, W] uint16 fruit ids (0 = background).
        depth: [H, W] float32 depth along the optical axis, metres (inf = sky).
        surface: [H, W] uint8 what each pixel shows: ``SURFACE_FRUIT``, ``SURFACE_LEAF``, ``SURFACE_WOOD`` (trunk
            and branches), ``SURFACE_GROUND`` or ``SURFACE_SKY`` (the depth sensor model drops thin leaves).
    """

    rgb: np.ndarray
    instance: np.ndarray
    depth: np.ndarray
    surface: np.ndarray | None = None


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[N, 8, 3] corners of the axis-aligned boxes [lo, hi] ([N, 3] each)."""
    box = np.stack([lo, hi], axis=1)
    return np.stack([np.stack([box[:, k & 1, 0], box[:, (k >> 1) & 1, 1], box[:, (k >> 2) & 1, 2]], axis=1)
                     for k in range(8)], axis=1)


class _Rays(NamedTuple):
    origin: torch.Tensor   # [3]
    dirs: torch.Tensor     # [P, 3], optical z component scaled to 1 (t = optical depth)


class _PixelBins(NamedTuple):
    """Pixels of a distorted image binned by where their rays meet the undistorted image plane.

    Bin (bx, by) holds the pixels whose undistorted position (fl_x * x + cx, fl_y * y + cy) lies in
    [u0 + bx, u0 + bx + 1) x [v0 + by, v0 + by + 1); ``order[ptr[b]:ptr[b + 1]]`` are the pixels of bin
    b = by * width + bx (row-major pixel indices).
    """

    u0: int
    v0: int
    width: int
    height: int
    ptr: np.ndarray       # [width * height + 1] int64
    order: torch.Tensor   # [H * W] int64


def _pixel_bins(grid: np.ndarray, K: CameraIntrinsics, device: torch.device) -> _PixelBins:
    u = np.floor(K.fl_x * grid[:, 0] + K.cx).astype(np.int64)
    v = np.floor(K.fl_y * grid[:, 1] + K.cy).astype(np.int64)
    u0, v0 = int(u.min()), int(v.min())
    width, height = int(u.max()) - u0 + 1, int(v.max()) - v0 + 1
    bin_of = (v - v0) * width + (u - u0)
    order = np.argsort(bin_of, kind='stable')
    ptr = np.searchsorted(bin_of[order], np.arange(width * height + 1))
    return _PixelBins(u0, v0, width, height, ptr.astype(np.int64), torch.as_tensor(order, device=device))


class Renderer:
    """Renders views of one :class:`Scene` on a torch device.

    Args:
        scene: the procedural tree.
        device: torch device (``resolve_device`` it first).
        appearance: lighting, sky and ground (default: the fixed look of every default dataset).

    Raises:
        SynthError: the scene has more primitives than the z-buffer key can index.
    """

    def __init__(self, scene: Scene, device: torch.device, appearance: Appearance = DEFAULT_APPEARANCE) -> None:
        self.scene = scene
        self.device = device
        self.tensors = SceneTensors(scene, device)
        crown = torch.as_tensor(np.stack([scene.crown_center, scene.crown_radii]), dtype=torch.float32, device=device)
        self.shader = Shader(self.tensors, crown[0], crown[1], appearance)
        if self.shader.sky_index > _INDEX_MASK:
            raise SynthError(f'too many primitives for the z-buffer key ({self.tensors.total} > {_INDEX_MASK - 1}); '
                             'use fewer fruits or a smaller leaf_scale')
        e, lv, c = scene.ellipsoids, scene.leaves, scene.cylinders
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
        self._lens: tuple[CameraIntrinsics, torch.Tensor, _PixelBins] | None = None

    # ------------------------------------------------------------------ rays and pixel sets
    def _lens_of(self, K: CameraIntrinsics) -> tuple[torch.Tensor, _PixelBins]:
        """Undistorted ray grid [P, 2] and pixel bins of a distorted camera (cached for the last ``K``)."""
        if self._lens is None or self._lens[0] != K:
            grid = undistorted_pixel_grid(K)
            self._lens = (K, torch.as_tensor(grid, dtype=torch.float32, device=self.device),
                          _pixel_bins(grid, K, self.device))
        return self._lens[1], self._lens[2]

    def _pixel_rays(self, T_world_camera: np.ndarray, K: CameraIntrinsics) -> tuple[_Rays, np.ndarray]:
        T_world_optical = np.asarray(T_world_camera, dtype=np.float64) @ T_OPENGL_OPTICAL
        R = torch.as_tensor(T_world_optical[:3, :3], dtype=torch.float32, device=self.device)
        origin = torch.as_tensor(T_world_optical[:3, 3], dtype=torch.float32, device=self.device)
        if is_distorted(K):
            grid, _ = self._lens_of(K)
            d_opt = torch.cat([grid, torch.ones(len(grid), 1, device=self.device)], dim=1)
            return _Rays(origin, d_opt @ R.T), T_world_optical
        v, u = torch.meshgrid(torch.arange(K.h, device=self.device, dtype=torch.float32),
                              torch.arange(K.w, device=self.device, dtype=torch.float32), indexing='ij')
        d_opt = torch.stack([(u.reshape(-1) + 0.5 - K.cx) / K.fl_x, (v.reshape(-1) + 0.5 - K.cy) / K.fl_y,
                             torch.ones(K.w * K.h, device=self.device)], dim=1)
        return _Rays(origin, d_opt @ R.T), T_world_optical

    def _projected_extent(self, kind: int, T_world_optical: np.ndarray, K: CameraIntrinsics
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Pinhole projections (u [N, C], v [N, C], undistorted pixel coordinates) of primitive ``kind``'s hull
        corners, with masks (all corners in front [N], some corners in front [N])."""
        corners = self.hulls[kind]
        T_opt_world = np.linalg.inv(T_world_optical)
        p = corners @ T_opt_world[:3, :3].T + T_opt_world[:3, 3]
        z = p[..., 2]
        in_front = z > NEAR_M
        zc = np.where(in_front, z, 1.0)
        u = K.fl_x * p[..., 0] / zc + K.cx
        v = K.fl_y * p[..., 1] / zc + K.cy
        return u, v, in_front.all(1), in_front.any(1)

    def _pixel_boxes(self, kind: int, T_world_optical: np.ndarray, K: CameraIntrinsics) -> np.ndarray:
        """[N, 4] inclusive pixel rectangles (x0, y0, x1, y1) holding primitive ``kind``'s projection."""
        if len(self.hulls[kind]) == 0:
            return np.zeros((0, 4), dtype=np.int64)
        u, v, all_front, any_front = self._projected_extent(kind, T_world_optical, K)
        rect = np.stack([np.ceil(u.min(1) - 0.5 - 1e-3), np.ceil(v.min(1) - 0.5 - 1e-3),
                         np.floor(u.max(1) - 0.5 + 1e-3), np.floor(v.max(1) - 0.5 + 1e-3)], axis=1)
        rect[~all_front & any_front] = [0, 0, K.w - 1, K.h - 1]
        rect[~any_front] = [1, 1, 0, 0]  # empty
        rect[:, [0, 2]] = np.clip(rect[:, [0, 2]], -1, K.w)
        rect[:, [1, 3]] = np.clip(rect[:, [1, 3]], -1, K.h)
        rect[:, 0] = np.maximum(rect[:, 0], 0)
        rect[:, 1] = np.maximum(rect[:, 1], 0)
        rect[:, 2] = np.minimum(rect[:, 2], K.w - 1)
        rect[:, 3] = np.minimum(rect[:, 3], K.h - 1)
        return rect.astype(np.int64)

    def _bin_boxes(self, kind: int, T_world_optical: np.ndarray, K: CameraIntrinsics, bins: _PixelBins
                   ) -> np.ndarray:
        """[N, 4] inclusive bin rectangles (bx0, by0, bx1, by1) of :class:`_PixelBins` holding ``kind``'s
        projection (distorted cameras)."""
        if len(self.hulls[kind]) == 0:
            return np.zeros((0, 4), dtype=np.int64)
        u, v, all_front, any_front = self._projected_extent(kind, T_world_optical, K)
        rect = np.stack([np.floor(u.min(1) - 1e-3) - bins.u0, np.floor(v.min(1) - 1e-3) - bins.v0,
                         np.floor(u.max(1) + 1e-3) - bins.u0, np.floor(v.max(1) + 1e-3) - bins.v0], axis=1)
        rect[~all_front & any_front] = [0, 0, bins.width - 1, bins.height - 1]
        rect[~any_front] = [1, 1, 0, 0]  # empty
        size = np.array([bins.width, bins.height])
        rect[:, :2] = np.clip(rect[:, :2], 0, size)       # a rectangle outside the bins ends up empty
        rect[:, 2:] = np.clip(rect[:, 2:], -1, size - 1)
        return rect.astype(np.int64)

    # ------------------------------------------------------------------ rendering
    def render(self, T_world_camera: np.ndarray, K: CameraIntrinsics) -> ViewRender:
        """Render one view: camera-to-world pose (OpenGL axes, 4x4) and intrinsics (top-left-corner cx, cy; the
        image is distorted by ``K.distortion``, OpenCV's plumb_bob k1, k2, p1, p2, k3, when given).

        Raises:
            SynthError: the lens distortion cannot be inverted over the image.
        """
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
        # Ground plane (z = 0) and sky initialise the z-buffer.
        t_ground = torch.where(dirs[:, 2] < -1e-9, -o[2] / torch.clamp(dirs[:, 2], max=-1e-9), torch.inf)
        sky_key = torch.iinfo(torch.int64).max
        keys = torch.where(torch.isfinite(t_ground),
                           (t_ground * _DEPTH_SCALE).to(torch.int64) * (1 << _INDEX_BITS) + self.shader.ground_index,
                           torch.full_like(t_ground, 0, dtype=torch.int64) + sky_key)
        for kind in range(3):
            if is_distorted(K):
                self._rasterise_binned(kind, T_world_optical, K, rays, keys)
            else:
                self._rasterise_pinhole(kind, T_world_optical, K, rays, keys)
        winner = keys & _INDEX_MASK
        winner = torch.where(keys == sky_key, torch.full_like(winner, self.shader.sky_index), winner)
        rgb, instance, depth = self.shader.shade(winner, o, dirs, t_ground)
        return ViewRender(rgb.reshape(K.h, K.w, 3).cpu().numpy(), instance.reshape(K.h, K.w).cpu().numpy(),
                          depth.reshape(K.h, K.w).cpu().numpy(), self._surface(winner).reshape(K.h, K.w))

    def _surface(self, winner: torch.Tensor) -> np.ndarray:
        """[P] uint8 surface kind of each pixel's z-buffer winner (see :class:`ViewRender`)."""
        bounds = torch.as_tensor([*self.tensors.offsets[1:], self.tensors.total, self.shader.ground_index + 1],
                                 device=winner.device)
        return torch.bucketize(winner, bounds, right=True).to(torch.uint8).cpu().numpy()

    def _rasterise_pinhole(self, kind: int, T_world_optical: np.ndarray, K: CameraIntrinsics, rays: _Rays,
                           keys: torch.Tensor) -> None:
        rect = self._pixel_boxes(kind, T_world_optical, K)
        w = np.maximum(rect[:, 2] - rect[:, 0] + 1, 0)
        h = np.maximum(rect[:, 3] - rect[:, 1] + 1, 0)
        area = w * h
        for sel in self._chunks(area):
            dev = self.device
            r, a, ww = rect[sel], area[sel], w[sel]
            # Per primitive: first pixel index and rectangle width; per pair: offset k inside the rectangle (int32).
            prim_local = torch.repeat_interleave(torch.arange(len(sel), dtype=torch.int32, device=dev),
                                                 torch.as_tensor(a, device=dev))
            start = (np.cumsum(a) - a).astype(np.int32)
            first_pix = (r[:, 1] * K.w + r[:, 0]).astype(np.int32)
            per_prim = torch.as_tensor(np.stack([start, first_pix, ww.astype(np.int32)], axis=1),
                                       device=dev)[prim_local]
            k = torch.arange(int(a.sum()), dtype=torch.int32, device=dev) - per_prim[:, 0]
            row = torch.div(k, per_prim[:, 2], rounding_mode='floor')
            pix = (per_prim[:, 1] + row * (K.w - per_prim[:, 2]) + k).long()
            self._zbuffer(kind, torch.as_tensor(sel, device=dev)[prim_local], pix, rays, keys)

    def _rasterise_binned(self, kind: int, T_world_optical: np.ndarray, K: CameraIntrinsics, rays: _Rays,
                          keys: torch.Tensor) -> None:
        _, bins = self._lens_of(K)
        rect = self._bin_boxes(kind, T_world_optical, K, bins)
        # One segment of the bin-sorted pixel list per primitive and bin row.
        rows = np.where(rect[:, 0] <= rect[:, 2], np.maximum(rect[:, 3] - rect[:, 1] + 1, 0), 0)
        seg_prim = np.repeat(np.arange(len(rect)), rows)
        seg_row = rect[seg_prim, 1] + np.arange(len(seg_prim)) - np.repeat(np.cumsum(rows) - rows, rows)
        seg_lo = bins.ptr[seg_row * bins.width + rect[seg_prim, 0]]
        seg_len = bins.ptr[seg_row * bins.width + rect[seg_prim, 2] + 1] - seg_lo
        pairs = np.bincount(seg_prim, weights=seg_len, minlength=len(rect)).astype(np.int64)
        seg_start = np.searchsorted(seg_prim, np.arange(len(rect) + 1))
        for sel in self._chunks(pairs):
            dev = self.device
            segs = np.arange(seg_start[sel[0]], seg_start[sel[-1] + 1])  # primitives between have no pairs
            lengths = torch.as_tensor(seg_len[segs], device=dev)
            seg_of_pair = torch.repeat_interleave(torch.arange(len(segs), device=dev), lengths)
            first = torch.as_tensor(seg_lo[segs], device=dev)
            offset = torch.arange(int(lengths.sum()), device=dev) - (torch.cumsum(lengths, 0) - lengths)[seg_of_pair]
            pix = bins.order[first[seg_of_pair] + offset]
            idx = torch.as_tensor(seg_prim[segs], device=dev)[seg_of_pair]
            self._zbuffer(kind, idx, pix, rays, keys)

    @staticmethod
    def _chunks(pairs: np.ndarray) -> Iterator[np.ndarray]:
        """Indices of the primitives with pairs, in groups of about ``_MAX_PAIRS`` pairs."""
        live = np.flatnonzero(pairs > 0)
        cum = np.cumsum(pairs[live])
        start = 0
        while start < len(live):
            base = cum[start - 1] if start else 0
            stop = max(start + 1, int(np.searchsorted(cum, base + _MAX_PAIRS, side='right')))
            yield live[start:stop]
            start = stop

    def _zbuffer(self, kind: int, idx: torch.Tensor, pix: torch.Tensor, rays: _Rays, keys: torch.Tensor) -> None:
        """Intersect the (primitive ``idx``, pixel ``pix``) pairs and keep the nearest hit per pixel in ``keys``."""
        t = self.tensors.hit(kind, rays.origin, rays.dirs[pix], idx)
        hit = torch.isfinite(t)
        if not bool(hit.any()):
            return
        key = (t[hit] * _DEPTH_SCALE).to(torch.int64) * (1 << _INDEX_BITS) + (idx[hit] + self.tensors.offsets[kind])
        keys.scatter_reduce_(0, pix[hit], key, reduce='amin', include_self=True)

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
            for kind, n in enumerate(self.tensors.counts):
                if n == 0:
                    continue
                step = max(1, _MAX_PAIRS // n)
                for r0 in range(0, n_rays, step):
                    ray = torch.arange(r0, min(n_rays, r0 + step), device=self.device)
                    ray_p = ray.repeat_interleave(n)
                    idx = torch.arange(n, device=self.device).repeat(len(ray))
                    t = self.tensors.hit(kind, o_all[ray_p], d_all[ray_p], idx).reshape(len(ray), n)
                    t_min, arg = t.min(dim=1)
                    better = t_min < best_t[ray]
                    best_t[ray] = torch.where(better, t_min, best_t[ray])
                    inst = self.tensors.e_instance[arg] if kind == 0 else torch.zeros_like(arg)
                    best_inst[ray] = torch.where(better, inst, best_inst[ray])
            return best_t.cpu().numpy(), best_inst.cpu().numpy()
