"""Typed configuration dataclasses from and to YAML.

Each pipeline stage has one frozen dataclass (``SynthConfig``, ``TrainConfig``, ``ExportConfig``,
``ClusterConfig``...). This module turns nested mappings (from YAML or ROS parameters) into those dataclasses,
rejecting unknown keys and wrong types with a :class:`ConfigError` that names the key.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, Mapping, TypeVar

import yaml

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['config_from_mapping', 'config_to_mapping', 'load_config', 'load_yaml_mapping', 'save_config',
           'replace_nested']

T = TypeVar('T')


def _convert(value: Any, annotation: Any, key: str) -> Any:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if dataclasses.is_dataclass(annotation) and isinstance(annotation, type):
        if isinstance(value, annotation):
            return value
        if not isinstance(value, Mapping):
            raise ConfigError(f'{key}: expected a mapping for {annotation.__name__}, got {value!r}')
        return config_from_mapping(annotation, value, prefix=f'{key}.')
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, key)
            except ConfigError as err:
                errors.append(str(err))
        raise ConfigError('; '.join(errors) or f'{key}: invalid value {value!r}')
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f'{key}: {value!r} is not one of {list(args)}')
        return value
    if origin in (tuple,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f'{key}: expected a list, got {value!r}')
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f'{key}[{i}]') for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise ConfigError(f'{key}: expected {len(args)} values, got {len(value)}')
        if not args:
            return tuple(value)
        return tuple(_convert(v, a, f'{key}[{i}]') for i, (a, v) in enumerate(zip(args, value)))
    if origin in (list,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f'{key}: expected a list, got {value!r}')
        return [_convert(v, args[0], f'{key}[{i}]') for i, v in enumerate(value)] if args else list(value)
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f'{key}: expected true/false, got {value!r}')
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f'{key}: expected an integer, got {value!r}')
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f'{key}: expected a number, got {value!r}')
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f'{key}: expected a string, got {value!r}')
        return value
    if annotation is Path:
        return Path(value)
    return value


def config_from_mapping(cls: type[T], mapping: Mapping[str, Any] | None, *, prefix: str = '') -> T:
    """Build the dataclass ``cls`` from a nested mapping; missing keys keep their defaults.

    Raises:
        ConfigError: on an unknown key or a value of the wrong type.
    """
    mapping = dict(mapping or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(mapping) - set(fields))
    if unknown:
        raise ConfigError(f'unknown {cls.__name__} key(s): {", ".join(prefix + u for u in unknown)}; '
                          f'known: {", ".join(sorted(fields))}')
    kwargs = {name: _convert(value, hints[name], prefix + name) for name, value in mapping.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise ConfigError(f'{cls.__name__}: {err}') from err


def config_to_mapping(config: Any) -> dict[str, Any]:
    """Nested plain-Python mapping of a config dataclass (tuples become lists, paths strings)."""
    def plain(value: Any) -> Any:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, Mapping):
            return {k: plain(v) for k, v in value.items()}
        return value
    return plain(config)


def load_yaml_mapping(path: str | Path, *, kind: str = 'config file') -> dict[str, Any]:
    """The top-level mapping of a YAML file (an empty file gives ``{}``).

    Raises:
        ConfigError: the file is missing, not valid YAML, or its top level is not a mapping (``kind`` names the
            file's role in the message, e.g. ``params file``).
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except FileNotFoundError as err:
        raise ConfigError(f'{kind} not found: {path}') from err
    except yaml.YAMLError as err:
        raise ConfigError(f'{path}: not valid YAML: {err}') from err
    if not isinstance(data, Mapping):
        raise ConfigError(f'{path}: expected a mapping at top level, got {type(data).__name__}')
    return dict(data)


#: Top-level keys of a pipeline config file (``fruitnerfpp run --config``, the node's ``config_file``).
PIPELINE_SECTIONS = ('train', 'export', 'clustering')


def is_sectioned(data: Mapping[str, Any]) -> bool:
    """Whether a YAML mapping is a pipeline file (sections) rather than one config's fields."""
    return any(key in data for key in PIPELINE_SECTIONS)


def load_pipeline_sections(path: str | Path, *, kind: str = 'config file') -> dict[str, dict[str, Any]]:
    """The sections ``train`` / ``export`` / ``clustering`` of a pipeline config file, each ``{}`` when absent.

    One rule for every reader (``fruitnerfpp run --config``, the fruit_counter node's ``config_file``): any other
    top-level key is an error, so a misspelt section never passes silently.

    Raises:
        ConfigError: unreadable YAML, an unknown section, or a section that is not a mapping (naming the file).
    """
    return pipeline_sections(load_yaml_mapping(path, kind=kind), path, kind=kind)


def pipeline_sections(data: Mapping[str, Any], path: str | Path, *, kind: str = 'config file',
                      ) -> dict[str, dict[str, Any]]:
    """:func:`load_pipeline_sections` of a mapping already read from ``path`` (named in errors)."""
    unknown = sorted(set(data) - set(PIPELINE_SECTIONS))
    if unknown:
        raise ConfigError(f'{kind} {path}: unknown section(s) {", ".join(map(str, unknown))}; expected only '
                          f"{', '.join(PIPELINE_SECTIONS)} (each optional, each holding that stage's config)")
    sections: dict[str, dict[str, Any]] = {}
    for name in PIPELINE_SECTIONS:
        value = data.get(name) or {}
        if not isinstance(value, Mapping):
            raise ConfigError(f'{kind} {path}: section {name} must be a mapping, got {type(value).__name__}')
        sections[name] = dict(value)
    return sections


def load_config(cls: type[T], path: str | Path) -> T:
    """Load ``cls`` from a YAML file (a mapping of its fields)."""
    path = Path(path)
    data = load_yaml_mapping(path)
    try:
        return config_from_mapping(cls, data)
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from err


def save_config(config: Any, path: str | Path) -> None:
    """Write a config dataclass as YAML (atomically)."""
    atomic_write_text(path, yaml.safe_dump(config_to_mapping(config), sort_keys=False))


def replace_nested(config: T, overrides: Mapping[str, Any]) -> T:
    """Return a copy of ``config`` with nested ``overrides`` applied (validated like a YAML file)."""
    merged = config_to_mapping(config)

    def merge(base: dict[str, Any], extra: Mapping[str, Any]) -> None:
        for key, value in extra.items():
            if isinstance(value, Mapping) and isinstance(base.get(key), dict):
                merge(base[key], value)
            else:
                base[key] = value
    merge(merged, overrides)
    return config_from_mapping(type(config), merged)
