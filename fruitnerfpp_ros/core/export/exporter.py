"""Volumetric export: sample a trained field on a uniform grid, keep dense fruit points, attach their features.

The grid is streamed in batches through the field on its own device, so memory grows with the kept points, not
with the grid. A coarse pass (every ``coarse_factor``-th sample) first marks where dense fruit can be; only the
fine samples near marked coarse samples are evaluated. When the field offers ``density_and_fruit_prob``
(the FruitNeRF++ field does), density and fruit probability are computed first and the colour and instance heads
run only on the kept points. An :class:`ExportReport` counts the samples passing each threshold, so an empty
cloud says which threshold removed what.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import asdict, dataclass
from typing import Any, Iterator, NamedTuple

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.fields.query import QueryableField
from fruitnerfpp_ros.core.progress import Phase, ProgressCallback, ProgressEvent, ignore_progress
from fruitnerfpp_ros.errors import ExportError

__all__ = ['ExportReport', 'ExportResult', 'export_fruit_cloud', 'export_grid']


@dataclass(frozen=True)
class ExportReport:
    """What the export sampled and what each threshold removed.

    Attributes:
        grid_shape: samples per axis (x, y, z) of the fine grid.
        voxel_size_m: grid spacing (m).
        aabb: [[xmin, ymin, zmin], [xmax, ymax, zmax]] sampled box (m).
        n_grid: fine grid samples (the whole box).
        n_coarse: coarse-pass samples (0 without a coarse pass).
        n_coarse_dense: coarse samples with density >= ``density_threshold``.
        n_coarse_refined: coarse cells whose fine samples were evaluated (marked cells after dilation).
        n_evaluated: fine samples evaluated (the rest lie far from any dense fruit coarse sample).
        n_dense: samples with density >= ``density_threshold``.
        n_fruit: samples with fruit probability >= ``fruit_threshold`` (regardless of density).
        n_kept: samples passing both (the cloud size).
        density_threshold: 1/m.
        fruit_threshold: probability.
        max_density: largest density seen in either pass (1/m).
        max_fruit_prob_dense: largest fruit probability among the dense samples of either pass (0 when none).
        stopped: the export was interrupted by the stop event (the cloud is partial).
        time_s: wall time.
    """

    grid_shape: tuple[int, int, int]
    voxel_size_m: float
    aabb: list[list[float]]
    n_grid: int
    n_coarse: int
    n_coarse_dense: int
    n_coarse_refined: int
    n_evaluated: int
    n_dense: int
    n_fruit: int
    n_kept: int
    density_threshold: float
    fruit_threshold: float
    max_density: float
    max_fruit_prob_dense: float
    stopped: bool
    time_s: float

    def explain(self) -> str:
        """One line saying how many samples each threshold kept (and, for an empty cloud, why it is empty)."""
        coarse = (f'coarse pass: {self.n_coarse_dense}/{self.n_coarse} samples dense, {self.n_coarse_refined} '
                  'cells refined; ' if self.n_coarse else '')
        line = (f'grid export: {self.n_grid} grid samples (voxel {self.voxel_size_m * 1000:.1f} mm; {coarse}'
                f'{self.n_evaluated} evaluated) -> {self.n_dense} with density >= {self.density_threshold:.3g}/m '
                f'-> {self.n_kept} also with fruit probability >= {self.fruit_threshold:.2f} ({self.n_fruit} pass '
                'the fruit threshold alone)')
        if self.n_kept == 0:
            if self.max_density < self.density_threshold:
                line += (f'; EMPTY: the density threshold removed everything (max density {self.max_density:.3g}/m '
                         f'< {self.density_threshold:.3g}/m): lower density_threshold / density_scale or check the '
                         'training run')
            elif self.max_fruit_prob_dense < self.fruit_threshold:
                line += (f'; EMPTY: the fruit threshold removed all dense samples (max fruit probability among '
                         f'them {self.max_fruit_prob_dense:.2f} < {self.fruit_threshold:.2f}): lower '
                         'fruit_threshold or check the semantic stage / masks')
            else:
                line += ('; EMPTY: no sample passed both thresholds at once (dense samples and fruit samples lie '
                         'apart): check the semantic stage, or lower coarse_*_fraction / coarse_factor')
        return line

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data['grid_shape'] = list(self.grid_shape)
        data['explanation'] = self.explain()
        return data


class ExportResult(NamedTuple):
    """The exported cloud and its report."""

    cloud: FruitPointCloud
    report: ExportReport


DEFAULT_GRID_POINTS = 8_000_000
"""Grid size when neither a voxel size, a grid size nor the scene's marching step is known."""


