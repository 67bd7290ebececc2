"""The fruit point cloud: the record passed from export to clustering (and to the ROS cloud publisher)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fruitnerfpp_ros.errors import ExportError

__all__ = ['FruitPointCloud']


@dataclass(frozen=True)
class FruitPointCloud:
    """Points kept by the export, in the dataset's world frame.

    Attributes:
        xyz: [N, 3] float32 positions in metres.
        rgb: [N, 3] uint8 colours.
        semantic: [N] float32 fruit probability in [0, 1].
        embedding: [N, D] float32 instance embeddings (L2-normalised).
        spacing_m: the sampling grid's spacing (the export voxel, m) when known; clustering scales its cluster
            sizes to it (``ClusterConfig.reference_spacing_m``). Saved in the PLY header and the .npz.
        fruit_diameter_m: the scene's fruit diameter when known; clustering scales its lengths (the Euclidean
            weight, partition overlap) and sizes to it (``ClusterConfig.reference_fruit_diameter_m``). Saved too.
        view_dir: [N, 3] float32 or None: per point, the mean of the unit directions of the camera rays that put
            it there (length 1 when every ray came from one direction, shorter when they spread). Clustering moves
            a point along it towards its fruit's centre (``ClusterConfig.centre_shift_diameters``): the caps of
            one fruit seen from the two sides of a row then meet. None when unknown (a grid export, an older file).

    Raises:
        ExportError: the arrays' shapes disagree.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    semantic: np.ndarray
    embedding: np.ndarray
    spacing_m: float | None = None
    fruit_diameter_m: float | None = None
    view_dir: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.xyz)
        if self.xyz.shape != (n, 3) or self.rgb.shape != (n, 3) or self.semantic.shape != (n,) \
                or self.embedding.ndim != 2 or len(self.embedding) != n \
                or (self.view_dir is not None and self.view_dir.shape != (n, 3)):
            raise ExportError(f'inconsistent FruitPointCloud shapes: xyz {self.xyz.shape}, rgb {self.rgb.shape}, '
                              f'semantic {self.semantic.shape}, embedding {self.embedding.shape}'
                              + ('' if self.view_dir is None else f', view_dir {self.view_dir.shape}'))

    def __len__(self) -> int:
        return len(self.xyz)

    @property
    def embedding_dim(self) -> int:
        return int(self.embedding.shape[1])

    @classmethod
    def empty(cls, embedding_dim: int, spacing_m: float | None = None,
              fruit_diameter_m: float | None = None) -> 'FruitPointCloud':
        return cls(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), np.zeros(0, np.float32),
                   np.zeros((0, embedding_dim), np.float32), spacing_m, fruit_diameter_m)

    def one_embedding(self) -> 'FruitPointCloud':
        """A copy whose points all have the same unit embedding (the first axis): for a run whose instance field was
        not trained, so the count tells fruits apart by position alone (the cosine term 0, every pair agreeing)."""
        embedding = np.zeros_like(self.embedding)
        embedding[:, :1] = 1.0
        return dataclasses.replace(self, embedding=embedding)

    def subset(self, mask_or_index: np.ndarray) -> 'FruitPointCloud':
        return FruitPointCloud(self.xyz[mask_or_index], self.rgb[mask_or_index], self.semantic[mask_or_index],
                               self.embedding[mask_or_index], self.spacing_m, self.fruit_diameter_m,
                               None if self.view_dir is None else self.view_dir[mask_or_index])
