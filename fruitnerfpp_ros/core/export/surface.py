"""Surface export: the fruit surfaces the cameras saw, as a point cloud with instance embeddings.

Every fruit pixel of every training view is rendered through the trained field; where its ray terminates (the
median of its render weights) is a point on a fruit surface. A ray that stays semi-transparent (fog), or ends on
something the field does not call fruit, gives no surface point; along such a ray the samples that are dense and
fruit, wherever they lie, are candidate points instead (``behind_foliage``): a briefly trained field often ends a
fruit pixel's ray in a haze where leaves and the gaps between them were not told apart, with the fruit, dense and
fruit, behind it. The points are merged on a voxel grid sized in fruit diameters (or in pixel footprints on the
fruit, when a pixel is wider), and a voxel is kept only when at least ``min_views`` different views put a point in
it (one view's floater is not a fruit) and when it lies on a fruit pixel in at least ``min_mask_agreement`` of the
training views it projects into (a point of fog or leaf in front of a fruit drifts off the fruit masks of the other
views, while a fruit's surface stays on them wherever it is not hidden). No threshold here is a density in 1/m, so
nothing depends on how opaque a briefly trained field became or on the size of the scene box (the candidates'
one-step opacity follows the marching step, which is set in fruit diameters).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.rays import RayBundle, rays_for_pixels
from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.fields.fruit_field import FruitField
from fruitnerfpp_ros.core.progress import Phase, ProgressCallback, ProgressEvent, ignore_progress
from fruitnerfpp_ros.core.rendering.marching import march_rays
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings, autocast_for, render_rays

__all__ = ['SurfaceExportReport', 'export_surface_cloud', 'merge_on_voxels']


@dataclass(frozen=True)
class SurfaceExportReport:
    """What the surface export rendered and what each test kept.

    Attributes:
        views: views whose fruit pixels were rendered.
        n_fruit_pixels: fruit pixels in those views.
        n_rays: rays rendered (a subsample when there were more than ``max_rays``).
        n_opaque: rays whose opacity reached ``min_opacity``.
        n_fruit: of those, rays whose rendered fruit probability reached ``fruit_threshold``.
        n_behind: candidate points of fruit behind foliage (``ExportConfig.behind_foliage``).
        n_voxels: voxels holding at least one surface point.
        n_multi_view: voxels with points from at least ``min_views`` views.
        n_kept: of those, voxels on the fruit masks of at least ``min_mask_agreement`` of the views (the cloud).
        voxel_size_m: merge voxel (m).
        fruit_diameter_m: the scene's fruit diameter the voxel follows from.
        min_opacity, fruit_threshold, min_views: the tests.
        stopped: interrupted by the stop event (the cloud is partial).
        time_s: wall time.
    """

    views: int
    n_fruit_pixels: int
    n_rays: int
    n_opaque: int
    n_fruit: int
    n_behind: int
    n_voxels: int
    n_multi_view: int
    n_kept: int
    voxel_size_m: float
    fruit_diameter_m: float
    min_opacity: float
    fruit_threshold: float
    min_views: int
    min_mask_agreement: float
    stopped: bool
    time_s: float

    def explain(self) -> str:
        """One line saying what each test kept (and, for an empty cloud, which test removed everything)."""
        line = (f'surface export: {self.n_rays} fruit-pixel rays of {self.views} views -> {self.n_opaque} opaque '
                f'(>= {self.min_opacity:.2f}) -> {self.n_fruit} ending on fruit (p >= {self.fruit_threshold:.2f}) '
                f'(+ {self.n_behind} points of fruit behind foliage) -> '
                f'{self.n_voxels} voxels of {self.voxel_size_m * 1000:.1f} mm -> {self.n_multi_view} seen from >= '
                f'{self.min_views} views -> {self.n_kept} on the fruit masks of >= {self.min_mask_agreement:.0%} of '
                'the views')
        if self.n_kept == 0:
            if self.n_rays == 0:
                line += '; EMPTY: the masks hold no fruit pixel'
            elif self.n_opaque == 0:
                line += '; EMPTY: no fruit ray became opaque: the geometry did not train (check poses, steps)'
            elif self.n_fruit + self.n_behind == 0:
                line += '; EMPTY: no opaque ray ended on fruit: check the semantic stage and the masks'
            elif self.n_multi_view == 0:
                line += '; EMPTY: no surface voxel was seen from enough views: lower min_views or check the poses'
            else:
                line += '; EMPTY: no surface voxel agrees with the other views\' masks: check the poses and masks'
        return line

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data['method'] = 'surface'
        data['explanation'] = self.explain()
        return data


def mask_agreement(xyz: torch.Tensor, dataset: SceneDataset, T_world_camera: torch.Tensor, views: list[int],
                   dilation_px: int) -> torch.Tensor:
    """Per point [N], the fraction of ``views`` it projects into (inside the valid image, in front of the camera)
    whose fruit mask (dilated by ``dilation_px``) holds it; 0 where no view sees it."""
    seen = torch.zeros(len(xyz), device=xyz.device)
    agree = torch.zeros_like(seen)
    width, height = dataset.width, dataset.height
    for view in views:
        T = T_world_camera[view].to(xyz)
        K = dataset.intrinsics[view].to(xyz)
        cam = (xyz - T[:3, 3]) @ T[:3, :3]
        depth = -cam[:, 2]
        safe = torch.where(depth > 1e-6, depth, torch.ones_like(depth))
        u = K[0] * cam[:, 0] / safe + K[2]
        v = -K[1] * cam[:, 1] / safe + K[3]
        inside = (depth > 1e-6) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        col, row = u.long().clamp(0, width - 1), v.long().clamp(0, height - 1)
        if dataset.valid_masks is not None:
            inside &= dataset.valid_masks[view].to(xyz.device)[row, col]
        fruit = dataset.semantic_masks[view].to(xyz.device, torch.float32)[None, None]
        if dilation_px > 0:
            fruit = F.max_pool2d(fruit, 2 * dilation_px + 1, stride=1, padding=dilation_px)
        seen += inside.float()
        agree += (inside & (fruit[0, 0, row, col] > 0)).float()
    return agree / seen.clamp_min(1.0)


def merge_on_voxels(xyz: torch.Tensor, view: torch.Tensor, values: dict[str, torch.Tensor], voxel: float,
                    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]:
    """Average points on a voxel grid.

    Args:
        xyz: [N, 3] points (m).
        view: [N] view each point came from.
        values: per-point features [N, C] (or [N]) averaged per voxel.
        voxel: voxel size (m).

    Returns:
        (voxel mean positions [M, 3], per-voxel mean features, distinct views per voxel [M]).
    """
    lo = xyz.min(0).values
    ijk = torch.floor((xyz - lo) / voxel).long()
    dims = ijk.max(0).values + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    keys, inverse, counts = torch.unique(key, return_inverse=True, return_counts=True)
    m = len(keys)
    weight = counts.to(xyz.dtype)[:, None]
    mean_xyz = xyz.new_zeros(m, 3).index_add_(0, inverse, xyz) / weight
    means = {}
    for name, v in values.items():
        flat = v.reshape(len(v), -1).to(xyz.dtype)
        summed = flat.new_zeros(m, flat.shape[1]).index_add_(0, inverse, flat) / weight
        means[name] = summed.reshape((m,) + tuple(v.shape[1:]))
    pairs = torch.unique(inverse * (int(view.max()) + 1) + view)
    n_views = torch.bincount(pairs // (int(view.max()) + 1), minlength=m)
    return mean_xyz, means, n_views


def _fruit_pixels(masks: torch.Tensor, views: list[int], max_rays: int) -> tuple[torch.Tensor, int]:
    """(view, row, col) [M, 3] of the fruit pixels of ``views``, a seeded uniform subsample of ``max_rays`` of them
    when there are more (drawn view by view: never all pixels of all views at once), and the total count."""
    total = int(sum(int(masks[v].sum()) for v in views))
    keep_share = min(1.0, max_rays / max(total, 1))
    generator = torch.Generator().manual_seed(0)
    out = []
    for view in views:
        rows_cols = torch.nonzero(masks[view])
        if keep_share < 1.0:
            rows_cols = rows_cols[torch.rand(len(rows_cols), generator=generator) < keep_share]
        out.append(torch.cat([torch.full((len(rows_cols), 1), view, dtype=torch.int64), rows_cols], 1))
    return (torch.cat(out) if out else torch.zeros((0, 3), dtype=torch.int64)), total


def _behind_foliage(field: FruitField, grid: OccupancyGrid, settings: RenderSettings, rays: RayBundle,
                    config: ExportConfig) -> tuple[torch.Tensor, ...]:
    """Candidate fruit points along ``rays`` wherever they lie: (ray index [K], position [K, 3], embedding [K, D],
    rgb [K, 3], fruit probability [K], ray direction [K, 3]) of the samples that are dense and fruit. Every sample
    is evaluated (no stop behind an opaque haze: what lies behind it is the point)."""
    samples = march_rays(rays, grid, settings.step, near=settings.near)
    with autocast_for(rays.origins.device, settings.mixed_precision):
        geo = field.geometry(samples.positions)
        alpha = 1.0 - torch.exp(-geo.density.float() * samples.step)
        dense = torch.nonzero(alpha >= config.behind_min_alpha).squeeze(1)
        prob = torch.sigmoid(field.fruit_logit(samples.positions[dense], geo.features[dense]).float())
        fruit = prob >= config.behind_fruit_threshold
        at = dense[fruit]
        xyz, features = samples.positions[at], geo.features[at]
        emb = F.normalize(field.embedding(xyz, features).float(), dim=-1)
        rgb = field.rgb(features, samples.directions[at]).float().clamp(0, 1)
    return samples.ray_index[at], xyz, emb, rgb, prob[fruit], samples.directions[at].float()


@torch.no_grad()
def export_surface_cloud(field: FruitField, grid: OccupancyGrid, settings: RenderSettings, dataset: SceneDataset,
                         T_world_camera: torch.Tensor, fruit_diameter_m: float, config: ExportConfig | None = None, *,
                         views: list[int] | None = None, progress: ProgressCallback | None = None,
                         stop_event: threading.Event | None = None) -> tuple[FruitPointCloud, SurfaceExportReport]:
    """Render the fruit pixels of ``views`` and keep the fruit surfaces several views agree on.

    Args:
        field, grid, settings: the trained field, its occupancy grid and marching settings.
        dataset: the training dataset (fruit masks, intrinsics).
        T_world_camera: [V, 4, 4] the poses the field was trained with (refined ones when pose refinement ran).
        fruit_diameter_m: the scene's fruit diameter (the merge voxel is ``config.voxel_fruit_fraction`` of it).
        config: thresholds (defaults when None).
        views: views to render (default: the training views).
        progress: receives ``export`` phase events.
        stop_event: when set, the export stops and returns what it has (``report.stopped``).
    """
    config = config or ExportConfig()
    progress = progress or ignore_progress
    started = time.perf_counter()
    device = grid.aabb.device
    views = [int(v) for v in (dataset.train_indices if views is None else views)]
    hits, n_pixels = _fruit_pixels(dataset.semantic_masks, views, config.max_rays)   # [M, 3]: (view, row, col)
    view_of = hits[:, 0]
    poses, intrinsics = T_world_camera.to(device), dataset.intrinsics.to(device)
    parts: dict[str, list[torch.Tensor]] = {k: [] for k in ('xyz', 'view', 'emb', 'rgb', 'prob', 'dir', 'footprint')}
    focal = torch.sqrt(intrinsics[:, 0] * intrinsics[:, 1])
    n_opaque = n_fruit = n_behind = 0
    # a ray holds up to box diagonal / step samples before empty-space skipping: bound the samples of a chunk
    per_ray = float(torch.linalg.norm(grid.aabb[1] - grid.aabb[0])) / settings.step
    chunk = max(64, min(config.chunk_rays, int(config.max_chunk_samples / max(per_ray, 1.0))))
    n_chunks = max(1, math.ceil(len(hits) / chunk))
    stopped = False
    for c in range(n_chunks):
        if stop_event is not None and stop_event.is_set():
            stopped = True
            break
        sl = slice(c * chunk, (c + 1) * chunk)
        view = view_of[sl].to(device)
        rays = rays_for_pixels(poses, intrinsics, view, hits[sl, 1].to(device), hits[sl, 2].to(device))
        out = render_rays(field, grid, rays, settings, semantic=True, instance=True, depth=True)
        opaque = (out.opacity >= config.min_opacity) & torch.isfinite(out.depth)
        prob = out.fruit_prob / out.opacity.clamp_min(1e-6)
        fruit = opaque & (prob >= config.surface_fruit_threshold)
        n_opaque += int(opaque.sum())
        n_fruit += int(fruit.sum())
        idx = torch.nonzero(fruit).squeeze(1)
        parts['xyz'].append(rays.origins[idx] + out.depth[idx, None] * rays.directions[idx])
        parts['view'].append(view[idx])
        parts['emb'].append(F.normalize(out.embedding[idx], dim=-1))
        parts['rgb'].append(out.rgb[idx].float().clamp(0, 1))
        parts['prob'].append(prob[idx].clamp(0, 1))
        parts['dir'].append(rays.directions[idx])
        parts['footprint'].append(out.depth[idx] / focal[view[idx]])     # a pixel's width on the surface (m)
        if config.behind_foliage != 'none':
            source = torch.arange(len(view), device=device)
            if config.behind_foliage == 'unsurfaced':
                source = torch.nonzero(~fruit).squeeze(1)
            if len(source):
                ray, xyz, emb, rgb, p, direction = _behind_foliage(
                    field, grid, settings, RayBundle(rays.origins[source], rays.directions[source]), config)
                parts['xyz'].append(xyz)
                parts['view'].append(view[source][ray])
                parts['emb'].append(emb)
                parts['rgb'].append(rgb)
                parts['prob'].append(p)
                parts['dir'].append(direction)
                n_behind += len(ray)
        if (c + 1) % max(1, n_chunks // 20) == 0 or c + 1 == n_chunks:
            progress(ProgressEvent(Phase.EXPORT, c + 1, n_chunks,
                                   f'{n_fruit} fruit surface points, {n_behind} behind foliage'))
    # voxels no finer than a pixel on the fruit: finer ones would hold one view's points each
    footprint = float(torch.cat(parts['footprint']).median()) if n_fruit else 0.0
    voxel = max(config.voxel_fruit_fraction * fruit_diameter_m, config.voxel_pixels * footprint)
    dim = field.embedding_dim
    n_voxels = n_multi = n_kept = 0
    cloud = FruitPointCloud.empty(dim, spacing_m=voxel)
    if n_fruit + n_behind:
        xyz = torch.cat(parts['xyz']).double()
        mean_xyz, means, n_views = merge_on_voxels(
            xyz, torch.cat(parts['view']),
            {'emb': torch.cat(parts['emb']), 'rgb': torch.cat(parts['rgb']), 'prob': torch.cat(parts['prob']),
             'dir': torch.cat(parts['dir'])}, voxel)
        multi = n_views >= config.min_views
        agreement = mask_agreement(mean_xyz[multi].float(), dataset, T_world_camera, views, config.mask_dilation_px)
        kept = multi.clone()
        kept[multi] = agreement >= config.min_mask_agreement
        n_voxels, n_multi, n_kept = len(mean_xyz), int(multi.sum()), int(kept.sum())
        if n_kept:
            emb = F.normalize(means['emb'][kept].float(), dim=-1)
            rgb = (means['rgb'][kept] * 255 + 0.5).clamp(0, 255).to(torch.uint8)
            cloud = FruitPointCloud(mean_xyz[kept].float().cpu().numpy(), rgb.cpu().numpy(),
                                    means['prob'][kept].float().cpu().numpy(), emb.cpu().numpy(), spacing_m=voxel,
                                    view_dir=means['dir'][kept].float().cpu().numpy())
    report = SurfaceExportReport(views=len(views), n_fruit_pixels=n_pixels, n_rays=len(hits), n_opaque=n_opaque,
                                 n_fruit=n_fruit, n_behind=n_behind, n_voxels=n_voxels, n_multi_view=n_multi,
                                 n_kept=n_kept, voxel_size_m=voxel, fruit_diameter_m=fruit_diameter_m,
                                 min_opacity=config.min_opacity, fruit_threshold=config.surface_fruit_threshold,
                                 min_views=config.min_views, min_mask_agreement=config.min_mask_agreement,
                                 stopped=stopped, time_s=time.perf_counter() - started)
    return cloud, report
