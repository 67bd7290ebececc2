"""The count: fruits found by clustering, the record every output (counts.json, ROS topics) is made from."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ['Fruit', 'CountResult', 'fruit_diameter', 'label_groups']


def label_groups(labels: np.ndarray, index: np.ndarray | None = None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Group points by cluster label (labels < 0 are noise and left out), with one sort.

    Args:
        labels: [N] cluster labels.
        index: [N] what to put in the groups (default: the positions 0..N-1).

    Returns:
        (the K labels present, ascending; K arrays of ``index`` values, one per label, in input order).
    """
    valid = labels >= 0
    if not np.any(valid):
        return np.zeros(0, labels.dtype), []
    order = np.argsort(labels[valid], kind='stable')
    points = (np.flatnonzero(valid) if index is None else np.asarray(index)[valid])[order]
    sorted_labels = labels[valid][order]
    starts = np.flatnonzero(np.r_[True, sorted_labels[1:] != sorted_labels[:-1]])
    return sorted_labels[starts], np.split(points, starts[1:])


def fruit_diameter(points: np.ndarray, center: np.ndarray, percentile: float = 90.0) -> float:
    """Diameter (m) of a fruit's points [N, 3]: twice the ``percentile`` distance to its ``center``; 0 for a single
    point. 90 (robust to stray points) where ``center`` is the points' own median, which for a cap seen from one
    side lies inside the cap; 50 where ``center`` is the fruit's centre, so every surface point lies about a radius
    from it."""
    if len(points) < 2:
        return 0.0
    return 2.0 * float(np.percentile(np.linalg.norm(np.asarray(points, np.float64) - center, axis=1), percentile))


@dataclass(frozen=True)
class Fruit:
    """One counted fruit.

    Attributes:
        id: cluster id, starting at 1 (0 is noise everywhere).
        center: [3] robust (median) centre in metres, world frame.
        diameter_m: estimated diameter in metres.
        extent_m: [3] axis-aligned size of the cluster in metres.
        n_points: number of cloud points in the cluster.
        source: ``cloud`` (a cluster of the cloud) or ``masks`` (triangulated from the training views' masks where
            the cloud has no points: core/clustering/mask_fruits.py; ``n_points`` 0).
    """

    id: int
    center: np.ndarray
    diameter_m: float
    extent_m: np.ndarray
    n_points: int
    source: str = 'cloud'

    def to_json(self) -> dict[str, Any]:
        return {'id': int(self.id), 'center': [float(v) for v in self.center], 'diameter': float(self.diameter_m),
                'extent': [float(v) for v in self.extent_m], 'n_points': int(self.n_points),
                'source': self.source}


@dataclass(frozen=True)
class CountResult:
    """Clusters of a fruit point cloud.

    Attributes:
        labels: [N] int32 cluster id per cloud point (0 = noise / unassigned).
        fruits: one record per cluster, ids 1..count in order.
        stats: free-form figures for reports (timings, partition count...).
    """

    labels: np.ndarray
    fruits: list[Fruit]
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.fruits)

    def centers(self) -> np.ndarray:
        """[count, 3] fruit centres."""
        return np.array([f.center for f in self.fruits], dtype=np.float64).reshape(-1, 3)
