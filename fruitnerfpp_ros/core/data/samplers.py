"""Pixel samplers: uniform rays for colour/semantics, groups of neighbouring fruits for the instance field.

Both draw from one ``torch.Generator`` owned by the caller, so a checkpoint of the generator state makes training
resumable bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from fruitnerfpp_ros.core.data.rays import PixelBatch
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['UniformPixelSampler', 'GroupInstanceSampler', 'ViewFruits', 'index_view_fruits', 'mask_interior']


class UniformPixelSampler:
    """Pixels drawn uniformly over the valid pixels of the given views (with replacement).

    With ``fruit_masks`` and ``fruit_fraction > 0``, that fraction of every batch is drawn uniformly from the fruit
    pixels instead (fruit covers a few percent of an orchard image: without this a batch holds a handful of them).
    The uniform part comes first in every batch (:meth:`num_uniform`); with ``background_masks``, its last
    ``background_fraction`` comes from those pixels.

    Args:
        views: [V'] view indices to draw from.
        height, width: image size.
        fruit_masks: [V, H, W] bool fruit pixels (already False where a pixel is invalid), or None.
        fruit_fraction: share of a batch drawn from fruit pixels.
        valid_masks: [V, H, W] bool, False on pixels without data (never drawn); None = all valid.
        background_masks: [V, H, W] bool pixels (e.g. those whose rays miss the scene box) from which
            ``background_fraction`` of the uniform rays are drawn instead of from ``valid_masks`` (at most their
            share of the pixels); None = none.
    """

    def __init__(self, views: torch.Tensor, height: int, width: int, *, fruit_masks: torch.Tensor | None = None,
                 fruit_fraction: float = 0.0, valid_masks: torch.Tensor | None = None,
                 background_masks: torch.Tensor | None = None, background_fraction: float = 0.0) -> None:
        if len(views) == 0:
            raise DatasetError('no training views to sample rays from')
        self._views = views.to(torch.int64)
        self._height = height
        self._width = width
        self._valid = None if valid_masks is None else valid_masks.reshape(len(valid_masks), -1).to(torch.bool)
        if self._valid is not None and not bool(self._valid[self._views].any()):
            raise DatasetError('no valid pixel in the training views (every pixel is masked out)')
        self._fruit_pixels = torch.zeros(0, dtype=torch.int64)
        if fruit_masks is not None and fruit_fraction > 0:
            flat = fruit_masks.reshape(len(fruit_masks), -1)
            self._fruit_pixels = self._pool(flat if self._valid is None else flat & self._valid)
        self._fruit_fraction = fruit_fraction if len(self._fruit_pixels) else 0.0
        self._background_pixels = torch.zeros(0, dtype=torch.int64)
        self._background_fraction = 0.0
        if background_masks is not None and background_fraction > 0:
            self._background_pixels = self._pool(background_masks.reshape(len(background_masks), -1))
            # never more than the background's own share of the pixels (a box that a few pixels miss draws none)
            drawn = len(self._background_pixels)
            uniform = len(self._views) * height * width if self._valid is None else int(self._valid[self._views].sum())
            self._background_fraction = min(background_fraction, drawn / max(drawn + uniform, 1))

    def _pool(self, flat_masks: torch.Tensor) -> torch.Tensor:
        """The True pixels of ``flat_masks`` [V, H * W] in the sampled views, as view * H * W + flat pixel."""
        hits = torch.nonzero(flat_masks[self._views])  # [M, 2]: (position in views, flat pixel)
        return self._views[hits[:, 0]] * (self._height * self._width) + hits[:, 1]

    def num_uniform(self, batch_size: int) -> int:
        """How many of a ``batch_size`` batch are drawn uniformly: they come first, the fruit pixels after."""
        return batch_size - int(round(batch_size * self._fruit_fraction))

    def _uniform(self, count: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """``count`` (view, flat pixel) pairs, uniform over the valid pixels (rejection sampling: invalid draws are
        drawn again; without invalid pixels the first draw is the batch)."""
        views, pixels = [], []
        need = count
        while need > 0:
            view = self._views[torch.randint(len(self._views), (need,), generator=generator)]
            pixel = torch.randint(self._height * self._width, (need,), generator=generator)
            if self._valid is not None:
                keep = self._valid[view, pixel]
                view, pixel = view[keep], pixel[keep]
            views.append(view)
            pixels.append(pixel)
            need -= len(view)
        return torch.cat(views), torch.cat(pixels)

    def _from(self, pool: torch.Tensor, count: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """``count`` (view, flat pixel) pairs drawn uniformly from ``pool`` (view * H * W + flat pixel)."""
        chosen = pool[torch.randint(len(pool), (count,), generator=generator)]
        return chosen // (self._height * self._width), chosen % (self._height * self._width)

    def sample(self, batch_size: int, generator: torch.Generator) -> PixelBatch:
        n_uniform = self.num_uniform(batch_size)
        n_fruit = batch_size - n_uniform
        n_background = int(round(n_uniform * self._background_fraction))
        view, pixel = self._uniform(n_uniform - n_background, generator)
        for pool, count in ((self._background_pixels, n_background), (self._fruit_pixels, n_fruit)):
            if count:
                more_view, more_pixel = self._from(pool, count, generator)
                view, pixel = torch.cat([view, more_view]), torch.cat([pixel, more_pixel])
        return PixelBatch(view, pixel // self._width, pixel % self._width)


def mask_interior(instance_masks: torch.Tensor, fruit_masks: torch.Tensor) -> torch.Tensor:
    """[V, H, W] bool: the fruit pixels whose four neighbours show the same fruit (beyond the image edge counts as
    the same), and every pixel of a fruit that has no such pixel in its view (a fruit a few pixels wide keeps all).

    Args:
        instance_masks: [V, H, W] int instance ids, 0 = background.
        fruit_masks: [V, H, W] bool fruit pixels (the sampler's; a pixel outside it is never kept).
    """
    ids = torch.nn.functional.pad(instance_masks[:, None].to(torch.int64), (1, 1, 1, 1), mode='replicate')[:, 0]
    centre = ids[:, 1:-1, 1:-1]
    interior = fruit_masks & (centre > 0)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        interior &= ids[:, dy:dy + centre.shape[1], dx:dx + centre.shape[2]] == centre
    views = torch.arange(len(centre))[:, None, None].expand_as(centre)
    key = views * (int(centre.max()) + 1) + centre                               # (view, fruit) as one number
    lost = fruit_masks & ~torch.isin(key, key[interior])                         # fruits erosion would remove
    return interior | lost


@dataclass(frozen=True)
class ViewFruits:
    """The fruits of one view's instance mask, indexed for fast pixel sampling.

    Attributes:
        view: view index in the dataset.
        counts: [F] pixels per fruit.
        offsets: [F] start of each fruit's pixels in ``pixels``.
        pixels: [sum(counts)] flat pixel indices (row * W + col), grouped by fruit.
        neighbours: [F, F] fruit indices sorted by 2D centroid distance (itself first).
    """

    view: int
    counts: torch.Tensor
    offsets: torch.Tensor
    pixels: torch.Tensor
    neighbours: torch.Tensor


def index_view_fruits(view: int, instance_mask: torch.Tensor, min_pixels: int = 4) -> ViewFruits | None:
    """Index the fruits (ids > 0 with at least ``min_pixels`` pixels) of one [H, W] instance mask.

    Returns None when the view has fewer than two such fruits (nothing to contrast).
    """
    width = instance_mask.shape[1]
    flat = instance_mask.reshape(-1).to(torch.int64)
    fg = torch.nonzero(flat > 0).squeeze(1)
    if len(fg) == 0:
        return None
    ids, inverse, counts = torch.unique(flat[fg], return_inverse=True, return_counts=True)
    big = counts >= min_pixels
    if int(big.sum()) < 2:
        return None
    keep = big[inverse]
    fg, inverse = fg[keep], inverse[keep]
    # Number fruits by their first pixel in raster order, not by their id: the sampler then draws exactly the
    # same pixels whatever labels a segmenter gave (relabelling a view changes nothing).
    first = torch.full((len(ids),), flat.numel(), dtype=torch.int64).scatter_reduce(0, inverse, fg, 'amin')
    rank = torch.empty_like(first)
    kept_ids = torch.nonzero(big).squeeze(1)
    rank[kept_ids[torch.argsort(first[kept_ids])]] = torch.arange(len(kept_ids))
    label = rank[inverse]
    order = torch.argsort(label, stable=True)
    pixels = fg[order]
    counts = torch.bincount(label, minlength=int(big.sum()))
    offsets = torch.cumsum(counts, 0) - counts
    rows = (fg // width).to(torch.float64)
    cols = (fg % width).to(torch.float64)
    n = len(counts)
    cy = torch.zeros(n, dtype=torch.float64).index_add_(0, label, rows) / counts
    cx = torch.zeros(n, dtype=torch.float64).index_add_(0, label, cols) / counts
    centres = torch.stack([cy, cx], 1)
    dist = torch.cdist(centres, centres)
    dist.fill_diagonal_(-1.0)
    neighbours = torch.argsort(dist, dim=1, stable=True)
    return ViewFruits(view, counts, offsets, pixels, neighbours)


class GroupInstanceSampler:
    """The FruitNeRF++ group sampler: one image per step, G seed fruits each with its L-1 nearest fruits.

    Fruits are compared only within one image (per-image labels). ``P`` pixels are drawn per fruit; background
    pixels are never returned. Fruits shared by two groups are kept once.
    """

    def __init__(self, views: torch.Tensor, instance_masks: torch.Tensor, *, groups: int, group_size: int,
                 pixels_per_fruit: int, min_pixels: int = 4) -> None:
        self._width = int(instance_masks.shape[2])
        self._views = [v for v in (index_view_fruits(int(i), instance_masks[int(i)], min_pixels) for i in views)
                       if v is not None]
        if not self._views:
            raise DatasetError('no training view has two or more fruits in its instance mask: '
                               'cannot train the instance field')
        self.groups = groups
        self.group_size = group_size
        self.pixels_per_fruit = pixels_per_fruit

    @property
    def num_views(self) -> int:
        return len(self._views)

    def sample(self, generator: torch.Generator) -> PixelBatch:
        fruits = self._views[int(torch.randint(len(self._views), (1,), generator=generator))]
        n = len(fruits.counts)
        seeds = torch.randperm(n, generator=generator)[:min(self.groups, n)]
        members = fruits.neighbours[seeds, :min(self.group_size, n)].reshape(-1)
        chosen = torch.unique(members)  # sorted, duplicates removed
        f = len(chosen)
        draws = torch.rand((f, self.pixels_per_fruit), generator=generator, dtype=torch.float64)
        local = (draws * fruits.counts[chosen, None]).to(torch.int64)
        flat = fruits.pixels[fruits.offsets[chosen, None] + local].reshape(-1)
        label = torch.arange(f).repeat_interleave(self.pixels_per_fruit)
        view = torch.full_like(flat, fruits.view)
        return PixelBatch(view, flat // self._width, flat % self._width, label)
