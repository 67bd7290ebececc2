"""The output messages of a row count (fruit_counter's row mode): the same fruit topics as a single count plus
``~/tree_counts`` and ``~/tree_markers``.

Fruit ids are the row's (1..N along the row) in ``~/fruit_cloud``'s ``instance_id``, the fruit markers, the
centres' order and the report; ``~/tree_markers`` holds per tree a trunk cylinder (ns ``trees``) and a label
``tree <id>: <count>`` (ns ``tree_labels``), marker id = tree id, green when the tree is complete, grey while the
robot still passes it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np

from fruitnerfpp_ros.core.clustering.count_result import Fruit
from fruitnerfpp_ros.core.export.npz_io import read_cloud
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.orchard.row_run import RowResult
from fruitnerfpp_ros.core.orchard.trees import TreeCount
from fruitnerfpp_ros.errors import FruitNerfError
from fruitnerfpp_ros.nodes.conversions import pose_msg_from_transform, time_msg_from_ns
from fruitnerfpp_ros.nodes.result_msgs import cloud_msg_from_points, markers_from_fruits, pose_array_from_centers
from fruitnerfpp_ros.nodes.results import OutputTopic

__all__ = ['ROW_OUTPUT_TOPICS', 'row_messages', 'tree_markers', 'row_cloud']

ROW_OUTPUT_TOPICS = (
    OutputTopic('tree_counts', 'std_msgs/msg/String', 'Row report JSON (schema fruitnerfpp_ros/fruit_report v2): per '
                'tree id, position, WGS84, count, diameter mean / spread, complete; per fruit its tree; segments.'),
    OutputTopic('tree_markers', 'visualization_msgs/msg/MarkerArray', 'Per tree a trunk cylinder (ns trees) and a '
                "label 'tree <id>: <count>' (ns tree_labels), marker id = tree id."),
)


class _Segment(NamedTuple):
    cloud: FruitPointCloud
    labels: np.ndarray


def row_cloud(result: RowResult, cloud_dirs: dict[int, Path]) -> tuple[FruitPointCloud, np.ndarray]:
    """The points of every kept fruit, from its segment's cloud (``<dir>/run/cloud.npz``), labelled with its row
    fruit id (1..N); segments whose cloud is missing are left out."""
    parts, labels = [], []
    fruits = result.fruits
    for index in np.unique(fruits.segments):
        path = cloud_dirs.get(int(index), Path('-')) / 'run' / 'cloud.npz'
        try:
            cloud, local = read_cloud(path)
        except (FruitNerfError, OSError, ValueError):
            continue
        if local is None:
            continue
        mine = np.flatnonzero(fruits.segments == index)
        lookup = dict(zip(fruits.local_ids[mine].tolist(), (mine + 1).tolist()))
        row_ids = np.array([lookup.get(int(v), 0) for v in local], np.int64)
        keep = row_ids > 0
        parts.append(cloud.subset(keep))
        labels.append(row_ids[keep])
    if not parts:
        return FruitPointCloud.empty(0), np.zeros(0, np.int64)
    dim = min(p.embedding_dim for p in parts)
    cloud = FruitPointCloud(np.concatenate([p.xyz for p in parts]), np.concatenate([p.rgb for p in parts]),
                            np.concatenate([p.semantic for p in parts]),
                            np.concatenate([p.embedding[:, :dim] for p in parts]))
    return cloud, np.concatenate(labels)


def tree_markers(trees: Sequence[TreeCount], frame_id: str, stamp_ns: int, height_m: float = 1.0) -> Any:
    """``visualization_msgs/MarkerArray``: DELETEALL, then per tree a trunk cylinder and a count label."""
    from std_msgs.msg import ColorRGBA, Header
    from visualization_msgs.msg import Marker, MarkerArray
    header = Header(stamp=time_msg_from_ns(stamp_ns), frame_id=frame_id)
    markers = [Marker(header=header, action=Marker.DELETEALL)]
    for tree in trees:
        colour = ColorRGBA(r=0.2, g=0.8, b=0.2, a=0.9) if tree.complete else ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.6)
        pose = pose_msg_from_transform(np.eye(4))
        pose.position.x, pose.position.y, pose.position.z = float(tree.position[0]), float(tree.position[1]), \
            0.5 * height_m
        trunk = Marker(header=header, ns='trees', id=int(tree.id), type=Marker.CYLINDER, action=Marker.ADD,
                       pose=pose, color=colour)
        trunk.scale.x = trunk.scale.y = 0.05
        trunk.scale.z = height_m
        label_pose = pose_msg_from_transform(np.eye(4))
        label_pose.position.x, label_pose.position.y = pose.position.x, pose.position.y
        label_pose.position.z = height_m + 0.25
        label = Marker(header=header, ns='tree_labels', id=int(tree.id), type=Marker.TEXT_VIEW_FACING,
                       action=Marker.ADD, pose=label_pose, text=f'tree {tree.id}: {tree.count}', color=colour)
        label.scale.z = 0.12
        markers += [trunk, label]
    return MarkerArray(markers=markers)


def row_messages(result: RowResult, frame_id: str, cloud_dirs: dict[int, Path]) -> dict[str, Any]:
    """rclpy messages of a row count keyed by private topic name (the fruit topics and :data:`ROW_OUTPUT_TOPICS`)."""
    from std_msgs.msg import String, UInt32
    stamp_ns = int(result.report['stamp_ns'])
    fruits = result.fruits
    records = [Fruit(k + 1, fruits.centers[k], float(fruits.diameters[k]), np.zeros(3), int(fruits.n_points[k]))
               for k in range(len(fruits))]
    cloud, labels = row_cloud(result, cloud_dirs)
    top = float(np.max(fruits.centers[:, 2])) if len(fruits) else 1.0
    return {
        'fruit_count': UInt32(data=len(fruits)),
        'tree_counts': String(data=json.dumps(result.report)),
        'fruit_cloud': cloud_msg_from_points(cloud, labels, frame_id, stamp_ns),
        'fruit_centers': pose_array_from_centers(fruits.centers, frame_id, stamp_ns),
        'fruit_markers': markers_from_fruits(records, frame_id, stamp_ns),
        'tree_markers': tree_markers(result.tree_counts, frame_id, stamp_ns, height_m=top),
    }
