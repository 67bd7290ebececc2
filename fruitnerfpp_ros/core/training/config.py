"""TrainConfig: every hyper-parameter of cascaded training in one typed, frozen, YAML-loadable config.

Presets (``presets.py``): ``tiny`` (CPU tests, 96 px scenes in about a minute), ``cpu``, ``default`` (GPU),
``paper`` (the paper's long schedule). ``config/train_<preset>.yaml`` hold the same values as YAML.

Scale: every length follows from the scene's fruit diameter d (``scale``, measured from the masks and poses before
training: core/data/scene_scale.py): the marching step, the occupancy and hash-grid cells. The scene box is the
fruit region found by the same measurement plus ``data.box_margin_m`` (within where the cameras' views overlap);
the far field holds what lies beyond it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as _field
from typing import Any

from fruitnerfpp_ros.core.data.pass_registration import PassRegistrationConfig
from fruitnerfpp_ros.core.data.pose_alignment import PoseAlignmentConfig
from fruitnerfpp_ros.core.data.scene_scale import ScaleConfig
from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig, HashGridConfig
from fruitnerfpp_ros.core.preset_names import PRESET_NAMES  # noqa: F401 - re-exported
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['TrainConfig', 'DataConfig', 'RenderConfig', 'StageSchedule', 'GeometryStageConfig',
           'SemanticStageConfig', 'InstanceStageConfig', 'OptimizerConfig', 'DepthConfig', 'FieldConfig',
           'HashGridConfig', 'ScaleConfig', 'PRESET_NAMES']


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
    box_margin_m: float | None = 0.5
    """The camera-derived box is cut to the fruit region (where the fruit masks of many views agree, see ``scale``),
    and to the cameras unless ``box_around`` is ``fruit``, grown by this margin (m) (training/scene_box.py). None
    keeps the whole camera-derived box."""
    box_around: str = 'fruit'
    """What the cut box holds: ``fruit`` (the fruit region alone on every axis: the cameras, the ground and what lies
    past the tree are left to the far field, ``field.far_field``, which it needs) or ``fruit_and_cameras`` (the
    fruit region and the cameras across (x, y), the camera box's full height: the box before the far field). On
    the suite ``fruit`` trained 2-4x faster (plum row: 1.9 x 2.9 x 1.9 m against 4.9 x 5.1 x 5.6 m) and counted
    better on most scenes (docs/results/accuracy_suite.md)."""
    min_fruit_pixels: int = 4
    """Fruit masks with fewer pixels are ignored by the group sampler."""
    rays_through_box: bool = True
    """The geometry and semantic stages draw their uniform rays among the pixels whose rays pass through the scene
    box (a ray that misses it meets only the far field and trains nothing in the box), but for
    ``outside_box_fraction``. On a hemisphere every pixel does; on the suite's row drives 23-67 % do
    (docs/results/accuracy_suite.md)."""
    outside_box_fraction: float = 0.1
    """With ``rays_through_box``: this share of the uniform rays (at most those pixels' own share) comes from the
    pixels whose rays miss the box, so the far field still learns the backdrop (ground, sky) the held-out views
    show there."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.outside_box_fraction < 1.0:
            raise ConfigError(f'data.outside_box_fraction must be in [0, 1), got {self.outside_box_fraction}')


@dataclass(frozen=True)
class RenderConfig:
    """Ray marching and empty-space skipping."""

    step: float = 0.19
    """Ray-marching step in fruit diameters (0.19 d = 1.4 cm for 7.5 cm apples). The step must stay well below the
    fruit size: on the 300-view apple tree 4.3 cm steps (0.57 d) left held-out semantic IoU at 0.17, 1.4 cm reached
    0.41 with a shorter schedule (bench/results/gpu_default_preset.md). Occupancy skipping keeps the samples
    actually evaluated to ~12-25 per ray."""
    near: float = 0.05
    """Minimum sample distance from the camera, metres."""
    occupancy_cell: float = 0.45
    """Occupancy grid cell size in fruit diameters (the resolution follows from the box's longest side)."""
    occupancy_resolution: int = 192
    """Cap on the occupancy grid's cells per axis (memory and update cost grow with its cube)."""
    occupancy_threshold: float = 0.01
    """Optical thickness (density * step) above which an occupancy cell is occupied."""
    occupancy_decay: float = 0.95
    """Decay of the occupancy values per update."""
    occupancy_update_every: int = 16
    """Training steps between occupancy updates (stages 1 and 2)."""
    occupancy_probe_fraction: float = 1.0
    """Share of all occupancy cells probed at random per update besides the occupied ones (instant-NGP's update);
    1 probes every cell."""
    stop_transmittance: float = 1e-3
    """Training rays drop their samples behind the point where the transmittance (from a first, gradient-free
    density pass) falls below this; 0 disables early termination."""
    chunk_rays: int = 8192
    """Rays per chunk when rendering whole images for evaluation."""
    mixed_precision: bool = True
    """bfloat16 autocast for the field on CUDA (ignored on the CPU)."""
    compile: bool = True
    """torch.compile the field's MLP heads on CUDA (ignored on the CPU or when unavailable)."""

    def __post_init__(self) -> None:
        if not 0.0 < self.occupancy_probe_fraction <= 1.0:
            raise ConfigError(f'render.occupancy_probe_fraction must be in (0, 1], got {self.occupancy_probe_fraction}')

    def step_m(self, fruit_diameter_m: float) -> float:
        """Ray-marching step in metres."""
        return self.step * fruit_diameter_m

    def occupancy_cells(self, extent_m: float, fruit_diameter_m: float) -> int:
        """Occupancy grid resolution for a box whose longest side is ``extent_m``."""
        cells = math.ceil(extent_m / (self.occupancy_cell * fruit_diameter_m))
        return int(min(self.occupancy_resolution, max(8, cells)))


@dataclass(frozen=True)
class StageSchedule:
    """What every training stage has: a number of steps and an exponentially decaying learning rate."""

    iterations: int = 1000
    """Training steps."""
    lr: float = 1e-2
    """Adam learning rate of the stage's own parameters at its first step."""
    lr_final_factor: float = 0.1
    """Learning rate at the last step, as a fraction of ``lr`` (exponential decay in between)."""

    @property
    def lr_final(self) -> float:
        """Learning rate at the last step."""
        return self.lr * self.lr_final_factor


@dataclass(frozen=True)
class GeometryStageConfig(StageSchedule):
    """Stage 1: density + colour, uniform rays."""

    iterations: int = 4000
    """Training steps."""
    batch_rays: int = 4096
    """Rays per step."""
    distortion_weight: float = 0.01
    """Weight of the distortion loss (1/m): pulls each ray's weight together, against floaters and fog. Computed on
    the uniformly drawn rays only (stage 1's fruit-pixel rays train the photometric loss; in stage 2 the
    fruit-biased rays train the semantic head only)."""
    fruit_fraction: float = 0.2
    """Share of each batch drawn from fruit pixels (the rest uniformly); their colour trains density and colour
    like the uniform rays' (the distortion, opacity-entropy and depth losses stay on the uniform part). Fruit is
    under 1 % of a row drive's pixels: with uniform batches alone each fruit pixel trained the density about once
    and the fruit surfaces came out 0.1-0.4 m off (docs/results/accuracy_suite.md). 0 = uniform batches."""
    fruit_rays_far_field: bool = False
    """Whether the fruit-drawn rays see the far field behind the box. False (default): they see the background
    colour there, so their fruit colour must come from inside the box, where the fruit region lies; with True the
    far field learned to paint the fruit behind a semi-transparent crown (lemon: 40 % of the fruit rays stayed
    below half opacity)."""
    fruit_interior: bool = False
    """Draw those fruit rays from the masks' interior only (:func:`~fruitnerfpp_ros.core.data.samplers.mask_interior`:
    pixels whose four neighbours show the same fruit; a fruit without such a pixel keeps all of its). A fruit a
    few pixels wide is mostly edge, and an edge pixel's colour mixes the fruit with what lies behind it."""
    opacity_entropy_weight: float = 0.0
    """Weight of the binary entropy of each uniform ray's opacity through the box: pushes a ray to either end in
    the box or pass it for the far field, not both (a semi-transparent tree with the far field seen through it).
    0 = off."""
    fruit_opacity_weight: float = 0.02
    """Weight of the fruit rays' transparency through the box, mean (1 - opacity)^2 over stage 1's fruit-drawn
    rays: a fruit pixel sees a solid fruit inside the box (the mask loss of object reconstruction, one-sided: a
    pixel off the masks may see past the box). Without it a fruit ray's colour was half the background's (plum
    row: median opacity 0.74; mango: 48 % below 0.9) and the fruits few views see got no density; 0.05 raised
    the hemispheres more but added false fruit on the row drives (docs/results/accuracy_suite.md). 0 = off."""
    fruit_opacity_interior: bool = False
    """That term only on the fruit rays through a mask's interior (``mask_interior``: a fruit without interior
    pixels keeps all of its): an edge pixel's colour mixes the fruit with what lies behind it, which may be past the
    box."""
    pose_lr: float = 0.0
    """Adam learning rate of the per-view pose corrections (radians, metres; pose_refinement.py), trained in
    stages 1 and 2 and decayed like ``lr``; 0 = the recorded poses are used as they are."""
    pose_start_fraction: float = 0.25
    """The pose corrections start training after this fraction of stage 1 (a first geometry to align to)."""
    pose_refine_when: str = 'always'
    """``always``: ``pose_lr`` refines the poses of every run. ``aligned``: only of a run whose pose alignment
    (``pose_alignment``) found the recorded poses off the images and corrected them, or whose pass registration
    (``pass_registration``) moved a row drive's return pass; poses that agree with the images (or a run without
    either) stay as recorded. A short schedule's refinement drifts exact poses:
    ``tiny`` with it always on lost 0.08-0.09 F1 on two noise-free rows (docs/results/pose_refinement.md)."""
    coarse_to_fine_fraction: float = 0.0
    """The geometry grid's levels open coarse to fine over this fraction of stage 1 (BARF's schedule): poses align
    to a smooth field first, where the photometric gradient points the way over more than a fine cell. 0 = all
    levels from the start."""

    @property
    def pose_lr_final(self) -> float:
        """Pose learning rate at the end of stage 1 (and throughout stage 2)."""
        return self.pose_lr * self.lr_final_factor


@dataclass(frozen=True)
class SemanticStageConfig(StageSchedule):
    """Stage 2: + fruit semantics, uniform rays plus fruit pixels; density, colour (and poses) keep training at the
    constant learning rate stage 1 ended with (``GeometryStageConfig.lr_final`` / ``pose_lr_final``)."""

    iterations: int = 1500
    """Training steps."""
    batch_rays: int = 4096
    """Rays per step."""
    semantic_weight: float = 1.0
    """lambda_sem, the weight of the BCE loss."""
    fruit_fraction: float = 0.25
    """Fraction of each batch drawn from fruit pixels (the rest uniformly): fruit is a few percent of an image. The
    photometric and distortion losses use the uniform part only."""


@dataclass(frozen=True)
class InstanceStageConfig(StageSchedule):
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
    weight_threshold: float = 1e-4
    """Samples with a render weight below this are skipped by the instance head."""
    contrastive_weight: float = 1.0
    """lambda_contr, the weight of the contrastive loss."""
    interior: bool = False
    """Draw each fruit's pixels from its mask's interior only (``samplers.mask_interior``; a fruit without interior
    pixels keeps all): a segmenter's boundary a pixel off labels the neighbour's or the leaves' surface."""


@dataclass(frozen=True)
class OptimizerConfig:
    """Adam settings shared by every stage (instant-NGP's choice for hash grids)."""

    beta1: float = 0.9
    """Adam beta1."""
    beta2: float = 0.99
    """Adam beta2."""
    eps: float = 1e-15
    """Adam epsilon (tiny: hash-table entries see rare, small gradients)."""


@dataclass(frozen=True)
class DepthConfig:
    """Depth supervision from an RGB-D camera (``core/rendering/depth_loss.py``).

    Used only when the dataset has depth images (``depth_file_path``) and ``weight > 0``: a dataset without depth
    trains exactly as without this section. The line-of-sight loss acts on the uniformly drawn rays of stages 1 and
    2 that have a depth (like the photometric loss, it reaches density and the pose corrections; semantic and
    instance heads are untouched).
    """

    weight: float = 0.05
    """lambda_depth, weight of the line-of-sight loss (dimensionless, per ray); 0 = depth is ignored."""
    free_space_weight: float = 0.3
    """Weight of its free-space term (render weight in front of the measured surface) against its surface term
    (1 - render weight within the surface window). 1.0 removed a little more fog but thinned the fruit (75-85 %
    opacity, held-out semantic IoU 0.40-0.54 on the test scene); 0.3 keeps them opaque (docs/results/rgbd.md)."""
    sigma_min_m: float = 0.004
    """Depth standard deviation at zero range (m): quantisation, calibration."""
    sigma_per_m2: float = 0.0025
    """Range-squared growth of a stereo camera's depth error (1/m): sigma(z) = sigma_min_m + sigma_per_m2 z^2,
    i.e. k / (f b) for a disparity noise of k px, a focal length of f px and a baseline of b m (0.08 px, 640 px,
    5 cm: 0.0025; 1 cm at 2 m)."""
    window_sigmas: float = 2.0
    """The surface window of a ray: the measured depth +- this many standard deviations (never narrower than one
    marching step). A ray's loss is scaled by (narrowest window / its window): uncertain depths count less."""
    min_depth_m: float = 0.1
    """Depths closer than this are no return (m)."""
    max_depth_m: float = 20.0
    """Depths farther than this are no return (m): beyond any RGB-D camera's range, e.g. a wrong unit."""
    check_views: bool = True
    """Before training, check each view's depth against its neighbours' (``core/data/depth_check.py``) and train
    without the depth of views that disagree (a broken, misaligned or mis-scaled sensor)."""
    min_agreement: float = 0.5
    """A view's depth is used when at least this fraction of its checked points agree with the neighbouring
    views' depth (of the points a neighbour sees and does not see through)."""
    check_neighbours: int = 4
    """Neighbouring views (nearest camera centres, facing the same way) each view is checked against."""

    def __post_init__(self) -> None:
        if self.weight < 0 or self.free_space_weight < 0:
            raise ConfigError('depth.weight and depth.free_space_weight must be >= 0')
        if self.sigma_min_m <= 0 or self.sigma_per_m2 < 0 or self.window_sigmas <= 0:
            raise ConfigError('depth.sigma_min_m and depth.window_sigmas must be > 0, depth.sigma_per_m2 >= 0')
        if not 0 <= self.min_depth_m < self.max_depth_m:
            raise ConfigError('depth: need 0 <= min_depth_m < max_depth_m')
        if not 0.0 <= self.min_agreement <= 1.0 or self.check_neighbours < 1:
            raise ConfigError('depth.min_agreement must lie in [0, 1] and depth.check_neighbours be >= 1')

    def sigma_m(self, depth_m: Any) -> Any:
        """Standard deviation (m) of measured depths (m; a float, numpy array or tensor), by the stereo model."""
        return self.sigma_min_m + self.sigma_per_m2 * depth_m * depth_m


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
    scale: ScaleConfig = _field(default_factory=ScaleConfig)
    """The fruit diameter (measured from the masks and poses, or given) every length follows from."""
    optimizer: OptimizerConfig = _field(default_factory=OptimizerConfig)
    """Adam settings."""
    depth: DepthConfig = _field(default_factory=DepthConfig)
    """Depth supervision, when the dataset has depth images."""
    pose_alignment: PoseAlignmentConfig = _field(default_factory=PoseAlignmentConfig)
    """Feature tracks and a bundle adjustment of the recorded poses before training (core/data/pose_alignment.py):
    the start of the geometry stage's pose corrections."""
    pass_registration: PassRegistrationConfig = _field(default_factory=PassRegistrationConfig)
    """A row drive's return pass registered onto its first pass on the fruit masks, after the pose alignment
    (core/data/pass_registration.py): odometry's drift between the two sides of a row."""
    seed: int = 0
    """Seed of every random source (weights, samplers, jitter)."""
    checkpoint_every: int = 500
    """Steps between periodic checkpoints (a killed run loses at most this many steps)."""
    log_every: int = 50
    """Steps between lines of metrics.jsonl."""
    eval_max_views: int = 8
    """Held-out views rendered for the stage-end evaluation (n spread evenly over them, the first and the last
    included; before session 48 the first n, which on a row drive all lay on the way out)."""
    eval_max_pixels: int = 262_144
    """... each scored on at most this many pixels (every k-th row and column of a larger view): 3 views of
    1280 x 960 took 203-339 s per stage end on the CPU at every pixel (``tiny``), 27-44 s at every 3rd row and
    column, with the same figures (docs/results/robustness.md). The suites' views (up to 512 x 512) are scored
    whole."""
    cpu_threads: int = 1
    """torch CPU threads the callers (CLI, benchmark scene, node) set before training on the CPU; the library itself
    never changes process-wide settings. 0 (the ``cpu`` preset's): ``OMP_NUM_THREADS`` when set, else the cores the
    process may run on divided among the jobs its caller runs at once (``bench accuracy --jobs 2`` on 2 cores: one
    each; :func:`~fruitnerfpp_ros.core.device.cpu_thread_count`); the ``fruit_counter`` node takes 0 as one thread
    (it shares the robot's cores). One thread per process is the fast choice when processes share the cores (with
    more, OpenMP barriers collapse); a run alone on 2 cores trains 1.5x faster with both (apple_hemi_200's first 400
    / 200 geometry / semantic steps: 121 / 51 s on one thread, 80 / 34 s on two; docs/results/accuracy_suite.md)."""

    def __post_init__(self) -> None:
        for name in ('geometry', 'semantic', 'instance'):
            if getattr(self, name).iterations < 0:
                raise ConfigError(f'{name}.iterations must be >= 0')
        for name in ('geometry', 'semantic'):
            if not 0.0 <= getattr(self, name).fruit_fraction < 1.0:
                raise ConfigError(f'{name}.fruit_fraction must lie in [0, 1)')
        if self.geometry.pose_refine_when not in ('always', 'aligned'):
            raise ConfigError(f"geometry.pose_refine_when must be 'always' or 'aligned', got "
                              f"{self.geometry.pose_refine_when!r}")
        if not 0.0 <= self.geometry.coarse_to_fine_fraction <= 1.0:
            raise ConfigError('geometry.coarse_to_fine_fraction must lie in [0, 1]')
        if self.checkpoint_every <= 0 or self.log_every <= 0 or self.eval_max_pixels <= 0:
            raise ConfigError('checkpoint_every, log_every and eval_max_pixels must be positive')
        if self.data.box_around not in ('fruit', 'fruit_and_cameras'):
            raise ConfigError(f"data.box_around must be 'fruit' or 'fruit_and_cameras', got {self.data.box_around!r}")
        if self.data.box_around == 'fruit' and self.data.aabb is None and not self.field.far_field.enabled:
            raise ConfigError("data.box_around 'fruit' leaves the ground and what lies past the tree to the far field: "
                              "field.far_field.samples must be > 0 (or data.box_around 'fruit_and_cameras')")
        if self.data.aabb is not None and len(self.data.aabb) != 6:
            raise ConfigError('data.aabb needs 6 numbers: xmin ymin zmin xmax ymax zmax')

    def surface_density(self, fruit_diameter_m: float) -> float:
        """Density (1/m) at which one ray-marching step is half opaque: a surface / empty-space threshold."""
        return math.log(2.0) / self.render.step_m(fruit_diameter_m)

    @classmethod
    def preset(cls, name: str) -> 'TrainConfig':
        """The named preset (``core/training/presets.py``): ``tiny`` (CPU tests, ~1.5 min), ``cpu`` (a real tree on a
        CPU, ~5 min), ``default`` (GPU, minutes) or ``paper`` (long schedule)."""
        from fruitnerfpp_ros.core.training.presets import preset
        return preset(name)
