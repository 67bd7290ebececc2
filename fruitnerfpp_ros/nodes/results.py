"""The output messages of a count, shared by the live node (publishers) and bag replay (results.mcap).

Output topics live under the node's name (``~/fruit_count`` of node ``fruit_counter`` is
``/fruit_counter/fruit_count``); results.mcap uses the same full names, so tools read both alike.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.clustering.count_result import CountResult
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.nodes.conversions import time_msg_from_ns
from fruitnerfpp_ros.nodes.result_msgs import (cloud_msg_from_points, markers_from_fruits, pose_array_from_centers,
                                               report_json)
from fruitnerfpp_ros.nodes.status import DiagnosticLevel

__all__ = ['OutputTopic', 'OUTPUT_TOPICS', 'DIAGNOSTICS_TOPIC', 'RESULTS_NODE_NAME', 'result_messages',
           'diagnostics_msg', 'write_report']

#: Default node name; output topics are ``/<node name>/<name>``.
RESULTS_NODE_NAME = 'fruit_counter'
DIAGNOSTICS_TOPIC = '/diagnostics'


class OutputTopic(NamedTuple):
    """One result topic: private name (under the node), ROS type, type name as rosbags spells it."""

    name: str
    msg_type: str
    description: str


OUTPUT_TOPICS = (
    OutputTopic('fruit_count', 'std_msgs/msg/UInt32', 'Number of fruits counted.'),
    OutputTopic('fruit_report', 'std_msgs/msg/String', 'Versioned JSON report (schema fruitnerfpp_ros/fruit_report '
                'v1): stamp, frame_id, total, per fruit id / center / diameter, run_id.'),
    OutputTopic('fruit_cloud', 'sensor_msgs/msg/PointCloud2', 'Fruit points in world_frame: x, y, z float32, rgb '
                '(packed), instance_id uint32 (fruit id, 0 = noise), semantic float32.'),
    OutputTopic('fruit_centers', 'geometry_msgs/msg/PoseArray', 'One pose per fruit centre, in fruit id order.'),
    OutputTopic('fruit_markers', 'visualization_msgs/msg/MarkerArray', 'Per fruit a sphere (diameter) and an id '
                'label, marker id = fruit id.'),
)


def result_messages(count: CountResult, cloud: FruitPointCloud, frame_id: str, stamp_ns: int, run_id: str,
                    extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """rclpy messages of a count keyed by private topic name (see :data:`OUTPUT_TOPICS`)."""
    from std_msgs.msg import String, UInt32
    labels = np.asarray(count.labels)
    if len(labels) != len(cloud):
        labels = np.zeros(len(cloud), np.uint32)
    return {
        'fruit_count': UInt32(data=int(count.count)),
        'fruit_report': String(data=report_json(count, frame_id, stamp_ns, run_id, extra)),
        'fruit_cloud': cloud_msg_from_points(cloud, labels, frame_id, stamp_ns),
        'fruit_centers': pose_array_from_centers(count.centers(), frame_id, stamp_ns),
        'fruit_markers': markers_from_fruits(count.fruits, frame_id, stamp_ns),
    }


def diagnostics_msg(name: str, hardware_id: str, level: DiagnosticLevel, message: str, values: dict[str, Any],
                    stamp_ns: int) -> Any:
    """``diagnostic_msgs/DiagnosticArray`` with one status; ``values`` become key-value pairs (``str`` of each)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from std_msgs.msg import Header
    levels = {DiagnosticLevel.OK: DiagnosticStatus.OK, DiagnosticLevel.WARN: DiagnosticStatus.WARN,
              DiagnosticLevel.ERROR: DiagnosticStatus.ERROR}
    status = DiagnosticStatus(level=levels[level], name=name, message=message, hardware_id=hardware_id,
                              values=[KeyValue(key=str(k), value=str(v)) for k, v in values.items()])
    return DiagnosticArray(header=Header(stamp=time_msg_from_ns(stamp_ns)), status=[status])


def write_report(path: str | Path, report_msg_data: str) -> Path:
    """Write the report JSON (the ``fruit_report`` payload) atomically, pretty-printed."""
    return atomic_write_text(path, json.dumps(json.loads(report_msg_data), indent=1))
