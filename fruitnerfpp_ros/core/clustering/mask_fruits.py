"""Fruit the training views' masks agree on where the cloud has none: triangulated from the masks it leaves unexplained.

The surface export keeps a fruit only where the trained field made a surface. A fruit seen through gaps in the
foliage, a few views at a time, often gets none: the field ends its rays on the leaves in front (docs/results/
accuracy_suite.md, session 20), and no clustering can count points that were never exported. Its masks are still in
the training views. This step, run after the clustering, looks for them:

1. **Unexplained masks.** Every counted fruit is drawn into every training view as a disc of its projected size
   (``disc_radius_factor`` radii plus ``disc_margin_px``). A view's instance mask of at least ``min_mask_pixels``
   pixels (fewer where the fruit are small in the views: ``min_mask_share`` of a whole fruit's mask) is explained
   when at least ``explained_share`` of its pixels lie on such discs; the others are fruit the count may lack (or the
   caps of counted fruits whose centres lie off, which the next steps must not turn into doubles).
2. **Rays.** An unexplained mask gives the ray through its centroid and a farthest depth: the depth at which a whole
   fruit of the scene's diameter would span the mask's extent, times ``max_depth_factor`` (a mask cut by leaves is
   smaller, its fruit nearer than that).
3. **Triangulation.** Rays of two different views that pass within ``ray_gap_diameters`` of each other, in front of
   both cameras, within both farthest depths and inside the scene box, meet at a candidate; candidates within
   ``min_separation_diameters`` of a counted fruit are dropped (they are its caps).
4. **Greedy support.** A candidate's support is the number of distinct views with an unused ray through it (within
   half the gap, within its farthest depth). The best-supported candidate with at least ``min_views`` views becomes
   a fruit at the least-squares point of its rays, its rays are used up, and the next is taken, until none has the
   support left: each mask explains one fruit at most, so two fruits' rays crossing by chance cannot outvote them.
5. **Agreement by chance.** Rays of different fruits (or of a segmenter's false detections on leaves) also pass
   near one point in a few views. How often depends on the masks: how many go unexplained per view, how large,
   from how many views. So the rays are shuffled (each view's rays turned together by a few fruit diameters:
   every view keeps its masks, the views no longer agree) and triangulated in the same way, ``chance_draws``
   times; ``min_views`` is raised until the shuffles give at most ``max_chance_share`` times as many fruit as the
   real rays. Clean masks keep a floor of 3-5 views; with a false detection per ten fruit it rises to 4-6, and
   what would have been dozens of ghosts is not counted (docs/results/accuracy_suite.md, session 33).

Everything is in metres and fruit diameters; nothing depends on the scene box's size. The added fruits have no
cloud points (``n_points`` 0, ``source`` ``masks``): counts, centres and markers hold them, the instance cloud does
not.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sparse
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.clustering.config import MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.clustering.mask_views import MaskViews, pinhole_view
from fruitnerfpp_ros.core.tracking.camera import PinholeView, triangulate
from fruitnerfpp_ros.core.tracking.detections import detect_blobs

__all__ = ['MaskViews', 'MaskRays', 'fruit_discs', 'mask_pixel_floor', 'unexplained_mask_rays', 'triangulate_mask_rays',
           'ChanceFloor', 'shuffled_rays', 'chance_min_views', 'add_mask_fruits']


@dataclass(frozen=True)
class MaskRays:
    """The rays through the unexplained masks' centroids.

    Attributes:
        view: [R] the view of each mask.
        origin: [R, 3] camera centre (m).
        direction: [R, 3] unit direction through the mask's centroid.
        max_depth: [R] farthest distance along the ray at which its fruit may lie (m).
        pixels: [R] the mask's pixels.
        min_pixels: the floor the masks met (:func:`mask_pixel_floor`).
    """

    view: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    max_depth: np.ndarray
    pixels: np.ndarray
    min_pixels: int = 0

    def __len__(self) -> int:
        return len(self.view)


def fruit_discs(camera: PinholeView, centers: np.ndarray, fruit_diameter_m: float,
                config: MaskFruitConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The discs a counted fruit explains masks with in a view: ([K, 2] projected centres (pixels), [K] radii
    (``disc_radius_factor`` times the fruit's projected radius plus ``disc_margin_px``), [K] in front of the
    camera) of the fruits at ``centers`` [K, 3]."""
    uv, depth = camera.project(centers)                  # NaN behind the camera
    radius_m = 0.5 * fruit_diameter_m * config.disc_radius_factor
    radius = radius_m * camera.fl_x / np.maximum(depth, 1e-9) + config.disc_margin_px
    return uv, radius, depth > 1e-6


