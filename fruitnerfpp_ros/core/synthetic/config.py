"""Configuration of the synthetic orchard generator (``fruitnerfpp synth``, ``config/synth.yaml``)."""

from __future__ import annotations

from dataclasses import dataclass

from fruitnerfpp_ros.core.synthetic.fruit_types import FRUIT_NAMES, MIXED
from fruitnerfpp_ros.errors import SynthError

__all__ = ['SynthConfig', 'TRAJECTORIES', 'MIXED_DEFAULT_COUNT']

TRAJECTORIES = ('hemisphere', 'row')
#: Default fruit count of a ``mixed`` tree (split evenly over the six types).
MIXED_DEFAULT_COUNT = 240


@dataclass(frozen=True)
class SynthConfig:
    """Settings of one synthetic tree scene. Invalid values raise :class:`SynthError` on construction."""

    fruit: str = 'apple'
    """Fruit type: apple, plum, lemon, pear, peach, mango, or ``mixed`` (all six types on one tree)."""
    count: int | None = None
    """Number of fruits; None = the type's default (the paper's count: apple 283, plum 745, ...)."""
    views: int = 32
    """Number of rendered camera views."""
    resolution: tuple[int, int] = (128, 128)
    """Image size (width, height) in pixels."""
    trajectory: str = 'hemisphere'
    """``hemisphere``: random views on the upper hemisphere looking at the tree (BlenderNeRF style);
    ``row``: a robot driving along the row on both sides of the tree, camera facing the tree."""
    seed: int = 0
    """Random seed: the same seed gives byte-identical outputs."""
    fov_deg: float = 50.0
    """Field of view across the shorter image side, degrees."""
    leaf_scale: float = 1.0
    """Multiplier on the fruit type's leaf density (0 = no leaves)."""
    cluster_scale: float = 1.0
    """Multiplier on the probability that a fruit hangs in a cluster of touching fruits (0 = all single)."""
    device: str = 'auto'
    """Torch device for rendering: auto (CUDA when present), cpu, cuda."""
    sparse_points: int = 4000
    """Points in ``sparse_pc.ply`` (visible surface points, like a COLMAP sparse cloud)."""
    pose_noise_m: float = 0.0
    """Odometry error: standard deviation (m, per axis) of noise on the recorded camera positions (transforms.json
    and the bag); the images are rendered from the true poses."""
    pose_noise_deg: float = 0.0
    """Standard deviation (degrees, per axis) of a rotation noise on the recorded camera orientations."""

    def __post_init__(self) -> None:
        known = (*FRUIT_NAMES, MIXED)
        if self.fruit not in known:
            raise SynthError(f'unknown fruit type {self.fruit!r}; expected one of {", ".join(known)}')
        if self.count is not None and (isinstance(self.count, bool) or not isinstance(self.count, int)
                                       or self.count < 1 or self.count > 20000):
            raise SynthError(f'count must be an integer between 1 and 20000, got {self.count!r}')
        if isinstance(self.views, bool) or not isinstance(self.views, int) or self.views < 1:
            raise SynthError(f'views must be a positive integer, got {self.views!r}')
        res = tuple(self.resolution)
        if (len(res) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in res)
                or min(res) < 8 or max(res) > 8192):
            raise SynthError(f'resolution must be (width, height) with 8..8192 px each, got {self.resolution!r}')
        object.__setattr__(self, 'resolution', res)
        for name in ('pose_noise_m', 'pose_noise_deg'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0.0 <= value < 1e3:
                raise SynthError(f'{name} must be a number >= 0, got {value!r}')
        if self.trajectory not in TRAJECTORIES:
            raise SynthError(f'unknown trajectory {self.trajectory!r}; expected one of {", ".join(TRAJECTORIES)}')
        if not 10.0 <= float(self.fov_deg) <= 120.0:
            raise SynthError(f'fov_deg must be within 10..120 degrees, got {self.fov_deg!r}')
        if self.leaf_scale < 0 or self.cluster_scale < 0:
            raise SynthError('leaf_scale and cluster_scale must be >= 0')
        if self.sparse_points < 0:
            raise SynthError(f'sparse_points must be >= 0, got {self.sparse_points!r}')

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return self.resolution[0]

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return self.resolution[1]
