"""A trained run loaded back for export: the field, its box, config and occupancy grid."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.config_io import config_from_mapping
from fruitnerfpp_ros.core.device import resolve_device
from fruitnerfpp_ros.core.fields.fruit_field import FruitField
from fruitnerfpp_ros.core.data.scene_scale import SceneScale
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.model import occupancy_grid, render_settings
from fruitnerfpp_ros.core.training.pose_refinement import PoseRefinement
from fruitnerfpp_ros.core.training.run_dir import RunDir
from fruitnerfpp_ros.errors import CheckpointError

__all__ = ['TrainedScene', 'load_trained_scene', 'CHECKPOINT_VERSION', 'SCALE_JSON', 'scale_from_json']

#: Version of the checkpoint layout (3: the scene's fruit scale; 2: nested hash-grid configs, no outer field).
CHECKPOINT_VERSION = 3
#: The run's scale (fruit diameter, fruit region, scene box), written when training starts.
SCALE_JSON = 'scale.json'


def scale_from_json(data: dict) -> SceneScale:
    """The :class:`SceneScale` of its ``to_json`` form."""
    region = data.get('fruit_region')
    return SceneScale(float(data['fruit_diameter_m']), str(data['source']),
                      None if region is None else np.asarray(region, np.float64), int(data['n_fruit_voxels']),
                      int(data['n_masks_measured']), float(data.get('units_per_metre', 1.0)))


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
        scale: the scene's fruit diameter and fruit region.
        pose_corrections: the learned per-view pose corrections (pose refinement on), else None.
    """

    field: FruitField
    aabb: np.ndarray
    config: TrainConfig
    dataset_dir: Path
    completed_stages: int
    occupancy: OccupancyGrid
    scale: SceneScale
    pose_corrections: PoseRefinement | None = None

    @property
    def fruit_diameter_m(self) -> float:
        return self.scale.fruit_diameter_m

    @property
    def march_step(self) -> float:
        """Ray-marching step (m)."""
        return self.config.render.step_m(self.fruit_diameter_m)

    @property
    def render_settings(self) -> RenderSettings:
        """How this run's rays are marched."""
        return render_settings(self.config, self.fruit_diameter_m)

    @property
    def surface_density(self) -> float:
        """Density threshold (1/m) separating surfaces from empty space, for the grid export.

        The smaller of ``ln 2 / step`` (one marching step half opaque: right for a converged, opaque field) and
        the 90th percentile of the occupancy grid's densities (right for briefly trained, semi-transparent
        fields such as the tiny preset's, whose fruit surfaces reach a few 1/m only).
        """
        opaque = self.config.surface_density(self.fruit_diameter_m)
        grid = float(torch.quantile(self.occupancy.values.float().cpu(), 0.9)) / self.march_step
        return min(opaque, grid) if grid > 0 else opaque

    def poses(self, recorded: torch.Tensor) -> torch.Tensor:
        """The camera-to-world poses [V, 4, 4] the run trained with: ``recorded``, corrected when refined."""
        if self.pose_corrections is None:
            return recorded
        with torch.no_grad():
            return self.pose_corrections(recorded.to(self.pose_corrections.correction.device))


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
    stored = dict(state['config'])
    if 'far_field' not in stored.get('field', {}):  # written before the far field existed: its field has none
        stored['field'] = {**stored.get('field', {}), 'far_field': {'samples': 0}}
    if 'box_around' not in stored.get('data', {}):  # ... and before the box around the fruit: the box held the cameras
        stored['data'] = {**stored.get('data', {}), 'box_around': 'fruit_and_cameras'}
    try:
        config = config_from_mapping(TrainConfig, stored)
    except Exception as err:
        raise CheckpointError(f'{run.latest_checkpoint}: stored config is invalid: {err}') from err
    aabb = np.asarray(state['aabb'], dtype=np.float64)
    scale = scale_from_json(state['scale'])
    field = FruitField(config.field, aabb, scale.fruit_diameter_m).to(dev)
    grid = occupancy_grid(config, aabb, scale.fruit_diameter_m).to(dev)
    corrections = None
    try:
        field.load_state_dict(state['field'])
        grid.load_state_dict(state['grid'])
        if state.get('poses') is not None:
            trained = state['poses']['trained']
            corrections = PoseRefinement(trained).to(dev)
            corrections.load_state_dict(state['poses'])
    except RuntimeError as err:
        raise CheckpointError(f'{run.latest_checkpoint}: weights do not match the stored config: {err}') from err
    field.eval()
    for p in field.parameters():
        p.requires_grad_(False)
    return TrainedScene(field, aabb, config, run.find_dataset(state), int(state['stage']), grid, scale,
                        corrections)
