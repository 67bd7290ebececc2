"""``fruitnerfpp bench accuracy``: one micro scene through the command line (fallback masks, --config, --log; the
fruit masks' blobs), a bag scene's replay parameters as a robot user writes them, and one-line errors."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from fruitnerfpp_ros.cli import bench
from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.benchmark.result import CounterScore, SceneResult
from fruitnerfpp_ros.core.benchmark.runner import SuiteOptions, run_suite
from fruitnerfpp_ros.core.benchmark.suites import BagOptions, SuiteScene

MICRO_CONFIG = ('train:\n  geometry: {iterations: 5}\n  semantic: {iterations: 5}\n  instance: {iterations: 5}\n'
                '  eval_max_views: 1\nclustering:\n  n_jobs: 1\n')


def test_micro_scene_with_fallback_masks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    micro = SuiteScene('micro', dict(fruit='apple', count=8, views=12, resolution=(48, 48), seed=5), 'micro')
    # the suites' scenes take minutes
    monkeypatch.setattr(bench, 'suite_scenes', lambda suite, names, draw=None: (micro,))
    config, out, log = tmp_path / 'micro.yaml', tmp_path / 'out', tmp_path / 'log.md'
    config.write_text(MICRO_CONFIG)
    code = main(['bench', 'accuracy', '--suite', 'quick', '--out', str(out), '--preset', 'tiny', '--masks',
                 'fallback', '--config', str(config), '--device', 'cpu', '--log', str(log)])
    printed = capsys.readouterr()
    scene = json.loads((out / 'accuracy.json').read_text())['scenes'][0]
    assert code == 0, scene['error']
    assert scene['times_s']['segment'] > 0  # the fallback segmenter replaced the ground-truth masks
    transforms = json.loads((out / 'micro' / 'data' / 'transforms.json').read_text())
    assert transforms['frames'][0]['instance_path'].startswith('instances/')
    assert transforms['mask_source'] == 'fallback'
    counts = json.loads((out / 'micro' / 'run' / 'counts.json').read_text())
    assert counts['stats']['mask_fruits'] == {'added': 0, 'skipped_mask_source': 'fallback'}
    assert 'quick suite: 1 scene(s), preset tiny, masks fallback, device cpu' in printed.out
    assert 'micro: count ' in printed.out + printed.err and 'tables: ' in printed.out
    section = log.read_text()
    assert f'--masks fallback --jobs 1 --device cpu --config {config}' in section
    assert (out / 'micro' / 'count.png').is_file()


def test_micro_scene_with_blobs_of_the_fruit_masks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    micro = SuiteScene('micro', dict(fruit='apple', count=8, views=12, resolution=(48, 48), seed=5), 'micro')
    monkeypatch.setattr(bench, 'suite_scenes', lambda suite, names, draw=None: (micro,))
    config, out = tmp_path / 'micro.yaml', tmp_path / 'out'
    config.write_text(MICRO_CONFIG)
    code = main(['bench', 'accuracy', '--suite', 'quick', '--out', str(out), '--preset', 'tiny', '--masks',
                 'semantic', '--config', str(config), '--device', 'cpu'])
    scene = json.loads((out / 'accuracy.json').read_text())['scenes'][0]
    assert code == 0, scene['error']
    assert scene['times_s']['segment'] > 0   # the ground-truth instances replaced by the fruit masks' blobs
    data = out / 'micro' / 'data'
    transforms = json.loads((data / 'transforms.json').read_text())
    assert transforms['mask_source'] == 'semantic'
    covered = []
    for frame in transforms['frames']:   # the instances lie on the scene's fruit masks, which stay as they were
        ids = cv2.imread(str(data / frame['instance_path']), cv2.IMREAD_UNCHANGED)
        fruit = cv2.imread(str(data / frame['semantic_path']), cv2.IMREAD_UNCHANGED) > 0
        assert ids.dtype == np.uint16 and not (ids[~fruit] > 0).any()
        covered.append(ids[fruit] > 0)
    assert np.concatenate(covered).mean() > 0.8   # measured 0.89: pieces under the smallest instance left out
    assert 'masks semantic' in capsys.readouterr().out


def test_a_bag_scene_replays_with_the_mask_source_of_its_masks(tmp_path: Path) -> None:
    from fruitnerfpp_ros.core.benchmark.scene_run import SceneJob, _bag_parameters
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.export.config import ExportConfig
    from fruitnerfpp_ros.core.training import TrainConfig

    scene = SuiteScene('bag', dict(fruit='apple', count=8, views=12, resolution=(48, 48), seed=5), 'bag',
                       via_bag=True)
    sources = {masks: _bag_parameters(SceneJob(scene, tmp_path, masks, 'cpu', 'tiny', TrainConfig.preset('tiny'),
                                               ExportConfig(), ClusterConfig()), scene.synth_config('cpu'))
               ['mask_source'] for masks in ('gt', 'fallback', 'semantic', 'noisy')}
    assert sources == {'gt': 'topic', 'fallback': 'fallback', 'semantic': 'semantic_topic', 'noisy': 'topic'}


def test_noisy_masks_are_generated_degraded_for_both_counters(tmp_path: Path) -> None:
    """``--masks noisy``: the scene is generated with a segmenter's errors in its masks (dataset and bag alike)."""
    from fruitnerfpp_ros.core.benchmark.scene_run import SceneJob, scene_synth_config
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.export.config import ExportConfig
    from fruitnerfpp_ros.core.training import TrainConfig

    scene = SuiteScene('micro', dict(fruit='apple', count=8, views=12, resolution=(48, 48), seed=5), 'micro')
    configs = {masks: scene_synth_config(SceneJob(scene, tmp_path, masks, 'cpu', 'tiny', TrainConfig.preset('tiny'),
                                                  ExportConfig(), ClusterConfig())) for masks in ('gt', 'noisy')}
    assert not configs['gt'].degrades_masks and configs['gt'] == scene.synth_config('cpu')
    assert (configs['noisy'].mask_missed, configs['noisy'].mask_false, configs['noisy'].mask_boundary_px) == \
        (0.15, 0.1, 1)
    assert configs['noisy'].seed == 5 and configs['noisy'].count == 8