def _discs(camera: PinholeView, centers: np.ndarray, fruit_diameter_m: float, config: MaskFruitConfig) -> np.ndarray:
    """[H, W] uint8 image, 1 on the :func:`fruit_discs` of the fruits at ``centers``."""
    image = np.zeros((camera.height, camera.width), np.uint8)
    if not len(centers):
        return image
    uv, radius, front = fruit_discs(camera, centers, fruit_diameter_m, config)
    u, v = uv.T
    near = front & (u + radius >= 0) & (u - radius < camera.width) & (v + radius >= 0) & (v - radius < camera.height)
    for x, y, r in zip(u[near], v[near], radius[near]):   # one filled circle per fruit in view (sub-pixel, 2 bits)
        cv2.circle(image, (int(round(x * 4)), int(round(y * 4))), max(1, int(round(r * 4))), 1, -1, shift=2)
    return image


def mask_pixel_floor(areas_px: np.ndarray, config: MaskFruitConfig) -> int:
    """The fewest pixels a mask needs to give a ray: ``min_mask_pixels``, or ``min_mask_share`` of a whole fruit's
    mask (the 90th percentile of ``areas_px``, every mask of every view) where that is less, never below
    ``smallest_mask_pixels``. A fruit's pixels follow the camera, the standoff and the fruit, not the scene: plums
    10-15 px in area at a row's standoff against apples of 40-110 px (docs/results/accuracy_suite.md, session 34)."""
    if not len(areas_px):
        return config.min_mask_pixels
    whole = float(np.percentile(areas_px, 90))
    return int(np.clip(np.ceil(config.min_mask_share * whole), config.smallest_mask_pixels, config.min_mask_pixels))


def unexplained_mask_rays(views: MaskViews, centers: np.ndarray, fruit_diameter_m: float,
                          config: MaskFruitConfig) -> MaskRays:
    """The rays of the masks of ``views`` that the fruits at ``centers`` [K, 3] do not explain (see module doc).

    One pass over the views: every mask's area is gathered for :func:`mask_pixel_floor` while the rays of the
    unexplained masks of at least ``smallest_mask_pixels`` are made; those under the floor are dropped at the end."""
    parts: list[tuple[np.ndarray, ...]] = [(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                                            np.zeros(0, np.int64))]
    areas = [np.zeros(0)]
    for view in np.asarray(views.views, np.int64):
        blobs = detect_blobs(np.asarray(views.instance_masks[view]), source=f'view {view} instance mask')
        areas.append(blobs.areas_px)
        if not len(blobs):
            continue
        camera = pinhole_view(views, view)
        discs = _discs(camera, centers, fruit_diameter_m, config)
        covered = np.bincount(blobs.labels.ravel(), weights=discs.ravel(), minlength=len(blobs) + 1)[1:]
        keep = (blobs.areas_px >= config.smallest_mask_pixels) & (covered < config.explained_share * blobs.areas_px)
        if not keep.any():
            continue
        direction, range_per_depth = camera.rays(blobs.centroids_px[keep])
        boxes = blobs.boxes_px[keep]
        extent = np.maximum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]).astype(np.float64)
        # a whole fruit spans `extent` pixels at depth f d / extent; the ray's length is longer off the axis
        max_depth = config.max_depth_factor * camera.fl_x * fruit_diameter_m / extent * range_per_depth
        parts.append((np.full(len(direction), view), np.broadcast_to(camera.origin, (len(direction), 3)), direction,
                      max_depth, blobs.areas_px[keep].astype(np.int64)))
    min_pixels = mask_pixel_floor(np.concatenate(areas), config)
    view, origin, direction, max_depth, pixels = (np.concatenate([p[i] for p in parts]) for i in range(5))
    big = pixels >= min_pixels
    return MaskRays(view[big], origin[big], direction[big], max_depth[big], pixels[big], min_pixels)


