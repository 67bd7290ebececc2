"""Parameters of counting a whole row, live (fruit_counter ``row_mode``) or offline (``fruitnerfpp orchard --params``):
declared, typed and documented in one place, beside the counter's own (:mod:`.params`).

A params file for a row holds both sets under ``ros__parameters`` (``config/orchard_row.yaml``);
:func:`split_parameters` sorts the names into the two. :func:`orchard_config` maps the row settings (plus an
optional ``orchard_config_file``, the YAML of :class:`~fruitnerfpp_ros.core.orchard.config.OrchardConfig`) onto the
core's config.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from fruitnerfpp_ros.core.config_io import config_from_mapping, load_yaml_mapping, replace_nested
from fruitnerfpp_ros.errors import ConfigError
from fruitnerfpp_ros.nodes.params import ParamSpec

__all__ = ['RowSettings', 'ROW_PARAMETERS', 'split_parameters', 'row_settings_from_parameters', 'orchard_config',
           'declare_row_parameters', 'row_parameter_table', 'parse_vector']


def _p(default: Any, description: str) -> Any:
    return field(default=default, metadata={'description': description})


@dataclass(frozen=True)
class RowSettings:
    """Row parameters (see each field's ``description``)."""

    row_mode: bool = _p(False, 'Count a whole row segment by segment while driving: each stretch of the row is '
                        'trained in the background as soon as the robot has passed it; ~/tree_counts and '
                        '~/fruit_count (the running row total) update per finished segment. False = one field for '
                        'everything on ~/train (the single-tree behaviour).')
    gnss_topic: str = _p('', "sensor_msgs/NavSatFix of the robot's GNSS antenna; with the poses it gives the world "
                         "frame <-> WGS84 relation (a yaw and a translation, as navsat_transform). '' = none.")
    datum: str = _p('', "'latitude longitude altitude [yaw_deg]' of world_frame's origin and the heading of its x "
                    "axis (degrees counter-clockwise from east); '' = estimated from gnss_topic.")
    gnss_antenna_offset: str = _p('', "'x y z': the GNSS antenna in the camera optical frame (x right, y down, z "
                                  "forward), metres; '' = at the camera.")
    planting_map: str = _p('', 'CSV (tree_id, x, y in world_frame or latitude, longitude) or GeoJSON points of the '
                           "trunks: trees and one segment per tree; '' = trees found from the fruit.")
    row_id: str = _p('1', 'Name of the row in the outputs.')
    segment_length_m: float = _p(0.0, 'Length of a segment along the row, metres; 0 = one segment per tree with a '
                                 'planting map, else 1.5 m.')
    segment_margin_m: float = _p(0.5, "A segment's keyframes see its stretch plus this much on both sides, metres.")
    tree_spacing_m: float = _p(0.0, 'Known tree spacing along the row, metres; 0 = the number of trees is found from '
                               'the fruit.')
    row_standoff_m: float = _p(0.0, "Distance from the camera to the row's centre line, metres; 0 = offline: "
                               'midway between the passes of a drive on both sides; live (the row frame is fixed '
                               'during the first pass) and one side only: 2 m.')
    orchard_config_file: str = _p('', 'Optional OrchardConfig YAML (config/orchard.yaml): segments, merge, trees, '
                                  'geo; the parameters above override it.')
    retrain_on_return: bool = _p(True, 'Live: train a segment again when the robot passes it on the way back (both '
                                 'sides in one field); its count replaces the first.')
    row_flush_after_s: float = _p(10.0, 'Live: count the segments not passed yet when no keyframe arrived for this '
                                  'long, seconds (also on ~/train).')

    def __post_init__(self) -> None:
        if self.segment_length_m < 0 or self.segment_margin_m < 0 or self.tree_spacing_m < 0 \
                or self.row_standoff_m < 0 or self.row_flush_after_s <= 0:
            raise ConfigError('segment_length_m, segment_margin_m, tree_spacing_m and row_standoff_m must be >= 0 and '
                              'row_flush_after_s > 0')
        if self.gnss_antenna_offset:
            parse_vector(self.gnss_antenna_offset, 'gnss_antenna_offset', 3)
        if self.datum:
            parse_vector(self.datum, 'datum', (3, 4))


ROW_PARAMETERS: tuple[ParamSpec, ...] = tuple(
    ParamSpec(f.name, f.default, f.metadata['description']) for f in dataclasses.fields(RowSettings))


def parse_vector(text: str, name: str, length: int | tuple[int, ...]) -> tuple[float, ...]:
    """Numbers of a 'a b c' parameter (commas allowed).

    Raises:
        ConfigError: not numbers, or not ``length`` of them.
    """
    lengths = (length,) if isinstance(length, int) else length
    try:
        values = tuple(float(v) for v in text.replace(',', ' ').split())
    except ValueError as err:
        raise ConfigError(f'{name}: not numbers: {text!r}') from err
    if len(values) not in lengths:
        raise ConfigError(f'{name}: expected {" or ".join(map(str, lengths))} numbers, got {text!r}')
    return values


def split_parameters(values: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(fruit_counter parameters, row parameters) of one params mapping."""
    row_names = {p.name for p in ROW_PARAMETERS}
    return ({k: v for k, v in values.items() if k not in row_names},
            {k: v for k, v in values.items() if k in row_names})


def row_settings_from_parameters(values: Mapping[str, Any] | None) -> RowSettings:
    """Validated row settings (missing ones keep their defaults).

    Raises:
        ConfigError: unknown name, wrong type or out of range.
    """
    values = dict(values or {})
    for spec in ROW_PARAMETERS:
        if isinstance(spec.default, float) and isinstance(values.get(spec.name), int) \
                and not isinstance(values.get(spec.name), bool):
            values[spec.name] = float(values[spec.name])
    return config_from_mapping(RowSettings, values)


def orchard_config(row: RowSettings, sections: Mapping[str, Any] | None = None) -> Any:
    """The core's OrchardConfig: ``orchard_config_file`` (or ``sections``, e.g. a ``--config`` file's ``orchard``
    section), then the row parameters that are set (``segment_margin_m`` and ``row_id`` at their defaults leave the
    file's values).

    Raises:
        ConfigError: an unreadable file or an unknown key.
    """
    from fruitnerfpp_ros.core.orchard.config import OrchardConfig

    base: Mapping[str, Any] = dict(sections or {})
    if row.orchard_config_file:
        data = load_yaml_mapping(Path(row.orchard_config_file), kind='orchard_config_file')
        base = data.get('orchard', data)
    config = config_from_mapping(OrchardConfig, base)
    default = RowSettings()
    overrides: dict[str, Any] = {'segments': {}, 'geo': {}}
    if row.segment_margin_m != default.segment_margin_m or 'margin_m' not in (base.get('segments') or {}):
        overrides['segments']['margin_m'] = row.segment_margin_m   # a file's value stays unless the parameter is set
    if row.row_id != default.row_id or 'row_id' not in (base.get('geo') or {}):
        overrides['geo']['row_id'] = row.row_id
    if row.segment_length_m > 0:
        overrides['segments']['length_m'] = row.segment_length_m
    if row.row_standoff_m > 0:
        overrides['segments']['standoff_m'] = row.row_standoff_m
    if row.tree_spacing_m > 0:
        overrides['trees'] = {'spacing_m': row.tree_spacing_m}
    if row.datum:
        overrides['geo']['datum'] = list(parse_vector(row.datum, 'datum', (3, 4)))
    if row.gnss_antenna_offset:
        overrides['geo']['antenna_in_camera_m'] = list(parse_vector(row.gnss_antenna_offset, 'gnss_antenna_offset',
                                                                    3))
    return replace_nested(config, overrides)


def declare_row_parameters(node: Any) -> RowSettings:
    """Declare every row parameter on an rclpy node (typed, described) and return the settings."""
    from rcl_interfaces.msg import ParameterDescriptor, ParameterType
    types = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
             float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}
    values = {}
    for spec in ROW_PARAMETERS:
        descriptor = ParameterDescriptor(name=spec.name, type=types[type(spec.default)], description=spec.description)
        values[spec.name] = node.declare_parameter(spec.name, spec.default, descriptor).value
    return row_settings_from_parameters(values)


def row_parameter_table() -> str:
    """Markdown table of the row parameters (docs/ros_interface.md)."""
    rows = ['| Parameter | Type | Default | Description |', '|---|---|---|---|']
    rows += [f'| `{s.name}` | {type(s.default).__name__} | `{s.default!r}` | {s.description} |' for s in ROW_PARAMETERS]
    return '\n'.join(rows)
