"""The runner, end to end on one micro scene in its own process, beside a scene that fails and one that dies."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

from fruitnerfpp_ros.core.benchmark.result import TIME_KEYS, SceneResult
from fruitnerfpp_ros.core.benchmark.runner import ACCURACY_JSON, ACCURACY_MD, SuiteOptions, run_suite
from fruitnerfpp_ros.core.benchmark.scene_run import SCENE_JSON, SCENE_LOG, SceneJob
from fruitnerfpp_ros.core.benchmark.scene_types import row_fields
from fruitnerfpp_ros.core.benchmark.suites import BagOptions, SuiteScene
from fruitnerfpp_ros.errors import ConfigError

#: A tree small enough for a one-minute test: 8 apples, 12 views of 48 px.
MICRO = SuiteScene('micro', dict(fruit='apple', count=8, views=12, resolution=(48, 48), seed=5), 'micro scene')
#: A camera 2 m high, pitched up, over a tree whose crown hangs at about half a metre: no view shows a fruit.
PAST = SuiteScene('past', dict(fruit='apple', count=8, views=12, resolution=(48, 48), seed=5,
                               **row_fields(row_standoff_m=2.4, camera_height_m=2.0, camera_pitch_deg=10.0)),
                  'cameras looking past the tree')
#: Fails in its process: SynthConfig has no such fruit.
BAD = SuiteScene('bad', dict(fruit='banana'), 'a broken definition')


def _options(**values: object) -> SuiteOptions:
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.config_io import replace_nested
    from fruitnerfpp_ros.core.export.config import ExportConfig
    from fruitnerfpp_ros.core.training import TrainConfig

    micro = replace_nested(TrainConfig.preset('tiny'), {'geometry': {'iterations': 5}, 'semantic': {'iterations': 5},
                                                        'instance': {'iterations': 5}, 'eval_max_views': 1})
    return SuiteOptions('tiny', micro, ExportConfig(), ClusterConfig(n_jobs=1), device='cpu', **values)


def test_one_micro_scene_end_to_end_and_a_failing_one(tmp_path: Path) -> None:
    """The micro scene's peer runs beside ours (as on a GPU; test/cli/test_bench.py runs it after ours)."""
    from fruitnerfpp_ros.core.tracking import track_dataset

    finished: list[str] = []
    suite = run_suite('test', [MICRO, BAD, PAST], tmp_path, _options(jobs=2, peer_beside_ours=True),
                      command='fruitnerfpp bench ...',
                      on_scene_done=lambda result: finished.append(result.name))
    assert sorted(finished) == ['bad', 'micro', 'past'] and [s.name for s in suite.scenes] == ['micro', 'bad', 'past']
    micro, bad, past = suite.scenes
    assert micro.ok, micro.error
    assert micro.gt_count == 8 and 0 < micro.gt_seen <= 8 and micro.n_views == 12
    assert micro.ours is not None and micro.peer is not None and micro.peer.count >= 1
    assert micro.peer.count == len(track_dataset(tmp_path / 'micro' / 'data').centers())
    assert 0.0 <= micro.ours.f1 <= 1.0 and 0.0 <= micro.peer.f1 <= 1.0
    assert math.isfinite(micro.psnr_db) and micro.box_size_m is not None and micro.voxel_mm > 0
    assert 0.05 < micro.gt_diameter_m < 0.1 and micro.diameter_m > 0 and micro.peak_rss_mb > 100
    assert set(TIME_KEYS) - {'segment', 'keyframes'} <= set(micro.times_s)  # every step of a dataset scene
    assert micro.times_s['prepare'] > 0.0 and micro.times_s['evaluate'] > 0.0
    steps = sum(micro.times_s[k] for k in ('prepare', 'geometry', 'semantic', 'instance', 'export', 'count'))
    assert steps < micro.times_s['ours'] < micro.times_s['total'] - micro.times_s['synth']  # ours: data to count
    assert micro.picture == 'micro/count.png' and (tmp_path / micro.picture).stat().st_size > 1000
    scene_dir = tmp_path / 'micro'
    assert (scene_dir / 'data' / 'gt_fruits.json').is_file() and (scene_dir / 'run' / 'counts.json').is_file()
    assert (scene_dir / 'track_counts.json').is_file() and (scene_dir / SCENE_LOG).is_file()
    assert json.loads((scene_dir / SCENE_JSON).read_text())['name'] == 'micro'

    assert not bad.ok and bad.ours is None and bad.peer is None
    assert "SynthError: unknown fruit type 'banana'" in bad.error

    # a scene no view sees a fruit of is reported, not scored (every count would score 1.0 there)
    assert not past.ok and past.gt_count == 8 and past.gt_seen == 0 and past.ours is None and past.peer is None
    assert 'no training view sees any of the 8 fruits' in past.error and 'not scored' in past.error
    assert json.loads((tmp_path / 'past' / 'run' / 'counts.json').read_text())['total'] == 0  # ours ran: 0

    data = json.loads((tmp_path / ACCURACY_JSON).read_text())
    assert data['suite'] == 'test' and data['summary']['failed'] == ['bad', 'past'] and len(data['scenes']) == 3
    assert data['summary']['mean_f1'] == pytest.approx(micro.ours.f1)
    text = (tmp_path / ACCURACY_MD).read_text()
    assert '[count.png](micro/count.png)' in text and "failed: scene: SynthError: unknown fruit type 'banana'" in text