def _pair_points(rays: MaskRays, gap_m: float, near_m: float, chunk_pairs: int = 1_000_000) -> np.ndarray:
    """[P, 3] midpoints of the closest approach of every two rays of different views that pass within ``gap_m``,
    in front of both cameras (``near_m``) and within both farthest depths. Pairs are formed a block of rays at a
    time (about ``chunk_pairs`` at once: memory stays bounded on a 300-view scene)."""
    n = len(rays)
    O, D = rays.origin, rays.direction
    block = max(1, chunk_pairs // max(n, 1))
    points = []
    for start in range(0, n, block):
        a, b = np.nonzero(np.arange(n)[None, :] > np.arange(start, min(n, start + block))[:, None])
        a += start
        keep = rays.view[a] != rays.view[b]
        a, b = a[keep], b[keep]
        w = O[a] - O[b]
        cos = np.einsum('ij,ij->i', D[a], D[b])
        da, db = np.einsum('ij,ij->i', D[a], w), np.einsum('ij,ij->i', D[b], w)
        denominator = 1.0 - cos * cos
        crossing = denominator > 1e-4                 # rays that are not parallel (a baseline to triangulate on)
        a, b, cos, da, db, denominator = a[crossing], b[crossing], cos[crossing], da[crossing], db[crossing], \
            denominator[crossing]
        s = (cos * db - da) / denominator             # distance along ray a
        t = (db - cos * da) / denominator             # distance along ray b
        pa, pb = O[a] + s[:, None] * D[a], O[b] + t[:, None] * D[b]
        good = (np.linalg.norm(pa - pb, axis=1) < gap_m) & (s > near_m) & (t > near_m) & \
            (s < rays.max_depth[a]) & (t < rays.max_depth[b])
        points.append(0.5 * (pa[good] + pb[good]))
    return np.concatenate(points) if points else np.zeros((0, 3))


def _support(candidates: np.ndarray, rays: MaskRays, reach_m: float, near_m: float,
             chunk: int = 4096) -> sparse.csr_matrix:
    """[C, R] sparse: ray r passes within ``reach_m`` of candidate c, in front of its camera and within its depth."""
    blocks = []
    for start in range(0, len(candidates), chunk):
        rel = candidates[start:start + chunk, None, :] - rays.origin[None]          # [c, R, 3]
        along = np.einsum('crk,rk->cr', rel, rays.direction)
        off = np.linalg.norm(rel - along[..., None] * rays.direction[None], axis=-1)
        blocks.append(sparse.csr_matrix((off < reach_m) & (along > near_m) & (along < rays.max_depth[None])))
    return sparse.vstack(blocks).tocsr()


def triangulate_mask_rays(rays: MaskRays, fruit_diameter_m: float, aabb: np.ndarray | None, centers: np.ndarray,
                          config: MaskFruitConfig) -> tuple[np.ndarray, np.ndarray]:
    """([M, 3] fruit centres several views' rays agree on, away from the counted ``centers`` [K, 3]; [M] the number
    of views that agree on each), best supported first: the support never rises along the list, so the fruits a
    higher ``min_views`` would find are a head of it (module doc)."""
    none = np.zeros((0, 3)), np.zeros(0, np.int64)
    if len(rays) < config.min_views:
        return none
    gap, near = config.ray_gap_diameters * fruit_diameter_m, config.min_camera_distance_m
    separation = config.min_separation_diameters * fruit_diameter_m
    points = _pair_points(rays, gap, near)
    if aabb is not None:
        lo, hi = np.asarray(aabb, np.float64)
        points = points[np.all((points >= lo) & (points <= hi), axis=1)]
    if len(centers) and len(points):
        points = points[cKDTree(centers).query(points)[0] >= separation]
    if not len(points):
        return none
    support = _support(points, rays, 0.5 * gap, near)
    views, view_index = np.unique(rays.view, return_inverse=True)
    one_hot = sparse.csr_matrix((np.ones(len(rays)), (np.arange(len(rays)), view_index)), shape=(len(rays), len(views)))
    unused = np.ones(len(rays))
    added: list[np.ndarray] = []
    n_added: list[int] = []
    while True:
        seen_views = (support @ sparse.diags(unused) @ one_hot) > 0
        n_views = np.asarray(seen_views.sum(1)).ravel()
        best = int(np.argmax(n_views))
        if n_views[best] < config.min_views:
            break
        members = support[best].indices[unused[support[best].indices] > 0]
        unused[members] = 0.0
        zero = np.zeros(len(members))                     # the point nearest the members' rays, no range prior
        x = triangulate(rays.origin[members], rays.direction[members], zero, zero + 1.0, zero).point
        others = np.vstack([np.asarray(centers, np.float64).reshape(-1, 3), *added])
        if not len(others) or np.min(np.linalg.norm(others - x, axis=1)) >= separation:
            added.append(x[None])
            n_added.append(int(n_views[best]))
    return (np.vstack(added), np.asarray(n_added, np.int64)) if added else none


@dataclass(frozen=True)
class ChanceFloor:
    """The views a masks' fruit needs, raised above ``min_views`` until agreement by chance is rare.

    Attributes:
        min_views: the floor.
        chance_fruits: how many fruit the shuffled rays give at that floor (mean over the draws).
    """

    min_views: int
    chance_fruits: float


def shuffled_rays(rays: MaskRays, fruit_diameter_m: float, config: MaskFruitConfig,
                  rng: np.random.Generator) -> MaskRays:
    """``rays`` with each view's rays turned together, about a random axis across the view, by the angle that
    ``chance_shift_diameters`` fruit diameters span at their depth: every view keeps its pattern of masks (as many,
    as close together, as far), but the views no longer agree on where the fruit hang."""
    _, index = np.unique(rays.view, return_inverse=True)
    count = np.bincount(index).astype(np.float64)
    axis = np.stack([np.bincount(index, weights=rays.direction[:, i]) for i in range(3)], axis=1)
    axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    depth = np.bincount(index, weights=rays.max_depth) / count / config.max_depth_factor
    turn = rng.normal(size=axis.shape)
    turn -= np.sum(turn * axis, axis=1, keepdims=True) * axis
    turn /= np.maximum(np.linalg.norm(turn, axis=1, keepdims=True), 1e-12)
    angle = config.chance_shift_diameters * fruit_diameter_m / np.maximum(depth, 1e-9)
    direction = Rotation.from_rotvec(turn * angle[:, None])[index].apply(rays.direction)
    return dataclasses.replace(rays, direction=direction)


def chance_min_views(rays: MaskRays, n_views: np.ndarray, fruit_diameter_m: float, aabb: np.ndarray | None,
                     centers: np.ndarray, config: MaskFruitConfig) -> ChanceFloor:
    """The lowest floor, from ``min_views`` up, at which ``chance_draws`` shuffles of ``rays``
    (:func:`shuffled_rays`) give on average at most ``max_chance_share`` times as many fruit as the real rays do
    (``n_views``: the views each real fruit has, from :func:`triangulate_mask_rays`)."""
    if not config.chance_draws or not len(n_views):
        return ChanceFloor(config.min_views, 0.0)
    rng = np.random.default_rng(config.chance_seed)
    draws = [triangulate_mask_rays(shuffled_rays(rays, fruit_diameter_m, config, rng), fruit_diameter_m, aabb,
                                   centers, config)[1] for _ in range(config.chance_draws)]
    floor = config.min_views
    while True:
        chance = float(np.mean([np.count_nonzero(d >= floor) for d in draws]))
        if chance <= config.max_chance_share * np.count_nonzero(n_views >= floor) or floor > n_views.max():
            return ChanceFloor(floor, chance)
        floor += 1


def add_mask_fruits(count: CountResult, views: MaskViews, fruit_diameter_m: float, aabb: np.ndarray | None,
                    config: MaskFruitConfig) -> CountResult:
    """``count`` with the fruits its unexplained masks agree on appended (ids after the clusters', ``n_points`` 0,
    ``source`` ``masks``); ``stats['mask_fruits']`` says how many, from how many unexplained masks, the views each
    needed (``min_views``, raised by chance) and how many the shuffled rays would have added at that floor."""
    if not config.enabled or not fruit_diameter_m > 0:
        return count
    centers = count.centers()
    rays = unexplained_mask_rays(views, centers, fruit_diameter_m, config)
    found, n_views = triangulate_mask_rays(rays, fruit_diameter_m, aabb, centers, config)
    chance = chance_min_views(rays, n_views, fruit_diameter_m, aabb, centers, config)
    found = found[n_views >= chance.min_views]
    start = max((f.id for f in count.fruits), default=0) + 1
    extent = np.full(3, fruit_diameter_m)
    fruits = [Fruit(start + i, x, fruit_diameter_m, extent, 0, source='masks') for i, x in enumerate(found)]
    stats = {**count.stats, 'mask_fruits': {'added': len(fruits), 'unexplained_masks': len(rays),
                                            'min_mask_pixels': rays.min_pixels, 'min_views': chance.min_views,
                                            'chance_fruits': chance.chance_fruits}}
    return dataclasses.replace(count, fruits=[*count.fruits, *fruits], stats=stats)
