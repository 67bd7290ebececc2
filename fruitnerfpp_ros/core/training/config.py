"""TrainConfig: every hyper-parameter of cascaded training in one typed, frozen, YAML-loadable config.

Presets: ``tiny`` (CPU tests, 96 px scenes in about a minute), ``default`` (GPU), ``paper`` (the paper's long
schedule). ``config/train_<preset>.yaml`` hold the same values as YAML.

Density scale (for the export): densities are in 1/m. A sample of thickness ``render.step`` metres is half
opaque when ``density >= ln 2 / step``: the ``surface_density`` method gives that value for a box, ~34/m for the
tiny preset on the 96 px apple scene. ``TrainedScene.surface_density`` (used by the export) takes the smaller of
it and the 90th percentile of the trained occupancy grid's densities (~2/m for the tiny run). Fields trained
briefly stay semi-transparent: the tiny CPU run measures a median density of ~0.25/m (90th percentile ~1.4/m) at
random points of the box and ~2.4/m median, ~30/m max on the GT fruit surfaces, so export thresholds for tiny runs
should sit near 2-5/m (or a multiple of the box median), with fruit_prob >= 0.9 doing most of the selection.
"""

from __future__ import annotations

import dataclasses

import math
from dataclasses import dataclass
from dataclasses import field as _field

from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig
from fruitnerfpp_ros.core.preset_names import PRESET_NAMES
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['TrainConfig', 'DataConfig', 'RenderConfig', 'GeometryStageConfig', 'SemanticStageConfig',
           'InstanceStageConfig', 'FieldConfig', 'PRESET_NAMES']


@dataclass(frozen=True)
class DataConfig:
    """How the dataset is split and bounded."""

    eval_every: int = 8
    """Hold out every n-th view (views 0, n, 2n...) for evaluation; 0 = no held-out views."""
    aabb: tuple[float, ...] | None = None
    """Optional explicit scene box (xmin, ymin, zmin, xmax, ymax, zmax) in metres; None = derived from the
    cameras and the sparse point cloud (the normal case)."""
    min_view_fraction: float = 0.3
    """A region belongs to the camera-derived box when at least this fraction of the cameras sees it."""
    points_growth: float = 2.0
    """With a sparse point cloud, the box may reach this many times the cloud's extent (about its centre) to hold
    what the cameras see around it."""
    aabb_padding: float = 0.05
    """Derived box grown by this fraction of its largest side on every face."""
    min_fruit_pixels: int = 4
    """Fruit masks with fewer pixels are ignored by the group sampler."""


@dataclass(frozen=True)
class RenderConfig:
    """Ray marching and empty-space skipping."""

    samples_per_ray: int = 768
    """Step = box diagonal / samples_per_ray (metres). The step must stay well below the fruit size: on the
    300-view apple tree (11 m box diagonal) 256 (4.3 cm steps) left held-out semantic IoU at 0.17, 768 (1.4 cm)
    reached 0.41 with a shorter schedule (bench/results/gpu_default_preset.md). Occupancy skipping keeps the
    samples actually evaluated to ~12-25 per ray."""
    near: float = 0.05
    """Minimum sample distance from the camera, metres."""
    occupancy_resolution: int = 192
    """Occupancy grid cells per axis."""
    occupancy_threshold: float = 0.01
    """Optical thickness (density * step) above which an occupancy cell is occupied."""
    occupancy_decay: float = 0.95
    """Decay of the occupancy values per update."""
    occupancy_update_every: int = 16
    """Training steps between occupancy updates (stages 1 and 2)."""
    chunk_rays: int = 8192
    """Rays per chunk when rendering whole images for evaluation."""
    mixed_precision: bool = True
    """bfloat16 autocast for the field on CUDA (ignored on the CPU)."""
    compile: bool = True
    """torch.compile the field's MLP heads on CUDA (ignored on the CPU or when unavailable)."""

    def step_size(self, aabb_diagonal: float) -> float:
        """Ray-marching step in metres for a box of the given diagonal."""
        return aabb_diagonal / self.samples_per_ray


