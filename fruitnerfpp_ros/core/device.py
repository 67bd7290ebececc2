"""Torch device selection: ``auto`` picks CUDA when present, else the CPU."""

from __future__ import annotations

import os

import torch

from fruitnerfpp_ros.core.preset_names import AUTO, AUTO_ON_CPU_NOTE, auto_preset
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['resolve_device', 'device_preset', 'available_cores', 'cpu_thread_count', 'use_cpu_threads']


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


def device_preset(name: str, device: str = 'auto') -> tuple[str, str | None]:
    """(The training preset ``name`` stands for on ``device``, a note for the user or None): a named preset as it
    is; ``auto`` is ``default`` on CUDA and ``cpu`` on the CPU, with ``AUTO_ON_CPU_NOTE``.

    Raises:
        ConfigError: ``auto`` with a device that cannot be used (see :func:`resolve_device`).
    """
    if name != AUTO:
        return name, None
    on_cuda = resolve_device(device).type == 'cuda'
    return auto_preset(on_cuda), (None if on_cuda else AUTO_ON_CPU_NOTE)


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else (os.cpu_count() or 1)


def cpu_thread_count(count: int, share: int = 1) -> int:
    """The torch CPU threads for ``TrainConfig.cpu_threads`` = ``count``.

    ``count`` > 0: that many. 0 (auto): ``OMP_NUM_THREADS`` when it holds a positive count (a parent that runs
    several jobs sets it for each; of a nested list such as ``4,2`` the first), else the cores this process may run
    on divided among the ``share`` jobs its caller runs at once (at least one).

    Raises:
        ConfigError: ``count`` < 0 or ``share`` < 1.
    """
    if count < 0 or share < 1:
        raise ConfigError(f'cpu_threads must be >= 0 and the jobs sharing the cores >= 1 (got {count}, {share})')
    if count > 0:
        return count
    env = os.environ.get('OMP_NUM_THREADS', '').split(',')[0].strip()
    if env.isdigit() and int(env) >= 1:
        return int(env)
    return max(1, available_cores() // share)


def use_cpu_threads(count: int, device: str = 'auto', share: int = 1) -> int:
    """Set torch's CPU thread count to :func:`cpu_thread_count` (``count``, ``share``) when work will run on the
    CPU; returns the count (also on CUDA, where nothing is set).

    For the owners of a process only (CLI commands, nodes, a benchmark's scene process): the library never changes
    process-wide settings; ``TrainConfig.cpu_threads`` is the value they pass.
    """
    threads = cpu_thread_count(count, share)
    if resolve_device(device).type == 'cpu':
        torch.set_num_threads(threads)
    return threads
