"""fruit_counter's row mode on a real ROS graph: orchard_sim replays a tiny row bag (images, masks, poses, GNSS);
segments are counted in the background as the robot passes them (a stand-in for training that returns the fruits
the segment's keyframes show), ~/tree_counts and ~/fruit_count update, /diagnostics shows the segments."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String, UInt32
from std_srvs.srv import Trigger

from fruitnerfpp_ros.core.orchard.latency import read_events, segment_latencies
from fruitnerfpp_ros.nodes.fruit_counter import LATCHED_QOS, FruitCounterNode
from test.core.orchard.conftest import TINY_ROW, fruits_shown_by_stamps
from test.nodes.test_live_nodes import Graph, wait_for

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def row_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from fruitnerfpp_ros.core.synthetic import SynthConfig
    from fruitnerfpp_ros.core.synthetic.row_scene import RowSceneConfig, generate_row

    out = tmp_path_factory.mktemp('row_node')
    generate_row(SynthConfig(**TINY_ROW), RowSceneConfig(trees=3, gnss=True), out / 'ds', bag=out / 'bag')
    return out


def test_row_mode_publishes_tree_counts_while_the_row_is_driven(row_bag: Path, tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    import fruitnerfpp_ros.nodes.row_counter as row_counter
    from fruitnerfpp_ros.nodes.orchard_sim import OrchardSimNode

    gt = json.loads((row_bag / 'ds' / 'gt_fruits.json').read_text())['fruits']

    monkeypatch.setattr(row_counter, 'train_segment', fruits_shown_by_stamps(row_bag / 'ds' / 'gt_fruits.json'))
    graph = Graph()
    try:
        params = dict(output_dir=str(tmp_path / 'run'), input_reliability='reliable', min_translation_m=0.05,
                      diagnostics_period_s=0.2, row_mode=True, gnss_topic='/gnss/fix',
                      gnss_antenna_offset='0 -0.5 0', row_standoff_m=1.2, row_flush_after_s=60.0,
                      planting_map=str(row_bag / 'ds' / 'planting_map.csv'))
        counter = graph.add(FruitCounterNode(context=graph.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()]))
        listener = graph.add(Node('farm', context=graph.context))
        reports: list[dict[str, Any]] = []
        totals: list[int] = []
        diagnostics: list[DiagnosticArray] = []
        listener.create_subscription(String, '/fruit_counter/tree_counts', lambda m: reports.append(json.loads(m.data)),
                                     LATCHED_QOS)
        listener.create_subscription(UInt32, '/fruit_counter/fruit_count', lambda m: totals.append(m.data),
                                     LATCHED_QOS)
        listener.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 10)
        sim = graph.add(OrchardSimNode(context=graph.context, parameter_overrides=[
            # 5 Hz: a 7 s drive, so a stall of the loaded CI machine (4 s once at 20 Hz) still leaves frames to come
            Parameter('source', value=str(row_bag / 'bag')), Parameter('rate_hz', value=5.0)]))
        wait_for(lambda: sim.done, 30, 'orchard_sim to publish the row')
        wait_for(lambda: len(counter.store) >= 30, 10, 'the keyframes of the drive')
        wait_for(lambda: bool(reports), 20, 'a first ~/tree_counts')
        first = reports[0]
        # counted while driving: the first report covers only the segments passed so far
        assert first['version'] == 2 and first['kind'] == 'row' and len(first['trees']) == 3
        assert first['keyframes'] < len(counter.store) and len(first['segments']) < 3
        answer = graph.call(listener.create_client(Trigger, '/fruit_counter/train'))  # the drive is over
        assert answer.success and answer.message.startswith('row:')
        wait_for(lambda: bool(reports) and reports[-1]['total'] == len(gt)
                 and all(t['complete'] for t in reports[-1]['trees']), 30, 'the whole row counted')
        last = reports[-1]
        assert [t['count'] for t in last['trees']] == [t['n_fruits'] for t in json.loads(
            (row_bag / 'ds' / 'gt_trees.json').read_text())['trees']]
        assert last['georef']['source'] == 'gnss' and last['georef']['residual_rms_m'] < 0.1
        assert 'latitude' in last['trees'][0]
        wait_for(lambda: bool(totals) and totals[-1] == len(gt), 5, '~/fruit_count = the row total')
        assert totals == sorted(totals)

        def row_values() -> dict[str, str]:
            return {kv.key: kv.value for d in diagnostics[-1:] for kv in d.status[0].values}
        wait_for(lambda: row_values().get('row/segments_done') == '3', 5, '/diagnostics: 3 segments done')
        assert row_values()['row/fixes'] != '0'
        assert (tmp_path / 'run' / 'row' / 'trees.geojson').is_file()
        events = read_events(tmp_path / 'run' / 'row' / 'events.jsonl')
        assert {e['event'] for e in events} == {'keyframe', 'queued', 'training', 'trained', 'published'}
        lags = segment_latencies(events)        # every segment passed and counted, each after it was passed
        assert [lag.segment for lag in lags] == sorted({e['segment'] for e in events if e['event'] == 'trained'})
        assert len(lags) == 3 and all(lag.first_count_s is not None and lag.first_count_s >= 0 for lag in lags)
        assert all(lag.final_count_s is not None for lag in lags)
    finally:
        graph.close()
