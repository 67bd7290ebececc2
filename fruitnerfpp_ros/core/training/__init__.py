"""Cascaded FruitNeRF++ training (geometry -> semantics -> instance field), checkpoints and run directories.

Public API::

    summary = train(dataset_dir, run_dir, TrainConfig.preset('tiny'), device='auto', resume=False,
                    progress=None, stop_event=None, show_progress=False)
    scene = load_trained_scene(run_dir, device='auto')   # scene.field.query(xyz) -> FieldQuery
"""

from fruitnerfpp_ros.core.training.config import (
    PRESET_NAMES,
    DataConfig,
    GeometryStageConfig,
    InstanceStageConfig,
    RenderConfig,
    SemanticStageConfig,
    TrainConfig,
)
from fruitnerfpp_ros.core.training.metrics import EvalMetrics
from fruitnerfpp_ros.core.training.run_dir import RunDir
from fruitnerfpp_ros.core.training.trained_scene import TrainedScene, load_trained_scene
from fruitnerfpp_ros.core.training.trainer import STAGES, StageSummary, TrainSummary, train

__all__ = ['TrainConfig', 'DataConfig', 'RenderConfig', 'GeometryStageConfig', 'SemanticStageConfig',
           'InstanceStageConfig', 'PRESET_NAMES', 'train', 'load_trained_scene', 'TrainedScene', 'TrainSummary',
           'StageSummary', 'EvalMetrics', 'RunDir', 'STAGES']
