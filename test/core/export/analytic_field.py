"""A stand-in QueryableField: solid spheres with known density, colour, fruit probability and embedding."""

from __future__ import annotations

import numpy as np
import torch

from fruitnerfpp_ros.core.fields.query import FieldQuery


class SphereField:
    """Fruit spheres (fruit probability ``fruit_prob``) and leaf spheres (probability 0.05), each with its own
    unit embedding; density ``density`` inside any sphere, 0 outside."""

    def __init__(self, fruit_centers: np.ndarray, radius: float, *, leaf_centers: np.ndarray | None = None,
                 dim: int = 16, density: float = 500.0, fruit_prob: float = 0.95, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        leaves = np.zeros((0, 3)) if leaf_centers is None else np.asarray(leaf_centers)
        self.centers = torch.as_tensor(np.concatenate([fruit_centers, leaves]), dtype=torch.float32)
        self.is_fruit = torch.arange(len(self.centers)) < len(fruit_centers)
        emb = rng.normal(size=(len(self.centers), dim))
        self.embeddings = torch.as_tensor(emb / np.linalg.norm(emb, axis=1, keepdims=True), dtype=torch.float32)
        self.radius, self.density, self.fruit_prob, self._dim = radius, density, fruit_prob, dim
        self.calls = 0

    @property
    def embedding_dim(self) -> int:
        return self._dim

    def query(self, xyz: torch.Tensor) -> FieldQuery:
        self.calls += 1
        dist = torch.cdist(xyz, self.centers)  # [N, S]
        nearest = dist.argmin(dim=1)
        inside = dist.gather(1, nearest[:, None])[:, 0] <= self.radius
        fruit = inside & self.is_fruit[nearest]
        density = torch.where(inside, torch.tensor(self.density), torch.tensor(0.0))
        prob = torch.where(fruit, torch.tensor(self.fruit_prob), torch.tensor(0.05))
        rgb = torch.where(fruit[:, None], torch.tensor([0.8, 0.1, 0.1]), torch.tensor([0.1, 0.6, 0.1]))
        return FieldQuery(density, rgb, prob, self.embeddings[nearest])
