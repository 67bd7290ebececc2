"""bench/recount.py on a suite-shaped directory of the tiny trained run: its base variant counts the run's own cloud,
an export variant exports the cloud again from the checkpoint; bench/mask_pairs.py on the same scene."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from fruitnerfpp_ros.core.pipeline import export_run
from test.accuracy_targets import assert_counted
from test.bench_scripts import load_bench_script


def test_export_variants_export_again_from_the_checkpoint(tiny_trained_run: Path, tiny_apple_dataset: Path,
                                                          tmp_path: Path) -> None:
    scene = tmp_path / 'suite' / 'apple'
    shutil.copytree(tiny_trained_run, scene / 'run')
    shutil.copytree(tiny_apple_dataset, scene / 'data')
    export_run(scene / 'run', device='cpu', dataset_dir=scene / 'data')       # the suite's own cloud
    recount = load_bench_script('recount')
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    variants = recount._variants(ClusterConfig(), ['same=export.min_views:2',       # the default: the same cloud
                                                   'strict=export.min_views:1000,masks.enabled:0',  # no voxel passes
                                                   'masks=export.min_views:1000'])  # the masks' fruit alone
    assert variants['same'].export == (('min_views', 2),) and variants['same'].cluster == ClusterConfig()
    assert variants['strict'].cluster.masks.enabled is False and variants['masks'].cluster.masks.enabled
    recount.recount_suites([tmp_path / 'suite'], variants, tmp_path / 'out')
    table = json.loads((tmp_path / 'out' / 'recount.json').read_text())['scenes']['suite/apple']
    (base_count, base_f1), (same_count, same_f1) = table['base'], table['same']
    assert_counted(base_count, 20, base_f1)
    assert (same_count, same_f1) == (base_count, base_f1)
    assert table['strict'][0] == 0
    masks_count, masks_f1 = table['masks']       # an empty cloud: every fruit triangulated from the training masks
    assert masks_count > 0 and masks_f1 >= 0.5, table['masks']
    assert (tmp_path / 'out' / 'clouds' / 'suite' / 'apple').is_dir()
    missed = recount._variants(ClusterConfig(), ['masks=export.min_views:1000'])    # every mask missed: nothing to add
    recount.recount_suites([tmp_path / 'suite'], missed, tmp_path / 'noisy', mask_noise=(1.0, 0.0))
    assert json.loads((tmp_path / 'noisy' / 'recount.json').read_text())['scenes']['suite/apple']['masks'][0] == 0
    pairs = load_bench_script('mask_pairs').scene_pairs(scene, 2.0)
    two = [p for p in pairs if p[0] == 'two fruits']          # neighbouring apples, both counted right
    assert two and sum(p[2] for p in two) > sum(p[1] for p in two), pairs   # the masks mostly show them apart
