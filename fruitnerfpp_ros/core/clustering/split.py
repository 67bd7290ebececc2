"""Second look at oversized clusters: a cluster much wider than the orchard's typical fruit is several fruits.

HDBSCAN's excess-of-mass selection keeps two touching fruits as one cluster when their joint cluster is more
persistent than the two halves, even with clearly different embeddings. Fruits of one orchard are alike in size,
so a cluster wider than ``split_diameter_factor`` times the median cluster diameter is clustered again on its own
with leaf selection (which prefers the finer clusters); the split is kept when it finds at least two fruits.
With fewer than three clusters there is no typical fruit: every cluster is a candidate (a cloud whose fruit points
all touch can come out of HDBSCAN as one giant cluster), and its split is kept only when the cluster is wider than
``split_diameter_factor`` times the parts' median diameter (several fruits, not the halves of one).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.count_result import fruit_diameter, label_groups
from fruitnerfpp_ros.core.clustering.hdbscan_cluster import cluster_partition

__all__ = ['cluster_diameters', 'split_oversized']


def cluster_diameters(xyz: np.ndarray, labels: np.ndarray) -> dict[int, tuple[float, np.ndarray]]:
    """Per cluster label >= 0: its diameter (m, :func:`fruit_diameter` about the median centre) and its points."""
    ids, groups = label_groups(labels)
    out = {}
    for label, members in zip(ids, groups):
        p = xyz[members]
        out[int(label)] = (fruit_diameter(p, np.median(p, axis=0)), members)
    return out


def split_oversized(xyz: np.ndarray, embedding: np.ndarray, labels: np.ndarray, config: ClusterConfig,
                    ) -> tuple[np.ndarray, int]:
    """Re-cluster clusters wider than ``config.split_diameter_factor`` x the median cluster diameter.

    Args:
        xyz: [N, 3] positions (m); embedding: [N, D] unit embeddings.
        labels: [N] cluster labels, 0-based, -1 = noise.
        config: the (spacing-scaled) clustering settings.

    Returns:
        (new labels, 0-based with -1 = noise; number of clusters that were split).
    """
    if config.split_diameter_factor <= 0:
        return labels, 0
    diameters = cluster_diameters(xyz, labels)
    # Fewer than three clusters give no typical fruit (one giant cluster and a stray one, say): each is a candidate.
    typical = len(diameters) >= 3
    limit = config.split_diameter_factor * float(np.median([d for d, _ in diameters.values()])) if typical else 0.0
    leaf = dataclasses.replace(config, cluster_selection_method='leaf')
    out, next_label, n_split = labels.copy(), int(labels.max()) + 1, 0
    for diameter, members in diameters.values():
        if diameter <= limit or len(members) < 2 * config.min_fruit_points:
            continue
        local, _ = cluster_partition(xyz[members], embedding[members], leaf, min_cluster_size=config.min_cluster_size,
                                     workers=config.n_jobs)
        sizes = np.bincount(local[local >= 0]) if np.any(local >= 0) else np.zeros(0, np.int64)
        parts = np.flatnonzero(sizes >= config.min_fruit_points)
        if len(parts) < 2:
            continue
        if not typical:  # the parts themselves must be much smaller (not the halves of one fruit)
            kept = np.where(np.isin(local, parts), local, -1)
            part_diameters = [d for d, _ in cluster_diameters(xyz[members], kept).values()]
            if diameter <= config.split_diameter_factor * float(np.median(part_diameters)):
                continue
        new = np.full(len(members), -1, np.int64)
        for part in parts:
            new[local == part] = next_label
            next_label += 1
        out[members] = new
        n_split += 1
    return out, n_split
