"""What a trained scene answers at 3D points: the interface between training and export."""

from __future__ import annotations

from typing import NamedTuple, Protocol

import torch

__all__ = ['FieldQuery', 'QueryableField']


class FieldQuery(NamedTuple):
    """Field values at N points (all on the field's device, no autograd graph).

    Attributes:
        density: [N] volume density sigma (1/m), >= 0.
        rgb: [N, 3] colour in [0, 1] (view direction fixed by the field, e.g. looking down -z).
        fruit_prob: [N] sigmoid of the semantic logit, in [0, 1].
        embedding: [N, D] instance embedding, L2-normalised.
    """

    density: torch.Tensor
    rgb: torch.Tensor
    fruit_prob: torch.Tensor
    embedding: torch.Tensor


class QueryableField(Protocol):
    """A trained FruitNeRF++ field that the exporter can sample."""

    @property
    def embedding_dim(self) -> int:
        """D, the instance embedding size."""

    def query(self, xyz: torch.Tensor) -> FieldQuery:
        """Evaluate the field at world points ``xyz`` [N, 3] (metres); callers batch N themselves."""
