"""The live node with a depth_topic: a silent depth topic is reported in /diagnostics like a silent required input."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter

from fruitnerfpp_ros.nodes.fruit_counter import FruitCounterNode
from test.nodes.test_live_nodes import Graph, wait_for

pytestmark = pytest.mark.ros


@pytest.fixture
def graph() -> Any:
    g = Graph()
    yield g
    g.close()


def test_a_silent_depth_topic_warns_in_diagnostics(graph: Graph, tmp_path: Path) -> None:
    overrides = [Parameter('output_dir', value=str(tmp_path / 'run')), Parameter('depth_topic', value='/rgbd/depth'),
                 Parameter('silent_input_warning_s', value=0.3), Parameter('diagnostics_period_s', value=0.2)]
    counter = graph.add(FruitCounterNode(context=graph.context, parameter_overrides=overrides))
    assert counter.assembler.optional_roles() == ['depth']
    listener = graph.add(Node('diagnostics_listener', context=graph.context))
    messages: list[str] = []
    listener.create_subscription(DiagnosticArray, '/diagnostics',
                                 lambda msg: messages.extend(s.message for s in msg.status), 10)
    wait_for(lambda: any('/rgbd/depth' in m for m in messages), 15.0, 'the silent depth topic in /diagnostics')
    assert any('silent inputs' in m and '/rgbd/depth' in m for m in messages)
