"""Configuration of the volumetric export of the fruit point cloud."""

from __future__ import annotations

from dataclasses import dataclass

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['ExportConfig']


@dataclass(frozen=True)
class ExportConfig:
    """How the trained field is sampled into a fruit point cloud.

    A uniform grid of cell centres covers the scene box; a sample is kept when its density and its fruit
    probability both pass their thresholds.
    """

    voxel_size_m: float | None = None
    """Grid spacing in metres. None: ``grid_points`` when set, else the trained scene's ray-marching step (the
    finest spacing at which rendering constrained the density; about 1.4 cm on the 300-view apple tree with the
    default preset, 2 cm on the tiny scene), else a grid of 8M samples."""

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
