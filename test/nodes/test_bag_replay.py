"""Bag replay of a synthetic orchard recording: both storages, results.mcap read back with rosbags and mcap.

Training is not repeated here: the replay reuses the session's tiny trained run of the very same scene
(``skip_training``), so this checks the replay plumbing on real trained output; the live-node test trains.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String, UInt32

from fruitnerfpp_ros.cli.main import main as cli_main
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.nodes.bag_replay import collect_keyframes, replay_bag
from fruitnerfpp_ros.nodes.result_msgs import points_from_cloud_msg
from fruitnerfpp_ros.nodes.log import LogLevel
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from fruitnerfpp_ros.nodes.results import OUTPUT_TOPICS
from test.accuracy_targets import assert_counted
from test.shared_fixtures import TINY_SCENE

#: The scene of the shared ``tiny_apple_dataset`` fixture (same config and seed -> the same tree and views).
SCENE = TINY_SCENE
SETTINGS = settings_from_parameters({'preset': 'tiny', 'device': 'cpu'})


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
    out = tmp_path_factory.mktemp('orchard_bags')
    return {storage: generate_orchard(SynthConfig(**SCENE), out / f'scene_{storage}', bag=out / f'bag_{storage}',
                                      bag_storage=storage).bag_path for storage in ('mcap', 'sqlite3')}


def _quiet(level: LogLevel, message: str) -> None:
    pass


def check_results_mcap(result: Any) -> None:
    """results.mcap holds the node's output topics; rosbags and the mcap library both read it."""
    count = result.count.count
    # rosbags: a bare .mcap file is a bag.
    from rosbags.highlevel import AnyReader
    expected = {f'/fruit_counter/{t.name}' for t in OUTPUT_TOPICS} | {'/diagnostics'}
    with AnyReader([result.results_mcap]) as reader:
        assert {c.topic for c in reader.connections} == expected
        decoded = {c.topic: reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()}
    assert decoded['/fruit_counter/fruit_count'].data == count
    assert len(decoded['/fruit_counter/fruit_centers'].poses) == count
    assert decoded['/diagnostics'].status[0].message.startswith('done')

    # mcap library + rclpy deserialisation.
    from mcap.reader import make_reader
    with open(result.results_mcap, 'rb') as f:
        reader = make_reader(f)
        raw = {channel.topic: (schema.name, channel.message_encoding, message.data)
               for schema, channel, message in reader.iter_messages()}
    assert raw['/fruit_counter/fruit_count'][:2] == ('std_msgs/msg/UInt32', 'cdr')
    assert deserialize_message(raw['/fruit_counter/fruit_count'][2], UInt32).data == count
    assert json.loads(deserialize_message(raw['/fruit_counter/fruit_report'][2], String).data)['total'] == count
    cloud = deserialize_message(raw['/fruit_counter/fruit_cloud'][2], PointCloud2)
    points = points_from_cloud_msg(cloud)
    assert np.array_equal(points['instance_id'], result.count.labels)
    ids = np.unique(points['instance_id'])
    assert set(ids[ids > 0].tolist()) == set(range(1, count + 1))