def test_bag_scene_replays_with_the_recordings_topics_and_frame(tmp_path: Path) -> None:
    """JPEG images, the odom frame and poses from /tf reach the keyframes; a replay that then fails (here: more
    keyframes demanded than the bag holds) is reported, and the peer counts the collected keyframes."""
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.export.config import ExportConfig
    from fruitnerfpp_ros.core.training import TrainConfig

    scene = SuiteScene('bag', dict(fruit='apple', count=8, views=12, resolution=(48, 48), seed=5,
                                   bag_image_format='jpeg', world_frame='odom'), 'bag',
                       via_bag=True, bag=BagOptions(pose_source='tf', params={'min_keyframes': 1000}))
    options = SuiteOptions('tiny', TrainConfig.preset('tiny'), ExportConfig(), ClusterConfig(), device='cpu')
    result = run_suite('test', [scene], tmp_path, options, bag_runner=bench.replay_scene_bag).scenes[0]
    assert 'ours: BagError: ' in result.error and 'only 12 keyframe(s), fewer than min_keyframes=1000' in result.error
    assert result.n_views == 12 and result.peer is not None and result.ours is None
    assert (tmp_path / 'bag' / 'run' / 'keyframes' / 'transforms.json').is_file()


@pytest.mark.parametrize('extra, message', [
    (['--scenes', 'nope'], 'unknown scene(s) nope in suite quick'),
    (['--config', 'CONFIG'], 'unknown section(s) trian'),
    (['--device', 'tpu'], "unknown device 'tpu'"),
])
def test_errors_are_one_line(extra: list[str], message: str, tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / 'bad.yaml'
    config.write_text('trian: {}\n')
    extra = [str(config) if word == 'CONFIG' else word for word in extra]
    assert main(['bench', 'accuracy', '--suite', 'quick', '--out', str(tmp_path / 'out'), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith('fruitnerfpp bench: error: ') and message in err and err.count('\n') == 1
    assert not (tmp_path / 'out').exists()


def test_scene_line_and_command_line() -> None:
    done = SceneResult('a', ours=CounterScore(19, 19, 1.0, 0.95, 0.974), peer=CounterScore(22, 18, 0.82, 0.9, 0.857),
                       gt_count=20, times_s={'total': 84.2})
    assert bench.scene_line(done) == 'a: count 19/20 F1 0.974 (peer 22, F1 0.857) 84 s'
    failed = SceneResult('b', error='scene: SynthError: no', times_s={'total': 0.3})
    assert bench.scene_line(failed) == 'b: 0 s FAILED: scene: SynthError: no'
    args = argparse.Namespace(suite='cpu', out=Path('my out'), masks='gt', jobs=2, device='auto', scenes='a,b',
                              config=None, draw=None)
    assert bench.command_line(args, 'cpu') == ("fruitnerfpp bench accuracy --suite cpu --out 'my out' --preset cpu "
                                               '--masks gt --jobs 2 --device auto --scenes a,b')
    args = argparse.Namespace(suite='blind', out=Path('b'), masks='gt', jobs=1, device='cpu', scenes=None,
                              config=None, draw=7)
    assert bench.command_line(args, 'cpu').endswith('--device cpu --draw 7')
