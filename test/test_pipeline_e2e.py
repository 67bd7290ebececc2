"""End to end on the shared tiny apple scene: export -> count -> eval through the CLI, against the CI floors.

Reuses the session's ``tiny_trained_run`` (no retraining): ``fruitnerfpp run --skip-training`` on a copy of it runs
the same ``run_pipeline`` path as a full run, after training.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.export.ply import read_ply
from test.accuracy_targets import assert_counted


def _cli(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in args])
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope='module')
def pipeline_run(tiny_trained_run: Path, tiny_apple_dataset: Path, tmp_path_factory: pytest.TempPathFactory):
    from fruitnerfpp_ros.core.clustering.hdbscan_cluster import warm_up
    warm_up()
    run = tmp_path_factory.mktemp('e2e') / 'run'
    shutil.copytree(tiny_trained_run, run)
    rc, out, err = _cli(['run', tiny_apple_dataset, '--out', run, '--skip-training', '--device', 'cpu', '--preset',
                         'tiny'])
    assert rc == 0, err
    return run, out


def test_run_counts_the_apples_above_the_floor(pipeline_run, tiny_apple_dataset: Path) -> None:
    run, printed = pipeline_run
    metrics = json.loads((run / 'eval.json').read_text())
    gt = json.loads((tiny_apple_dataset / 'gt_fruits.json').read_text())
    assert metrics['gt_count'] == len(gt['fruits'])
    assert 'hungarian' in printed and 'fruits counted' in printed
    assert 'return pass kept: the views look in many directions (no passes)' in printed  # a hemisphere
    assert {'precision', 'recall', 'f1', 'greedy'} <= set(metrics)
    counts = json.loads((run / 'counts.json').read_text())
    assert 0.04 < np.median([f['diameter'] for f in counts['fruits']]) < 0.12  # apples of ~8 cm
    assert_counted(metrics['count'], metrics['gt_count'], metrics['f1'])
    assert metrics['greedy']['f1'] >= metrics['f1'] - 0.1


def test_outputs_carry_the_same_ids(pipeline_run) -> None:
    run, _ = pipeline_run
    counts = json.loads((run / 'counts.json').read_text())
    assert counts['version'] == 1 and counts['total'] == len(counts['fruits'])
    assert [f['id'] for f in counts['fruits']] == list(range(1, counts['total'] + 1))
    cloud, labels = read_ply(run / 'cloud.ply')
    assert labels is not None and len(labels) == len(cloud)
    sizes = np.bincount(labels, minlength=counts['total'] + 1)
    assert [int(s) for s in sizes[1:]] == [f['n_points'] for f in counts['fruits']]
    # a fruit's centre: the median of its points moved along their viewing directions (which the file keeps)
    assert cloud.view_dir is not None and cloud.fruit_diameter_m
    moved = cloud.xyz + ClusterConfig().centre_shift_diameters * cloud.fruit_diameter_m * cloud.view_dir
    clusters = [f for f in counts['fruits'] if f['source'] == 'cloud']
    assert len(clusters) >= 0.8 * counts['total']
    for fruit in clusters:
        np.testing.assert_allclose(np.median(moved[labels == fruit['id']], axis=0), fruit['center'], atol=1e-5)
        assert fruit['diameter'] > 0
    for fruit in counts['fruits'][len(clusters):]:   # the masks' fruits follow the clusters, without points
        assert fruit['source'] == 'masks' and fruit['n_points'] == 0
    assert counts['stats']['mask_fruits']['added'] == counts['total'] - len(clusters)
    report = json.loads((run / 'export.json').read_text())
    assert report['method'] == 'surface' and report['n_kept'] == len(cloud) > 0
    assert report['n_rays'] >= report['n_opaque'] >= report['n_fruit'] and report['n_multi_view'] >= report['n_kept']


def test_count_and_eval_subcommands(pipeline_run, tiny_apple_dataset: Path, tmp_path: Path) -> None:
    run, _ = pipeline_run
    cloud_copy = tmp_path / 'cloud.ply'
    shutil.copy(run / 'cloud.ply', cloud_copy)
    rc, out, err = _cli(['count', cloud_copy, '--out', tmp_path / 'counts.json'])
    assert rc == 0, err
    total = json.loads((tmp_path / 'counts.json').read_text())['total']
    run_counts = json.loads((run / 'counts.json').read_text())
    # a cloud file alone has no training views: its count is the clusters; the run directory's adds the masks' fruit
    assert total == sum(f['source'] == 'cloud' for f in run_counts['fruits'])
    rc, out, err = _cli(['count', run, '--out', tmp_path / 'run_counts.json'])
    assert rc == 0, err
    again = json.loads((tmp_path / 'run_counts.json').read_text())
    assert again['total'] == run_counts['total'] and 'mask_fruits' in again['stats']
    rc, out, err = _cli(['eval', tmp_path / 'counts.json', '--gt', tiny_apple_dataset / 'gt_fruits.json', '--json'])
    assert rc == 0, err
    data = json.loads(out)
    assert {'count', 'gt_count', 'precision', 'recall', 'f1'} <= set(data)
    assert data['count'] == total and data['gt_count'] == 20
    assert_counted(total, 20, data['f1'])


def test_the_pipeline_reads_the_dataset_and_the_checkpoint_once(tiny_trained_run: Path, tiny_apple_dataset: Path,
                                                                tmp_path: Path, monkeypatch) -> None:
    from fruitnerfpp_ros.core import pipeline, training
    from fruitnerfpp_ros.core.data import dataset as dataset_module

    reads, loads = [], []
    original, original_scene = dataset_module.load_dataset, training.load_trained_scene

    def counted(*args, **kwargs):
        reads.append(args[0] if args else kwargs.get('dataset_dir'))
        return original(*args, **kwargs)

    def counted_scene(*args, **kwargs):
        loads.append(args[0] if args else kwargs.get('run_dir'))
        return original_scene(*args, **kwargs)

    monkeypatch.setattr(dataset_module, 'load_dataset', counted)
    monkeypatch.setattr(training, 'load_trained_scene', counted_scene)
    run = tmp_path / 'run'
    shutil.copytree(tiny_trained_run, run)
    result = pipeline.run_pipeline(tiny_apple_dataset, run, skip_training=True, device='cpu')
    assert len(reads) == 1, reads          # the surface export and the masks' check share one read
    assert len(loads) == 1, loads          # ... and one checkpoint
    assert result.count.count > 0 and 'mask_fruits' in result.count.stats


def test_a_moved_run_counts_and_scores_as_it_did_from_any_directory(pipeline_run, tiny_apple_dataset: Path,
                                                                    tmp_path: Path, monkeypatch) -> None:
    from fruitnerfpp_ros.core.pipeline import count_run
    from fruitnerfpp_ros.core.training import RunDir
    from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint, save_checkpoint

    run, _ = pipeline_run
    site = tmp_path / 'site'
    shutil.copytree(run, site / 'run')
    shutil.copytree(tiny_apple_dataset, site / 'data')
    checkpoint = RunDir(site / 'run').latest_checkpoint
    state = load_checkpoint(checkpoint)
    state['dataset_dir'] = 'data'   # as older releases wrote it: relative to the directory training ran in
    state.pop('dataset_from_run', None)
    save_checkpoint(state, checkpoint)
    (tmp_path / 'elsewhere').mkdir()
    monkeypatch.chdir(tmp_path / 'elsewhere')
    own_counts, own_eval = (json.loads((run / name).read_text()) for name in ('counts.json', 'eval.json'))
    count, _, _ = count_run(site / 'run', out=tmp_path / 'counts.json')
    assert 'mask_fruits' in count.stats and count.count == own_counts['total']   # its views' masks were read
    rc, out, err = _cli(['eval', site / 'run', '--json'])   # the run's counts, the ground truth beside its dataset
    assert rc == 0, err
    scored = json.loads(out)
    for key in ('count', 'gt_count', 'gt_unseen', 'tp', 'recall', 'f1'):   # as the run scored itself
        assert scored[key] == own_eval[key], key
    assert scored['count'] > 0


@pytest.mark.parametrize('error', ['DatasetError', 'CheckpointError'])
def test_a_run_whose_dataset_is_gone_still_counts_its_cloud(pipeline_run, tmp_path: Path, monkeypatch, caplog,
                                                            error: str) -> None:
    from fruitnerfpp_ros import errors
    from fruitnerfpp_ros.core import pipeline

    def gone(*args, **kwargs):   # the dataset moved away, or a checkpoint of another release
        raise getattr(errors, error)('transforms.json: not found')

    run, _ = pipeline_run
    monkeypatch.setattr(pipeline, 'load_run_views', gone)
    with caplog.at_level('WARNING', logger='fruitnerfpp_ros.core.pipeline'):
        count, _, _ = pipeline.count_run(run, out=tmp_path / 'counts.json')
    assert count.count > 0 and 'mask_fruits' not in count.stats
    assert 'without the masks' in caplog.text and 'transforms.json: not found' in caplog.text


def test_missing_files_are_one_line_errors(tmp_path: Path) -> None:
    rc, out, err = _cli(['export', tmp_path])
    assert rc == 2 and 'latest.pt' in err and 'Traceback' not in err
    rc, out, err = _cli(['count', tmp_path])
    assert rc == 2 and 'no cloud.npz or cloud.ply' in err and 'fruitnerfpp export' in err
    (tmp_path / 'counts.json').write_text(json.dumps({'total': 0, 'fruits': []}))
    rc, out, err = _cli(['eval', tmp_path / 'counts.json', '--gt', tmp_path / 'gt_fruits.json'])
    assert rc == 2 and 'gt_fruits.json: ground truth file not found' in err
    rc, out, err = _cli(['eval', tmp_path / 'counts.json', '--gt', tmp_path])   # a directory without it
    assert rc == 2 and 'gt_fruits.json: ground truth file not found' in err
    rc, out, err = _cli(['eval', tmp_path / 'counts.json'])   # no run, no --gt
    assert rc == 2 and 'give --gt' in err
    rc, out, err = _cli(['eval', tmp_path / 'counts.json', '--gt', tmp_path / 'counts.json' / 'x'])  # unreadable
    assert rc == 2 and 'Traceback' not in err
    (tmp_path / 'empty').mkdir()
    rc, out, err = _cli(['eval', tmp_path / 'empty', '--gt', tmp_path / 'gt_fruits.json'])
    assert rc == 2 and 'no counts.json in this directory' in err
    (tmp_path / 'gt_fruits.json').write_text(json.dumps({'fruit': []}))
    rc, out, err = _cli(['eval', tmp_path / 'counts.json', '--gt', tmp_path / 'gt_fruits.json'])
    assert rc == 2 and '"fruits" list' in err