def _dies_or_passes(job: SceneJob) -> SceneResult:
    """Scene function of the crash test: the scene named ``dies`` kills its process."""
    if job.scene.name == 'dies':
        os._exit(3)
    return SceneResult(job.scene.name, job.scene.covers, times_s={'total': 0.0})


def test_a_dead_scene_process_fails_only_its_scene(tmp_path: Path) -> None:
    scenes = [SuiteScene('dies', {}, 'x'), SuiteScene('lives', {}, 'y')]
    suite = run_suite('test', scenes, tmp_path, _options(jobs=2), scene_fn=_dies_or_passes)
    dies, lives = suite.scenes
    assert 'scene process: BrokenProcessPool' in dies.error and lives.ok


def _reads_the_report(job: SceneJob) -> SceneResult:
    """Scene function of the partial-report test: the second scene reads the report the suite holds so far."""
    path = job.out_dir / ACCURACY_JSON
    seen = path.read_text() if path.exists() else ''
    return SceneResult(job.scene.name, seen, times_s={'total': 0.0})


def test_the_report_holds_every_finished_scene_while_the_suite_runs(tmp_path: Path) -> None:
    scenes = [SuiteScene('first', {}, 'x'), SuiteScene('second', {}, 'y'), SuiteScene('third', {}, 'z')]
    suite = run_suite('test', scenes, tmp_path, _options(jobs=1), scene_fn=_reads_the_report)
    assert suite.scenes[0].covers == ''                       # nothing was written before the first scene ended
    during = json.loads(suite.scenes[2].covers)               # what an interrupted run would have left
    assert [s['name'] for s in during['scenes']] == ['first', 'second'] and during['pending'] == ['third']
    text = (tmp_path / ACCURACY_MD).read_text()
    assert 'unfinished' not in text and suite.pending == ()
    final = json.loads((tmp_path / ACCURACY_JSON).read_text())
    assert final['pending'] == [] and len(final['scenes']) == 3


def _reports_its_share(job: SceneJob) -> SceneResult:
    return SceneResult(job.scene.name, str(job.cpu_share), times_s={'total': 0.0})


def test_each_scene_knows_how_many_share_the_cores(tmp_path: Path) -> None:
    """With ``cpu_threads`` 0 (the cpu preset) a scene takes the cores divided among the scenes run at once."""
    two = [SuiteScene('a', {}, 'x'), SuiteScene('b', {}, 'y')]
    assert [s.covers for s in run_suite('test', two, tmp_path, _options(jobs=2), scene_fn=_reports_its_share).scenes] \
        == ['2', '2']
    assert [s.covers for s in run_suite('test', two[:1], tmp_path, _options(jobs=2),
                                        scene_fn=_reports_its_share).scenes] == ['1']   # one scene: alone


def test_refuses_duplicates_and_bag_scenes_without_a_replay(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match='repeated: micro'):
        run_suite('test', [MICRO, MICRO], tmp_path, _options())
    bag = SuiteScene('bagged', {}, 'x', via_bag=True, bag=BagOptions(pose_source='tf'))
    with pytest.raises(ConfigError, match='bag scenes bagged need the bag replay'):
        run_suite('test', [bag], tmp_path, _options())
    with pytest.raises(ConfigError, match='masks must be one of gt, fallback'):
        _options(masks='sam')
    with pytest.raises(ConfigError, match='jobs must be a positive integer'):
        _options(jobs=0)