def export_grid(aabb: np.ndarray, config: ExportConfig, default_voxel_m: float | None = None,
                ) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """The sampled box [2, 3] (crop applied), voxel size (m) and samples per axis.

    The voxel size is ``config.voxel_size_m``, else follows from ``config.grid_points``, else is
    ``default_voxel_m`` (a fraction of the scene's fruit diameter), else follows from :data:`DEFAULT_GRID_POINTS`.

    Raises:
        ExportError: when the box (or its intersection with the crop box) is empty or not finite, or the grid
            would exceed ``config.max_grid_points``.
    """
    box = np.asarray(aabb, np.float64).reshape(2, 3)
    if config.aabb is not None:
        crop = np.asarray(config.aabb, np.float64).reshape(2, 3)
        box = np.stack([np.maximum(box[0], crop[0]), np.minimum(box[1], crop[1])])
    size = box[1] - box[0]
    if not np.all(np.isfinite(box)) or np.any(size <= 0):
        raise ExportError(f'export box {box.tolist()} is empty or not finite (scene box {np.asarray(aabb).tolist()}, '
                          f'crop {config.aabb})')
    if config.voxel_size_m is not None:
        voxel = float(config.voxel_size_m)
    elif config.grid_points is not None or default_voxel_m is None:
        voxel = float((np.prod(size) / (config.grid_points or DEFAULT_GRID_POINTS)) ** (1.0 / 3.0))
    else:
        voxel = float(default_voxel_m)
    shape = tuple(int(v) for v in np.maximum(1, np.round(size / voxel)).astype(np.int64))
    if int(np.prod(shape)) > config.max_grid_points:
        raise ExportError(f'export grid {shape} at voxel {voxel * 1000:.1f} mm exceeds max_grid_points '
                          f'{config.max_grid_points}: set a larger voxel_size_m or a crop box')
    return box, voxel, shape  # type: ignore[return-value]


def _field_device(field: QueryableField) -> torch.device:
    parameters = getattr(field, 'parameters', None)
    if callable(parameters):
        for p in parameters():
            return p.device
    return torch.device('cpu')


