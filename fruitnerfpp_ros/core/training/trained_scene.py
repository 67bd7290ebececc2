"""A trained run loaded back for export: the field, its box, config and occupancy grid."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.config_io import config_from_mapping
from fruitnerfpp_ros.core.device import resolve_device
from fruitnerfpp_ros.core.fields.fruit_field import FruitField
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.run_dir import RunDir
from fruitnerfpp_ros.errors import CheckpointError

__all__ = ['TrainedScene', 'load_trained_scene', 'CHECKPOINT_VERSION']

#: Version of the checkpoint layout (2: nested hash-grid configs, no outer field, no global random states).
CHECKPOINT_VERSION = 2


@dataclass(frozen=True)
class TrainedScene:
    """A trained field ready for export.

    Attributes:
        field: the field (eval mode, no grad needed); satisfies ``QueryableField``.
        aabb: [2, 3] float64 scene box, metres (world frame of the dataset).
        config: the resolved training config.
        dataset_dir: the dataset it was trained on.
        completed_stages: stages finished (3 for a complete run).
        occupancy: the final occupancy grid (cells with density), on the field's device.
    """

    field: FruitField
    aabb: np.ndarray
    config: TrainConfig
    dataset_dir: Path
    completed_stages: int
    occupancy: OccupancyGrid

    @property
    def march_step(self) -> float:
        """Ray-marching step (m) of the scene box: the default export voxel size."""
        return self.config.render.step_size(float(np.linalg.norm(self.aabb[1] - self.aabb[0])))

    @property
    def surface_density(self) -> float:
        """Density threshold (1/m) separating surfaces from empty space, for the export.

        The smaller of ``ln 2 / step`` (one marching step half opaque: right for a converged, opaque field) and
        the 90th percentile of the occupancy grid's densities (right for briefly trained, semi-transparent
        fields such as the tiny preset's, whose fruit surfaces reach a few 1/m only).
        """
        opaque = self.config.surface_density(float(np.linalg.norm(self.aabb[1] - self.aabb[0])))
        grid = float(torch.quantile(self.occupancy.values.float().cpu(), 0.9)) / self.march_step
        return min(opaque, grid) if grid > 0 else opaque


def load_trained_scene(run_dir: str | Path, device: str = 'auto') -> TrainedScene:
    """Load the field of a run directory (its latest checkpoint) for export.

    Raises:
        CheckpointError: no run or checkpoint in ``run_dir``, or an unreadable / incompatible one.
    """
    run = RunDir(run_dir)
    if not run.latest_checkpoint.is_file():
        raise CheckpointError(f'{run.latest_checkpoint}: not found; is {run.root} a training run directory?')
    dev = resolve_device(device)
    state = load_checkpoint(run.latest_checkpoint, device=dev)
    if state.get('version') != CHECKPOINT_VERSION:
        raise CheckpointError(f'{run.latest_checkpoint}: checkpoint version {state.get("version")} is not '
                              f'{CHECKPOINT_VERSION} (written by another release); train the run again')
    try:
        config = config_from_mapping(TrainConfig, state['config'])
    except Exception as err:
        raise CheckpointError(f'{run.latest_checkpoint}: stored config is invalid: {err}') from err
    aabb = np.asarray(state['aabb'], dtype=np.float64)
    field = FruitField(config.field, aabb).to(dev)
    grid = OccupancyGrid(torch.as_tensor(aabb, dtype=torch.float32), resolution=config.render.occupancy_resolution,
                         threshold=config.render.occupancy_threshold, decay=config.render.occupancy_decay).to(dev)
    try:
        field.load_state_dict(state['field'])
        grid.load_state_dict(state['grid'])
    except RuntimeError as err:
        raise CheckpointError(f'{run.latest_checkpoint}: weights do not match the stored config: {err}') from err
    field.eval()
    for p in field.parameters():
        p.requires_grad_(False)
    return TrainedScene(field, aabb, config, Path(state['dataset_dir']), int(state['stage']), grid)
