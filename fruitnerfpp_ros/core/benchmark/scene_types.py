"""The records an accuracy suite is made of: :class:`SuiteScene` (a synthetic scene's SynthConfig fields, whether
it goes through a bag, what it covers), :class:`BagOptions` and :class:`Suite`. The suites themselves are data in
:mod:`.suites` and :mod:`.blind_suite`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, Mapping

from fruitnerfpp_ros.errors import ConfigError

if TYPE_CHECKING:
    from fruitnerfpp_ros.core.synthetic import SynthConfig

__all__ = ['BagOptions', 'SuiteScene', 'Suite', 'row_fields']


@dataclass(frozen=True)
class BagOptions:
    """How a ``via_bag`` scene is recorded and replayed (the image format and world frame are SynthConfig fields:
    ``bag_image_format``, ``world_frame``)."""

    storage: Literal['mcap', 'sqlite3'] = 'mcap'
    """rosbag2 storage plugin of the recording."""
    pose_source: Literal['pose', 'tf'] = 'pose'
    """Replay parameter ``pose_source``: the PoseStamped topic, or the /tf + /tf_static chain from the world frame
    to the camera's optical frame."""
    params: Mapping[str, Any] = field(default_factory=dict)
    """Further replay parameters (``config/fruit_counter.yaml`` names), applied last."""

    def __post_init__(self) -> None:
        if self.storage not in ('mcap', 'sqlite3'):
            raise ConfigError(f'BagOptions.storage must be mcap or sqlite3, got {self.storage!r}')
        if self.pose_source not in ('pose', 'tf'):
            raise ConfigError(f'BagOptions.pose_source must be pose or tf, got {self.pose_source!r}')
        object.__setattr__(self, 'params', dict(self.params))  # a copy (picklable, unlike a mappingproxy)


@dataclass(frozen=True)
class SuiteScene:
    """One scene of a suite.

    Example::

        SuiteScene('apple_hemi_20', dict(fruit='apple', count=20, views=48, resolution=(96, 96)), 'CI scene')
    """

    name: str
    """Unique name within the suite; the scene's folder under the output directory."""
    synth: Mapping[str, Any]
    """``SynthConfig`` fields of the scene (the rest keep their defaults)."""
    covers: str
    """Which axes of variation the scene covers, in a few words (shown in the report)."""
    via_bag: bool = False
    """Record the scene as a rosbag2 and count it through the bag replay (``fruitnerfpp replay``), as a robot user
    would; otherwise the pipeline runs on the transforms.json dataset (``fruitnerfpp run``)."""
    bag: BagOptions = field(default_factory=BagOptions)
    """Recording and replay options of a ``via_bag`` scene."""

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace('_', '').replace('-', '').isalnum():
            raise ConfigError(f'scene name must be letters, digits, _ and -, got {self.name!r}')
        object.__setattr__(self, 'synth', dict(self.synth))  # a copy (picklable, unlike a mappingproxy)

    def synth_config(self, device: str = 'auto') -> SynthConfig:
        """The scene's :class:`~fruitnerfpp_ros.core.synthetic.SynthConfig`, rendered on ``device``.

        Raises:
            SynthError: a field has an impossible value.
            ConfigError: a field SynthConfig does not have.
        """
        from fruitnerfpp_ros.core.synthetic import SynthConfig

        try:
            return SynthConfig(**{'device': device, **self.synth})
        except TypeError as err:
            raise ConfigError(f'scene {self.name}: {err}') from err


@dataclass(frozen=True)
class Suite:
    """A named list of scenes and the training preset it is meant for."""

    name: str
    """The suite's name (``quick``, ``cpu``, ``holdout``, ``blind``, ``gpu``, ``smoke``)."""
    preset: str
    """Training preset used unless the caller names another."""
    scenes: tuple[SuiteScene, ...]
    """The scenes, in run order."""
    description: str
    """What the suite is for and how long it takes."""


def row_fields(**fields: Any) -> dict[str, Any]:
    """SynthConfig fields of a row drive: no sparse cloud (a robot has no SfM), plus ``fields``."""
    return {'trajectory': 'row', 'sparse_points': 0, **fields}