@dataclass(frozen=True)
class GeometryStageConfig:
    """Stage 1: density + colour, uniform rays."""

    iterations: int = 4000
    """Training steps."""
    batch_rays: int = 4096
    """Rays per step."""
    lr: float = 1e-2
    """Adam learning rate (decays exponentially to lr * lr_final_factor)."""
    lr_final_factor: float = 0.1
    """Learning rate at the last step, as a fraction of ``lr``."""
    distortion_weight: float = 0.01
    """Weight of the distortion loss (1/m): pulls each ray's weight together, against floaters and fog."""
    pose_lr: float = 0.0
    """Adam learning rate of the per-view pose corrections (radians, metres; pose_refinement.py), trained in
    stages 1 and 2 and decayed like ``lr``; 0 = the recorded poses are used as they are."""
    pose_start_fraction: float = 0.25
    """The pose corrections start training after this fraction of stage 1 (a first geometry to align to)."""


@dataclass(frozen=True)
class SemanticStageConfig:
    """Stage 2: + fruit semantics, uniform rays, density and colour keep training."""

    iterations: int = 1500
    """Training steps."""
    batch_rays: int = 4096
    """Rays per step."""
    lr: float = 1e-2
    """Adam learning rate of the semantic head (density and colour continue at stage 1's final rate)."""
    lr_final_factor: float = 0.1
    """Learning rate at the last step, as a fraction of ``lr``."""
    semantic_weight: float = 1.0
    """lambda_sem, the weight of the BCE loss."""
    fruit_fraction: float = 0.25
    """Fraction of each batch drawn from fruit pixels (the rest uniformly): fruit is a few percent of an image."""


@dataclass(frozen=True)
class InstanceStageConfig:
    """Stage 3: instance field only (everything else frozen), group sampler, prototype InfoNCE."""

    iterations: int = 2500
    """Training steps."""
    groups: int = 4
    """G, seed fruits per step."""
    group_size: int = 8
    """L, fruits per group (the seed and its L-1 nearest fruits in the image)."""
    pixels_per_fruit: int = 32
    """P, pixels sampled per fruit."""
    temperature: float = 0.2
    """tau of the InfoNCE loss (feasible 0.1-0.3)."""
    lr: float = 1e-2
    """Adam learning rate (decays exponentially to lr * lr_final_factor)."""
    lr_final_factor: float = 0.1
    """Learning rate at the last step, as a fraction of ``lr``."""
    weight_threshold: float = 1e-4
    """Samples with a render weight below this are skipped by the instance head."""
    contrastive_weight: float = 1.0
    """lambda_contr, the weight of the contrastive loss."""