def test_both_storages_give_the_same_keyframes_as_the_dataset(bags: dict[str, Path], tmp_path: Path,
                                                              tiny_apple_dataset: Path) -> None:
    truth = read_transforms(tiny_apple_dataset)
    collected = {}
    for storage, bag in bags.items():
        collect_keyframes(bag, tmp_path / storage, SETTINGS, log=_quiet)
        collected[storage] = read_transforms(tmp_path / storage)
    mcap, sqlite = collected['mcap'], collected['sqlite3']
    assert len(mcap.frames) == len(truth.frames) == len(sqlite.frames)
    for a, b, t in zip(mcap.frames, sqlite.frames, truth.frames):
        assert a.stamp_ns == b.stamp_ns
        assert np.allclose(a.T_world_camera, t.T_world_camera, atol=1e-6)
        assert np.array_equal(a.T_world_camera, b.T_world_camera)
    assert mcap.intrinsics.cx == pytest.approx(truth.intrinsics.cx) and mcap.intrinsics == sqlite.intrinsics
    for k in (0, 11, 23):
        rgb_bag = cv2.imread(str(tmp_path / 'mcap' / mcap.frames[k].file_path))
        rgb_sql = cv2.imread(str(tmp_path / 'sqlite3' / sqlite.frames[k].file_path))
        rgb_true = cv2.imread(str(tiny_apple_dataset / truth.frames[k].file_path))
        assert np.array_equal(rgb_bag, rgb_true) and np.array_equal(rgb_sql, rgb_true)
        inst_bag = cv2.imread(str(tmp_path / 'mcap' / mcap.frames[k].instance_path), cv2.IMREAD_UNCHANGED)
        inst_true = cv2.imread(str(tiny_apple_dataset / truth.frames[k].instance_path), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(inst_bag, inst_true)


def test_replay_writes_results_mcap_readable_by_rosbags_and_mcap(bags: dict[str, Path], tmp_path: Path,
                                                                 tiny_trained_run: Path) -> None:
    run = tmp_path / 'run'
    shutil.copytree(tiny_trained_run, run)
    result = replay_bag(bags['mcap'], run, SETTINGS, log=_quiet, skip_training=True)
    count = result.count.count
    assert result.n_keyframes == SCENE['views']
    assert json.loads((run / 'counts.json').read_text())['total'] == count
    report = json.loads(result.report_path.read_text())
    assert report['total'] == count and report['frame_id'] == 'map' and report['keyframes'] == SCENE['views']

    check_results_mcap(result)
    assert_counted(count, 20)  # the fixture tree has 20 apples


def test_replay_cli_collects_and_reports_errors_in_one_line(bags: dict[str, Path], tmp_path: Path,
                                                            capsys: pytest.CaptureFixture) -> None:
    assert cli_main(['replay', str(bags['sqlite3']), '--out', str(tmp_path / 'run'), '--no-train']) == 0
    assert f"keyframes: {SCENE['views']}" in capsys.readouterr().out
    assert cli_main(['replay', str(tmp_path / 'missing'), '--out', str(tmp_path / 'run2')]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'no such bag' in err and 'Traceback' not in err
    params = tmp_path / 'p.yaml'
    params.write_text('/**:\n  ros__parameters:\n    image_topic: /nope\n')
    assert cli_main(['replay', str(bags['mcap']), '--out', str(tmp_path / 'run3'), '--params', str(params)]) == 2
    assert 'topics in the bag: /camera/camera_info' in capsys.readouterr().err


def test_results_mcap_with_a_stand_in_pipeline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The replay's output plumbing independent of training quality: run_pipeline returns a known count."""
    from types import SimpleNamespace

    import fruitnerfpp_ros.core.pipeline as pipeline
    from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
    from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
    from test.nodes import bag_factory as bf

    def stand_in(dataset_dir: Path, run_dir: Path, **kwargs: Any) -> Any:
        xyz = np.array([[0, 1, 0], [0.01, 1, 0], [0.5, 1, 0.2], [3, 3, 3]], np.float32)
        cloud = FruitPointCloud(xyz, np.full((4, 3), 200, np.uint8), np.full(4, 0.9, np.float32),
                                np.zeros((4, 2), np.float32))
        fruits = [Fruit(1, np.array([0.005, 1, 0]), 0.07, np.full(3, 0.07), 2),
                  Fruit(2, np.array([0.5, 1, 0.2]), 0.06, np.full(3, 0.06), 1)]
        return SimpleNamespace(count=CountResult(np.array([1, 1, 2, 0], np.int32), fruits), cloud=cloud,
                               stopped=False)

    monkeypatch.setattr(pipeline, 'run_pipeline', stand_in)
    bag = bf.write_bag(tmp_path / 'bag', bf.messages(6), 'sqlite3')
    result = replay_bag(bag, tmp_path / 'run', settings_from_parameters({'min_translation_m': 0.1}), log=_quiet)
    assert result.count.count == 2 and result.n_keyframes == 6
    check_results_mcap(result)
    report = json.loads(result.report_path.read_text())
    assert report['stamp_ns'] == bf.START_NS + 5 * bf.PERIOD_NS and report['fruits'][1]['diameter'] == 0.06