def _density_and_fruit(field: QueryableField, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Density [N] and fruit probability [N], through the cheap heads (``density_and_fruit_prob``: no colour, no
    embedding) when the field has them, else through ``query``."""
    cheap = getattr(field, 'density_and_fruit_prob', None)
    if callable(cheap):
        density, fruit_prob = cheap(xyz)
        return density.float(), fruit_prob.float()
    q = field.query(xyz)
    return q.density.float(), q.fruit_prob.float()


def _index_batches(shape: tuple[int, int, int], batch: int, device: torch.device,
                   cells: np.ndarray | None, factor: int) -> Iterator[torch.Tensor]:
    """Fine-grid sample indices [B, 3] (int64): the whole grid, or the fine samples of the given coarse cells."""
    dims = torch.as_tensor(shape, dtype=torch.int64, device=device)
    if cells is None:
        n = int(np.prod(shape))
        for start in range(0, n, batch):
            flat = torch.arange(start, min(n, start + batch), device=device)
            yield torch.stack([flat // (dims[1] * dims[2]), (flat // dims[2]) % dims[1], flat % dims[2]], dim=1)
        return
    offsets = torch.stack(torch.meshgrid(*[torch.arange(factor, device=device)] * 3, indexing='ij'), -1).reshape(-1, 3)
    cells_t = torch.as_tensor(cells, dtype=torch.int64, device=device)
    per_chunk = max(1, batch // len(offsets))
    for start in range(0, len(cells_t), per_chunk):
        ijk = (cells_t[start:start + per_chunk, None, :] * factor + offsets[None]).reshape(-1, 3)
        yield ijk[(ijk < dims).all(dim=1)]


@torch.no_grad()
def export_fruit_cloud(field: QueryableField, aabb: np.ndarray, config: ExportConfig | None = None, *,
                       surface_density: float | None = None, default_voxel_m: float | None = None,
                       progress: ProgressCallback | None = None,
                       stop_event: threading.Event | None = None) -> ExportResult:
    """Sample ``field`` on a uniform grid over ``aabb`` and keep the dense fruit points.

    Args:
        field: the trained field (queried in batches on its own device).
        aabb: [2, 3] scene box (m).
        config: grid and thresholds (defaults when None).
        surface_density: the scene's surface density (1/m) used when ``config.density_threshold`` is None.
        default_voxel_m: the voxel size when the config sets none (see :func:`export_grid`).
        progress: receives ``export:coarse`` (once) and ``export`` phase events.
        stop_event: when set, the export stops early and returns the points so far (``report.stopped``).

    Returns:
        The fruit point cloud (xyz m, rgb uint8, fruit probability, unit embeddings) and the report.

    Raises:
        ExportError: on an empty box, a field answering with wrong shapes, or more than ``max_points`` points.
    """
    config = config or ExportConfig()
    progress = progress or ignore_progress
    if config.density_threshold is not None:
        density_threshold = float(config.density_threshold)
    elif surface_density is not None:
        density_threshold = float(surface_density) * config.density_scale
    else:
        raise ExportError('export needs ExportConfig.density_threshold or the scene surface density; neither given')
    box, voxel, shape = export_grid(aabb, config, default_voxel_m)
    device = _field_device(field)
    lo = torch.as_tensor(box[0], dtype=torch.float32, device=device)
    dim = int(field.embedding_dim)
    start_time = time.perf_counter()

    def points(ijk: torch.Tensor) -> torch.Tensor:
        return lo + (ijk.to(torch.float32) + 0.5) * voxel

    # coarse pass: which coarse cells may hold dense fruit
    factor = config.coarse_factor
    cells = None
    n_coarse = 0
    coarse_max_density = coarse_max_fruit = 0.0
    n_coarse_dense = 0
    if factor > 1:
        coarse_shape = tuple(int(math.ceil(s / factor)) for s in shape)
        n_coarse = int(np.prod(coarse_shape))
        marks = []
        for ijk in _index_batches(coarse_shape, config.batch_size, device, None, 1):
            if stop_event is not None and stop_event.is_set():
                break
            fine = (ijk * factor + factor // 2).clamp(max=torch.as_tensor(shape, device=device) - 1)
            density, fruit_prob = _density_and_fruit(field, points(fine))
            coarse_max_density = max(coarse_max_density, float(density.max()))
            coarse_dense = density >= density_threshold
            n_coarse_dense += int(coarse_dense.sum())
            if bool(coarse_dense.any()):
                coarse_max_fruit = max(coarse_max_fruit, float(fruit_prob[coarse_dense].max()))
            marks.append(((density >= config.coarse_density_fraction * density_threshold)
                          & (fruit_prob >= config.coarse_fruit_fraction * config.fruit_threshold)).cpu().numpy())
        marked = np.zeros(n_coarse, bool)
        done = np.concatenate(marks) if marks else np.zeros(0, bool)
        marked[:len(done)] = done
        marked = binary_dilation(marked.reshape(coarse_shape), np.ones((3, 3, 3), bool))
        cells = np.argwhere(marked)
        progress(ProgressEvent(Phase.EXPORT_COARSE, 1, 1, f'{len(cells)}/{n_coarse} cells to refine'))

    n_grid = int(np.prod(shape))
    n_todo = n_grid if cells is None else len(cells) * factor ** 3
    n_batches = max(1, math.ceil(n_todo / config.batch_size))
    kept: list[tuple[np.ndarray, ...]] = []
    n_evaluated = n_dense = n_fruit = n_kept = 0
    max_density = coarse_max_density  # the coarse pass's maxima explain an empty export pruned there
    max_fruit_dense = coarse_max_fruit
    stopped = False
    for b, ijk in enumerate(_index_batches(shape, config.batch_size, device, cells, factor)):
        if stop_event is not None and stop_event.is_set():
            stopped = True
            break
        if len(ijk) == 0:
            continue
        xyz = points(ijk)
        n = len(xyz)
        density, fruit_prob = _density_and_fruit(field, xyz)
        if density.shape != (n,) or fruit_prob.shape != (n,):
            raise ExportError(f'field returned density {tuple(density.shape)} / fruit_prob '
                              f'{tuple(fruit_prob.shape)} for {n} points')
        dense = density >= density_threshold
        fruit = fruit_prob >= config.fruit_threshold
        both = dense & fruit
        n_evaluated += n
        n_dense += int(dense.sum())
        n_fruit += int(fruit.sum())
        n_both = int(both.sum())
        n_kept += n_both
        max_density = max(max_density, float(density.max()))
        if bool(dense.any()):
            max_fruit_dense = max(max_fruit_dense, float(fruit_prob[dense].max()))
        if n_kept > config.max_points:
            raise ExportError(f'export kept more than max_points={config.max_points} points (density >= '
                              f'{density_threshold:.3g}/m, fruit probability >= {config.fruit_threshold}); raise '
                              'the thresholds or the voxel size')
        if n_both:
            q = field.query(xyz[both])
            if q.rgb.shape != (n_both, 3) or q.embedding.shape != (n_both, dim):
                raise ExportError(f'field.query returned rgb {tuple(q.rgb.shape)}, embedding '
                                  f'{tuple(q.embedding.shape)} for {n_both} points (embedding_dim {dim})')
            emb = torch.nn.functional.normalize(q.embedding.float(), dim=1)
            rgb = (q.rgb.float().clamp(0, 1) * 255 + 0.5).to(torch.uint8)
            kept.append((xyz[both].cpu().numpy(), rgb.cpu().numpy(), fruit_prob[both].cpu().numpy(),
                         emb.cpu().numpy()))
        if (b + 1) % max(1, n_batches // 20) == 0:
            progress(ProgressEvent(Phase.EXPORT, b + 1, n_batches, f'{n_kept} fruit points'))
    progress(ProgressEvent(Phase.EXPORT, n_batches, n_batches, f'{n_kept} fruit points'))
    if kept:
        cloud = FruitPointCloud(*(np.ascontiguousarray(np.concatenate(parts)) for parts in zip(*kept)),
                                spacing_m=voxel)
    else:
        cloud = FruitPointCloud.empty(dim, spacing_m=voxel)
    report = ExportReport(grid_shape=shape, voxel_size_m=voxel, aabb=box.tolist(), n_grid=n_grid, n_coarse=n_coarse,
                          n_coarse_dense=n_coarse_dense, n_coarse_refined=0 if cells is None else len(cells),
                          n_evaluated=n_evaluated, n_dense=n_dense, n_fruit=n_fruit, n_kept=n_kept,
                          density_threshold=density_threshold, fruit_threshold=config.fruit_threshold,
                          max_density=max_density, max_fruit_prob_dense=max_fruit_dense,
                          stopped=stopped or (stop_event is not None and stop_event.is_set()),
                          time_s=time.perf_counter() - start_time)
    return ExportResult(cloud, report)
