"""The named training presets: ``tiny`` (CPU tests), ``cpu`` (a real tree on a CPU), ``default`` (GPU), ``paper``.

``config/train_<preset>.yaml`` hold the same values as YAML (checked by test/core/training/test_config.py).
"""

from __future__ import annotations

import dataclasses

from fruitnerfpp_ros.core.data.pose_alignment import PoseAlignmentConfig
from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig, HashGridConfig
from fruitnerfpp_ros.core.preset_names import PRESET_NAMES
from fruitnerfpp_ros.core.training.config import (DataConfig, GeometryStageConfig, InstanceStageConfig, RenderConfig,
                                                  SemanticStageConfig, TrainConfig)
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['preset']


#: Odometry noise in every preset: the poses are aligned to the images before training (core/data/pose_alignment.py;
#: exact poses pass its check unchanged, 2-12 s on a `cpu` suite scene, 31 s on 300 views of 512 px, 2 cores)
#: and refined from 10 % of stage 1 at 1e-3 only where the alignment found them off. `tiny` on the pose-noise row
#: 0.242 -> 0.836, its 12 noise-free `cpu` scenes unchanged; the refinement always on lost two noise-free rows
#: 0.08-0.09 (docs/results/pose_refinement.md, session 35).
_REFINE_POSES_IF_OFF = dict(pose_lr=1e-3, pose_start_fraction=0.1, pose_refine_when='aligned')


def _tiny() -> TrainConfig:
    return TrainConfig(
        # A coarse geometry grid (finest cells 0.28 fruit diameters: 6 levels up to 128 over the 2.6 m test box)
        # overfits 21 views of 96 px less than a finer one: held-out PSNR, semantic IoU and the count all improved
        # (docs/results/tiny_preset.md). Semantic and instance grids go to 0.14 d (256 over that box).
        field=FieldConfig(
            geometry_grid=HashGridConfig(num_levels=6, log2_table_size=15, coarsest_cell=4.5, finest_cell=0.28),
            hidden_dim=32, density_layers=1, color_layers=1, sh_degree=2, semantic_layers=1,
            semantic_grid=HashGridConfig(num_levels=6, log2_table_size=15, coarsest_cell=4.5, finest_cell=0.14),
            embedding_dim=32,
            instance_grid=HashGridConfig(num_levels=6, log2_table_size=15, coarsest_cell=4.5, finest_cell=0.14),
            instance_hidden_dim=32, instance_layers=1),
        # A box that reaches further into the ground and sky the cameras see (view fraction 0.1, 3x the sparse
        # points): floaters that painted the world outside the old box carried fruit probability; seed 2 of the
        # test scene went from F1 0.21 to 0.95. Occupancy cells of 0.75 d (48 over the test box).
        data=DataConfig(min_view_fraction=0.1, points_growth=3.0),
        render=RenderConfig(occupancy_cell=0.75, occupancy_resolution=64, occupancy_update_every=8, chunk_rays=4096),
        geometry=GeometryStageConfig(iterations=600, batch_rays=640, lr=2e-2, **_REFINE_POSES_IF_OFF),
        # fruit_fraction 0.5 taught a fruit prior of 50 % (fruit is ~5 % of a view): fruit probability >= 0.9 spread
        # over the canopy. 0.15 and 400 steps: held-out IoU 0.28 -> 0.56 / 0.50 / 0.30 on three seeds of the test
        # scene (docs/results/tiny_preset.md).
        semantic=SemanticStageConfig(iterations=400, batch_rays=512, lr=5e-2, fruit_fraction=0.15),
        instance=InstanceStageConfig(iterations=600, groups=4, group_size=8, pixels_per_fruit=24, lr=3e-2),
        pose_alignment=PoseAlignmentConfig(enabled=True),
        checkpoint_every=100, log_every=25, eval_max_views=3)


