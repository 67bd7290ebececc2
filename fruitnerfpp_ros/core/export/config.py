"""Configuration of the volumetric export of the fruit point cloud."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['ExportConfig']


@dataclass(frozen=True)
class ExportConfig:
    """How the trained field is sampled into a fruit point cloud.

    ``surface`` (default, core/export/surface.py): the fruit pixels of the training views are rendered; where a
    ray terminates on fruit is a surface point; points are merged on voxels of ``voxel_fruit_fraction`` fruit
    diameters and kept where ``min_views`` views agree. ``grid``: a uniform grid of cell centres covers the scene box;
    a sample is kept when its density and its fruit probability both pass their thresholds.
    """

    method: Literal['surface', 'grid'] = 'surface'
    """``surface``: fruit surfaces seen from the training views; ``grid``: the volume on a uniform grid."""

    voxel_fruit_fraction: float = 0.125
    """Export voxel in fruit diameters (surface merge voxel; also the grid spacing when ``voxel_size_m`` and
    ``grid_points`` are not set)."""

    voxel_pixels: float = 1.0
    """Surface: the merge voxel is at least this many pixel footprints on the fruit (median distance of the fruit
    surface points from their camera over the focal length): points of one view are a footprint apart, so finer
    voxels would hold one view's points each."""

    min_opacity: float = 0.5
    """Surface: a fruit ray gives a point only when its rendered opacity reaches this (no point from fog)."""

    surface_fruit_threshold: float = 0.5
    """Surface: ... and when the fruit probability it renders (normalised by its opacity) reaches this."""

    min_views: int = 2
    """Surface: a voxel is kept when points of at least this many views fall in it."""

    min_mask_agreement: float = 0.3
    """Surface: ... and when it lies on a fruit pixel in at least this fraction of the training views it projects
    into (fog and leaves in front of a fruit drift off the other views' fruit masks)."""

    mask_dilation_px: int = 2
    """Surface: fruit masks are grown by this many pixels for that test (poses and masks are not exact)."""

    behind_foliage: Literal['none', 'unsurfaced', 'all'] = 'unsurfaced'
    """Surface: also the fruit a ray passes behind foliage. Along a fruit ray, every sample whose one-step opacity
    reaches ``behind_min_alpha`` and whose fruit probability reaches ``behind_fruit_threshold`` is a candidate point,
    whatever lies in front of it, and meets the same voxel tests (views, mask agreement) as the surface points.
    ``unsurfaced``: only along the rays that gave no surface point; ``all``: along every fruit ray."""

    behind_min_alpha: float = 0.3
    """Surface, behind foliage: a candidate's one-step opacity, 1 - exp(-density x step)."""

    behind_fruit_threshold: float = 0.8
    """Surface, behind foliage: a candidate's fruit probability."""

    max_rays: int = 4_000_000
    """Surface: at most this many fruit pixels are rendered (a seeded subsample beyond)."""

    chunk_rays: int = 8192
    """Surface: rays rendered per batch at most."""

    max_chunk_samples: int = 2_000_000
    """Surface: ... and fewer when rays are long: a batch's rays hold at most this many samples before empty-space
    skipping (bounds memory: a 7 m box at 1.4 cm steps is 500 samples per ray)."""

    voxel_size_m: float | None = None
    """Grid: spacing in metres. None: ``grid_points`` when set, else ``voxel_fruit_fraction`` fruit diameters."""

    grid_points: int | None = None
    """Target number of grid samples over the box (the voxel size follows from the box volume); used when
    ``voxel_size_m`` is not set. Only the coarse pass (``samples / coarse_factor^3``) covers the whole box."""

    max_grid_points: int = 2_000_000_000
    """Safety cap on the fine grid's size (an ExportError names the voxel size when exceeded)."""

    density_threshold: float | None = None
    """Minimum density (1/m). None: the trained scene's surface density, ``ln 2 / ray-marching step``, where one
    marching step is half opaque (see ``TrainConfig.surface_density``)."""

    density_scale: float = 1.0
    """Multiplier applied to the automatic density threshold (ignored when ``density_threshold`` is set)."""

    fruit_threshold: float = 0.9
    """Minimum fruit probability (sigmoid of the semantic logit), in [0, 1]."""

    coarse_factor: int = 4
    """Coarse-to-fine: a first pass samples every ``coarse_factor``-th grid point; only fine samples in coarse
    cells near (one coarse cell dilation) a coarse sample with density >= ``coarse_density_fraction`` x threshold
    and fruit probability >= ``coarse_fruit_fraction`` x threshold are evaluated. 1 evaluates the whole grid."""

    coarse_density_fraction: float = 0.1
    """Share of the density threshold a coarse sample needs to mark its neighbourhood."""

    coarse_fruit_fraction: float = 0.5
    """Share of the fruit threshold a coarse sample needs to mark its neighbourhood."""

    batch_size: int = 131072
    """Grid samples per field query (bounds GPU/CPU memory; results are streamed)."""

    aabb: tuple[float, ...] | None = None
    """Optional crop box ``xmin ymin zmin xmax ymax zmax`` (m) intersected with the scene box."""

    max_points: int = 5_000_000
    """Safety cap on kept points (an ExportError names the thresholds when exceeded)."""

    def __post_init__(self) -> None:
        if self.grid_points is not None and self.grid_points < 1000:
            raise ConfigError('ExportConfig: grid_points must be >= 1000')
        if self.voxel_size_m is not None and not self.voxel_size_m > 0:
            raise ConfigError('ExportConfig: voxel_size_m must be > 0')
        if self.density_threshold is not None and self.density_threshold < 0:
            raise ConfigError('ExportConfig: density_threshold must be >= 0')
        if not self.density_scale > 0:
            raise ConfigError('ExportConfig: density_scale must be > 0')
        if not 0.0 <= self.fruit_threshold <= 1.0:
            raise ConfigError('ExportConfig: fruit_threshold must be in [0, 1]')
        if self.coarse_factor < 1:
            raise ConfigError('ExportConfig: coarse_factor must be >= 1')
        if not (0 <= self.coarse_density_fraction <= 1 and 0 <= self.coarse_fruit_fraction <= 1):
            raise ConfigError('ExportConfig: coarse_density_fraction and coarse_fruit_fraction must be in [0, 1]')
        if self.batch_size < 1:
            raise ConfigError('ExportConfig: batch_size must be >= 1')
        if self.aabb is not None and len(self.aabb) != 6:
            raise ConfigError('ExportConfig: aabb needs 6 numbers: xmin ymin zmin xmax ymax zmax')
        if self.max_points < 1:
            raise ConfigError('ExportConfig: max_points must be >= 1')
        if not 0 < self.voxel_fruit_fraction <= 2 or self.voxel_pixels < 0:
            raise ConfigError('ExportConfig: voxel_fruit_fraction must be in (0, 2] and voxel_pixels >= 0')
        if not (0 <= self.min_opacity <= 1 and 0 <= self.surface_fruit_threshold <= 1):
            raise ConfigError('ExportConfig: min_opacity and surface_fruit_threshold must be in [0, 1]')
        if not 0 <= self.min_mask_agreement <= 1 or self.mask_dilation_px < 0:
            raise ConfigError('ExportConfig: min_mask_agreement must be in [0, 1] and mask_dilation_px >= 0')
        if self.behind_foliage not in ('none', 'unsurfaced', 'all'):
            raise ConfigError('ExportConfig: behind_foliage must be none, unsurfaced or all, '
                              f'not {self.behind_foliage!r}')
        if not (0 < self.behind_min_alpha <= 1 and 0 <= self.behind_fruit_threshold <= 1):
            raise ConfigError('ExportConfig: behind_min_alpha must be in (0, 1] and behind_fruit_threshold in [0, 1]')
        if self.min_views < 1 or self.max_rays < 1 or self.chunk_rays < 1 or self.max_chunk_samples < 1:
            raise ConfigError('ExportConfig: min_views, max_rays and chunk_rays must be >= 1')
