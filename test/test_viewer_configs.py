"""rviz/fruit_counter.rviz and foxglove/fruit_counter.json show only what fruit_counter publishes: its output topics
(single count and row mode) with a display of the topic's message type, /diagnostics, and its world frame."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterator

import yaml

from fruitnerfpp_ros.nodes.result_msgs import CLOUD_DTYPE
from fruitnerfpp_ros.nodes.params import CounterSettings
from fruitnerfpp_ros.nodes.results import DIAGNOSTICS_TOPIC, OUTPUT_TOPICS
from fruitnerfpp_ros.nodes.row_results import ROW_OUTPUT_TOPICS

ROOT = Path(__file__).resolve().parents[1]
#: Every topic fruit_counter publishes (default node name, no namespace) -> its message type.
PUBLISHED = {f'/fruit_counter/{t.name}': t.msg_type for t in OUTPUT_TOPICS + ROW_OUTPUT_TOPICS}
PUBLISHED[DIAGNOSTICS_TOPIC] = 'diagnostic_msgs/msg/DiagnosticArray'
WORLD_FRAME = CounterSettings().world_frame
#: RViz display class -> the message type it shows.
RVIZ_TYPES = {'rviz_default_plugins/PointCloud2': 'sensor_msgs/msg/PointCloud2',
              'rviz_default_plugins/MarkerArray': 'visualization_msgs/msg/MarkerArray',
              'rviz_default_plugins/PoseArray': 'geometry_msgs/msg/PoseArray'}


def _strings(value: Any) -> Iterator[str]:
    """Every string key and value of a JSON document."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield k
            yield from _strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from _strings(v)
    elif isinstance(value, str):
        yield value


def test_rviz_config_shows_the_node_outputs_in_its_frame() -> None:
    config = yaml.safe_load((ROOT / 'rviz/fruit_counter.rviz').read_text())
    manager = config['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == WORLD_FRAME
    shown = {}
    for display in manager['Displays']:
        if 'Topic' not in display:
            assert display['Class'] == 'rviz_default_plugins/Grid'
            continue
        topic = display['Topic']['Value']
        assert topic in PUBLISHED, f'{display["Name"]}: {topic} is not published by fruit_counter'
        assert RVIZ_TYPES[display['Class']] == PUBLISHED[topic], f'{display["Name"]}: wrong display for {topic}'
        assert display['Topic']['Durability Policy'] == 'Transient Local'  # the outputs are latched
        shown[topic] = display
    assert {'/fruit_counter/fruit_cloud', '/fruit_counter/fruit_markers', '/fruit_counter/tree_markers'} <= set(shown)
    cloud = shown['/fruit_counter/fruit_cloud']
    assert cloud['Channel Name'] in CLOUD_DTYPE.names and cloud['Channel Name'] == 'instance_id'
    frames = {d.get('Reference Frame') for d in manager['Displays']} - {None, '<Fixed Frame>'}
    assert not frames


def test_foxglove_layout_shows_the_node_outputs_in_its_frame() -> None:
    layout = json.loads((ROOT / 'foxglove/fruit_counter.json').read_text())
    panels = layout['configById']
    topics = {s.split('.')[0] for s in _strings(layout) if s.startswith('/')}
    assert topics and topics <= set(PUBLISHED), f'not published by fruit_counter: {topics - set(PUBLISHED)}'
    scene = next(v for k, v in panels.items() if k.startswith('3D!'))
    assert scene['followTf'] == WORLD_FRAME
    assert all(layer.get('frameId', WORLD_FRAME) == WORLD_FRAME for layer in scene['layers'].values())
    assert {'/fruit_counter/fruit_cloud', '/fruit_counter/fruit_markers', '/fruit_counter/tree_markers'} <= set(
        scene['topics'])
    assert scene['topics']['/fruit_counter/fruit_cloud']['colorField'] in CLOUD_DTYPE.names
    # every panel the layout places is configured, and every configured panel is placed
    placed = {s for s in _strings(layout['layout']) if '!' in s}
    assert placed == set(panels)
