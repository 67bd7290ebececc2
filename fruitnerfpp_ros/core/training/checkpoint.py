"""Atomic checkpoints: written to a temporary file, then renamed over the previous one."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from fruitnerfpp_ros.core.atomic_io import atomic_path
from fruitnerfpp_ros.errors import CheckpointError

__all__ = ['save_checkpoint', 'load_checkpoint']


def save_checkpoint(state: dict[str, Any], path: str | Path) -> Path:
    """Write ``state`` with torch.save to ``path`` atomically (a crash leaves the previous file intact).

    Raises:
        CheckpointError: the file cannot be written (e.g. the disk is full); the previous checkpoint is kept and
            no temporary file is left.
    """
    path = Path(path)
    try:
        with atomic_path(path) as tmp, open(tmp, 'wb') as f:
            torch.save(state, f)
            f.flush()
            os.fsync(f.fileno())
    except (OSError, RuntimeError) as err:  # torch.save reports a failed write as RuntimeError
        kept = 'the previous checkpoint is kept' if path.is_file() else 'no earlier checkpoint exists'
        reason = err.strerror if isinstance(err, OSError) and err.strerror else str(err).splitlines()[0]
        raise CheckpointError(f'{path}: cannot write checkpoint ({reason}); {kept}') from err
    return path


def load_checkpoint(path: str | Path, device: torch.device | str = 'cpu') -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint`.

    Raises:
        CheckpointError: naming the file when it is missing or unreadable.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f'{path}: checkpoint not found')
    try:
        state = torch.load(path, map_location=device, weights_only=False)
    except Exception as err:  # torch raises many types for corrupt files
        raise CheckpointError(f'{path}: cannot read checkpoint: {err}') from err
    if not isinstance(state, dict) or 'field' not in state:
        raise CheckpointError(f'{path}: not a fruitnerfpp training checkpoint')
    return state
