"""Fruit types of the synthetic orchard: real sizes, colours, default counts (the paper's synthetic trees).

Sizes are semi-axes in metres in the fruit's own frame, whose z axis is the hanging axis (stem at +z). A
``pear`` is built from two ellipsoids (a wide body and a narrower neck) sharing one instance id.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ['FruitType', 'FRUIT_TYPES', 'FRUIT_NAMES', 'MIXED', 'fruit_type']

MIXED = 'mixed'


@dataclass(frozen=True)
class FruitType:
    """Shape, size, colour and arrangement of one fruit type.

    Attributes:
        name: type name as written to ``gt_fruits.json``.
        default_count: fruits on a default tree (the paper's synthetic scene).
        radii_m: body semi-axes (x, y, z) in metres; z is the hanging axis.
        size_jitter: relative standard deviation of the size between fruits.
        neck_radii_m: semi-axes of a second, upper ellipsoid (pear neck), or None.
        neck_offset_m: height of the neck centre above the body centre, metres.
        base_rgb: main skin colour, linear 0..1.
        blush_rgb: secondary skin colour blended in by surface noise, 0..1.
        blush_amount: fraction of the skin covered by the blush colour (0..1).
        max_tilt_deg: largest tilt of the hanging axis from vertical, degrees.
        stem_length_m: stem length above the fruit, metres.
        radial_range: (inner, outer) position of fruits between crown centre (0) and crown surface (1).
        leaf_density: leaf area per crown surface area (higher = more occlusion).
        cluster_probs: probabilities of clusters of 1, 2, 3... touching fruits.
        leaf_half_size_m: leaf half-length and half-width, metres.
    """

    name: str
    default_count: int
    radii_m: tuple[float, float, float]
    size_jitter: float
    neck_radii_m: tuple[float, float, float] | None
    neck_offset_m: float
    base_rgb: tuple[float, float, float]
    blush_rgb: tuple[float, float, float]
    blush_amount: float
    max_tilt_deg: float
    stem_length_m: float
    radial_range: tuple[float, float]
    leaf_density: float
    cluster_probs: tuple[float, ...]
    leaf_half_size_m: tuple[float, float] = (0.04, 0.02)

    @property
    def bounding_radius_m(self) -> float:
        """Radius of a sphere around the body centre that holds the whole fruit (nominal size)."""
        body = max(self.radii_m)
        if self.neck_radii_m is None:
            return body
        return max(body, self.neck_offset_m + max(self.neck_radii_m))

    @property
    def diameter_m(self) -> float:
        """Nominal largest width across the body, metres (2 x the largest body semi-axis)."""
        return 2.0 * max(self.radii_m[:2])


FRUIT_TYPES: dict[str, FruitType] = {
    'apple': FruitType('apple', 283, (0.037, 0.037, 0.034), 0.08, None, 0.0,
                       (0.70, 0.07, 0.05), (0.80, 0.72, 0.22), 0.35, 20.0, 0.025, (0.8, 1.03), 0.85,
                       (0.5, 0.3, 0.2)),
    'plum': FruitType('plum', 745, (0.021, 0.021, 0.024), 0.08, None, 0.0,
                      (0.32, 0.05, 0.26), (0.45, 0.12, 0.40), 0.3, 15.0, 0.02, (0.76, 1.03), 1.0,
                      (0.35, 0.3, 0.2, 0.15), (0.033, 0.016)),
    'lemon': FruitType('lemon', 326, (0.029, 0.029, 0.042), 0.08, None, 0.0,
                       (0.95, 0.82, 0.12), (0.80, 0.78, 0.18), 0.25, 35.0, 0.02, (0.78, 1.03), 0.95,
                       (0.6, 0.3, 0.1), (0.045, 0.022)),
    'pear': FruitType('pear', 250, (0.034, 0.034, 0.036), 0.08, (0.021, 0.021, 0.030), 0.042,
                      (0.66, 0.72, 0.22), (0.72, 0.45, 0.15), 0.3, 15.0, 0.03, (0.8, 1.03), 0.85,
                      (0.6, 0.3, 0.1), (0.036, 0.022)),
    'peach': FruitType('peach', 152, (0.036, 0.036, 0.035), 0.07, None, 0.0,
                       (0.96, 0.58, 0.22), (0.80, 0.18, 0.10), 0.45, 20.0, 0.01, (0.8, 1.03), 0.85,
                       (0.6, 0.3, 0.1), (0.06, 0.014)),
    'mango': FruitType('mango', 1150, (0.040, 0.034, 0.058), 0.08, None, 0.0,
                       (0.50, 0.66, 0.14), (0.88, 0.32, 0.10), 0.4, 25.0, 0.09, (0.62, 0.98), 1.6,
                       (0.3, 0.3, 0.25, 0.15), (0.10, 0.024)),
}

#: Fruit type names in a fixed order (``mixed`` draws from these in this order).
FRUIT_NAMES: tuple[str, ...] = tuple(FRUIT_TYPES)


def fruit_type(name: str) -> FruitType:
    """The :class:`FruitType` called ``name`` (KeyError when unknown; callers validate first)."""
    return FRUIT_TYPES[name]