@dataclass(frozen=True)
class TrainConfig:
    """Cascaded FruitNeRF++ training: data, field, rendering, three stages, bookkeeping."""

    data: DataConfig = _field(default_factory=DataConfig)
    """Dataset split and scene box."""
    field: FieldConfig = _field(default_factory=FieldConfig)
    """Field encodings and heads."""
    render: RenderConfig = _field(default_factory=RenderConfig)
    """Ray marching and occupancy grid."""
    geometry: GeometryStageConfig = _field(default_factory=GeometryStageConfig)
    """Stage 1."""
    semantic: SemanticStageConfig = _field(default_factory=SemanticStageConfig)
    """Stage 2."""
    instance: InstanceStageConfig = _field(default_factory=InstanceStageConfig)
    """Stage 3."""
    seed: int = 0
    """Seed of every random source (weights, samplers, jitter)."""
    checkpoint_every: int = 500
    """Steps between periodic checkpoints (a killed run loses at most this many steps)."""
    log_every: int = 50
    """Steps between lines of metrics.jsonl."""
    eval_max_views: int = 8
    """Held-out views rendered for the stage-end evaluation (the first n)."""
    cpu_threads: int = 1
    """torch CPU threads while training on the CPU (0 = keep torch's setting). One thread is the fast choice for
    these small batches: with more, OpenMP barriers collapse when other processes share the cores."""

    def __post_init__(self) -> None:
        for name in ('geometry', 'semantic', 'instance'):
            if getattr(self, name).iterations < 0:
                raise ConfigError(f'{name}.iterations must be >= 0')
        if self.checkpoint_every <= 0 or self.log_every <= 0:
            raise ConfigError('checkpoint_every and log_every must be positive')
        if self.data.aabb is not None and len(self.data.aabb) != 6:
            raise ConfigError('data.aabb needs 6 numbers: xmin ymin zmin xmax ymax zmax')

    def surface_density(self, aabb_diagonal: float) -> float:
        """Density (1/m) at which one ray-marching step is half opaque: a surface / empty-space threshold."""
        return math.log(2.0) / self.render.step_size(aabb_diagonal)

    @classmethod
    def preset(cls, name: str) -> 'TrainConfig':
        """The named preset: ``tiny`` (CPU tests, ~1.5 min), ``cpu`` (a real tree on a CPU, ~5 min), ``default``
        (GPU, minutes) or ``paper`` (long schedule)."""
        if name == 'default':
            return cls()
        if name == 'tiny':
            return cls(
                # A coarse geometry grid (6 levels up to 128 over the box) overfits 21 views of 96 px less than a
                # finer one: held-out PSNR, semantic IoU and the count all improved (docs/results/tiny_preset.md).
                field=FieldConfig(num_levels=6, features_per_level=2, log2_table_size=15, base_resolution=8,
                                  max_resolution=128, hidden_dim=32, density_layers=1, color_layers=1, sh_degree=2,
                                  semantic_layers=1, semantic_num_levels=6, semantic_log2_table_size=15,
                                  semantic_base_resolution=8, semantic_max_resolution=256, embedding_dim=32,
                                  instance_num_levels=6, instance_log2_table_size=15, instance_base_resolution=8,
                                  instance_max_resolution=256, instance_hidden_dim=32, instance_layers=1),
                # A box that reaches further into the ground and sky the cameras see (view fraction 0.1, 3x the
                # sparse points) and 1.4 cm steps (288 per diagonal): floaters that painted the world outside the
                # old box carried fruit probability; seed 2 of the test scene went from F1 0.21 to 0.95.
                data=DataConfig(min_view_fraction=0.1, points_growth=3.0),
                render=RenderConfig(samples_per_ray=288, occupancy_resolution=48, occupancy_update_every=8,
                                    chunk_rays=4096),
                geometry=GeometryStageConfig(iterations=600, batch_rays=640, lr=2e-2),
                # fruit_fraction 0.5 taught a fruit prior of 50 % (fruit is ~5 % of a view): fruit probability
                # >= 0.9 spread over the canopy. 0.15 and 400 steps: held-out IoU 0.28 -> 0.56 / 0.50 / 0.30 on
                # three seeds of the test scene (docs/results/tiny_preset.md).
                semantic=SemanticStageConfig(iterations=400, batch_rays=512, lr=5e-2, fruit_fraction=0.15),
                instance=InstanceStageConfig(iterations=600, groups=4, group_size=8, pixels_per_fruit=24, lr=3e-2),
                checkpoint_every=100, log_every=25, eval_max_views=3)
        if name == 'cpu':
            # The tiny field with 3x the steps and 2x the rays of its geometry and semantic stages: on an
            # 80-apple tree F1 0.52 -> 0.66 (semantic IoU 0.26 -> 0.35); on the test scene's seeds 0 / 1
            # F1 0.97 / 0.88 -> 0.97 / 0.97 (docs/results/tiny_preset.md). About 3x tiny's training time. It
            # refines the poses, as robot odometry needs: with 2 cm / 1 deg noise F1 0.95; exact poses 0.97 -> 0.95.
            tiny = cls.preset('tiny')
            return dataclasses.replace(
                tiny, geometry=dataclasses.replace(tiny.geometry, iterations=1800, batch_rays=1280, pose_lr=3e-4),
                semantic=dataclasses.replace(tiny.semantic, iterations=1200, batch_rays=1024),
                checkpoint_every=200, log_every=50)
        if name == 'paper':
            return cls(
                geometry=GeometryStageConfig(iterations=30000, batch_rays=4096, lr=1e-2),
                semantic=SemanticStageConfig(iterations=10000, batch_rays=4096, lr=1e-2),
                instance=InstanceStageConfig(iterations=20000, groups=8, group_size=8, pixels_per_fruit=32),
                render=RenderConfig(samples_per_ray=1024, occupancy_resolution=256),
                checkpoint_every=2000, log_every=100)
        raise ConfigError(f'unknown training preset {name!r}; expected one of {", ".join(PRESET_NAMES)}')