def _cpu() -> TrainConfig:
    # The tiny field with 3x the steps and 2x the rays of its geometry and semantic stages: on an 80-apple tree
    # F1 0.52 -> 0.66 (semantic IoU 0.26 -> 0.35); on the test scene's seeds 0 / 1 F1 0.97 / 0.88 -> 0.97 / 0.97
    # (docs/results/tiny_preset.md). About 3x tiny's training time. It refines the poses, as robot odometry needs,
    # from 10 % of stage 1 at 1e-3: on the suite's 2 cm / 1 deg noise scene F1 0.222 -> 0.337 and 0.286 -> 0.465
    # (two seeds) against 3e-4 from 25 %, the noise-free suite scenes within -0.013..+0.009
    # (docs/results/pose_refinement.md). Twice the steps of half the rays (3600 x 640) raised the six scenes it was
    # chosen on but lost on all four held-out hemispheres (apple_hemi_200 0.830 -> 0.738): not kept
    # (docs/results/accuracy_suite.md, "More geometry training"). The poses are first aligned to the images by
    # feature tracks and a bundle adjustment (core/data/pose_alignment.py): the pose-noise scene 0.504 -> 0.867, a
    # second noisy row (peach, seed 201) 0.286 -> 0.761; on the 12 noise-free scenes the recorded poses already agree
    # with the images (0.07-0.14 px) and are kept (docs/results/pose_refinement.md). As the other presets, `cpu`
    # refines the poses only where the alignment or the pass registration found them off (`aligned`; it refined
    # every run's until session 42): exact poses refined turned each pass's end views by 0.8-1.8 deg; `aligned` on
    # the suites 0.923 -> 0.928 (`cpu`), 0.972 -> 0.968 (`quick`), 0.908 -> 0.901 (`holdout`), on six rows mean F1
    # 0.950 -> 0.957, doubles across cuts 4 -> 0, trees within 10 % 22 -> 22 of 30 (bench/results/row_suite.md).
    # Each occupancy update probes the occupied cells and a random quarter of the others (instant-NGP's update):
    # with the CPU's chunked hash-grid passes the `cpu` suite's scenes take 260-591 s (281-784 s before), its mean
    # F1 0.873 -> 0.880, within one run's spread (docs/results/accuracy_suite.md, "Faster training steps").
    # Threads: the cores this process may use, shared among the jobs run at once (TrainConfig.cpu_threads 0): a run
    # alone on 2 cores trains 1.5x faster than on one thread; `bench accuracy --jobs 2` still gives each scene one.
    # Its held-out figures are over up to 8 views (tiny: 3, for the demo's time): 3 of a row's 8 moved the PSNR by up
    # to 2.4 dB and the semantic IoU by 0.09 from all eight's, which cost 5-7 s more per stage end on a row's
    # fields (docs/results/accuracy_suite.md, session 49).
    tiny = _tiny()
    return dataclasses.replace(
        tiny, render=dataclasses.replace(tiny.render, occupancy_probe_fraction=0.25),
        geometry=dataclasses.replace(tiny.geometry, iterations=1800, batch_rays=1280),
        semantic=dataclasses.replace(tiny.semantic, iterations=1200, batch_rays=1024),
        checkpoint_every=200, log_every=50, cpu_threads=0, eval_max_views=8)


def _default() -> TrainConfig:
    return TrainConfig(geometry=GeometryStageConfig(**_REFINE_POSES_IF_OFF),
                       pose_alignment=PoseAlignmentConfig(enabled=True))


def _paper() -> TrainConfig:
    return TrainConfig(
        geometry=GeometryStageConfig(iterations=30000, batch_rays=4096, lr=1e-2, **_REFINE_POSES_IF_OFF),
        pose_alignment=PoseAlignmentConfig(enabled=True),
        semantic=SemanticStageConfig(iterations=10000, batch_rays=4096, lr=1e-2),
        instance=InstanceStageConfig(iterations=20000, groups=8, group_size=8, pixels_per_fruit=32),
        render=RenderConfig(step=0.14, occupancy_cell=0.35, occupancy_resolution=256),
        checkpoint_every=2000, log_every=100)


_PRESETS = {'tiny': _tiny, 'cpu': _cpu, 'default': _default, 'paper': _paper}
assert tuple(_PRESETS) == PRESET_NAMES


def preset(name: str) -> TrainConfig:
    """The named preset.

    Raises:
        ConfigError: unknown name.
    """
    if name not in _PRESETS:
        raise ConfigError(f'unknown training preset {name!r}; expected one of {", ".join(PRESET_NAMES)}')
    return _PRESETS[name]()
