"""Torch device selection: ``auto`` picks CUDA when present, else the CPU."""

from __future__ import annotations

import torch

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['resolve_device', 'use_cpu_threads']


def resolve_device(name: str = 'auto') -> torch.device:
    """Return the torch device for ``name`` (``auto``, ``cpu``, ``cuda`` or ``cuda:N``).

    Raises:
        ConfigError: when CUDA is asked for but not available, or the name is unknown.
    """
    if name == 'auto':
        return torch.device('cuda' if torch.cuda.is_available() else 'cpu')
    if name.startswith('cuda'):
        if not torch.cuda.is_available():
            raise ConfigError(f'device {name!r} requested but CUDA is not available on this machine; use --device cpu')
        return torch.device(name)
    if name == 'cpu':
        return torch.device('cpu')
    raise ConfigError(f'unknown device {name!r}; expected auto, cpu, cuda or cuda:N')


def use_cpu_threads(count: int, device: str = 'auto') -> None:
    """Set torch's CPU thread count to ``count`` when work will run on the CPU (``count`` 0: leave it).

    For the owners of a process only (CLI commands, nodes): the library never changes process-wide settings;
    ``TrainConfig.cpu_threads`` is the value they pass.
    """
    if count > 0 and resolve_device(device).type == 'cpu':
        torch.set_num_threads(count)
