"""The training run directory: resolved config, checkpoints and the metrics log."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from fruitnerfpp_ros.core.atomic_io import atomic_write_text

__all__ = ['RunDir']


class RunDir:
    """Paths and logs of one training run::

        RUN_DIR/config.yaml          resolved TrainConfig
        RUN_DIR/checkpoints/latest.pt  last periodic or stage-end checkpoint
        RUN_DIR/metrics.jsonl        one JSON object per logging step / stage-end evaluation
        RUN_DIR/refined_poses.json   with pose refinement: recorded vs refined pose of every view
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @property
    def config_path(self) -> Path:
        return self.root / 'config.yaml'

    @property
    def checkpoint_dir(self) -> Path:
        return self.root / 'checkpoints'

    @property
    def latest_checkpoint(self) -> Path:
        return self.checkpoint_dir / 'latest.pt'

    @property
    def metrics_path(self) -> Path:
        return self.root / 'metrics.jsonl'

    @property
    def refined_poses_path(self) -> Path:
        return self.root / 'refined_poses.json'

    def dataset_record(self, dataset_dir: str | Path) -> dict[str, str]:
        """How a checkpoint names the dataset the run trains on: its absolute path, and its path from the run
        directory (a run moved together with its dataset still finds it)."""
        dataset = Path(dataset_dir).resolve()
        return {'dataset_dir': str(dataset), 'dataset_from_run': os.path.relpath(dataset, self.root.resolve())}

    def find_dataset(self, state: dict[str, Any]) -> Path:
        """The dataset a checkpoint's ``state`` was trained on (:meth:`dataset_record`), wherever the caller runs.

        Tried in turn: the recorded path; the path from the run directory; and for checkpoints written before
        both were recorded (a path relative to the trainer's working directory), that path from the working
        directory, then from each directory above the run (the working directory the run was started from).
        Returns the recorded path when none holds a dataset (reading it then names that path).
        """
        stored = Path(state['dataset_dir'])
        candidates = [stored]
        if state.get('dataset_from_run'):
            candidates.append(Path(os.path.normpath(self.root.absolute() / state['dataset_from_run'])))
        if not stored.is_absolute():
            candidates += [parent / stored for parent in self.root.resolve().parents]
        return next((c for c in candidates if (c / 'transforms.json').is_file()), stored)

    def create(self) -> None:
        self.checkpoint_dir.mkdir(parents=True, exist_ok=True)

    def append_metrics(self, record: dict[str, Any]) -> None:
        """Append one JSON line (non-finite floats written as null)."""
        clean = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in record.items()}
        with open(self.metrics_path, 'a') as f:
            f.write(json.dumps(clean) + '\n')

    def read_metrics(self) -> list[dict[str, Any]]:
        """The logged records; a last line a kill cut short (no newline, not JSON) is left out."""
        if not self.metrics_path.is_file():
            return []
        text = self.metrics_path.read_text()
        lines = text.splitlines()
        if lines and not text.endswith('\n'):
            try:
                json.loads(lines[-1])
            except ValueError:
                lines = lines[:-1]
        return [json.loads(line) for line in lines if line.strip()]

    def truncate_metrics(self, keep_until_global_step: int) -> None:
        """Drop lines logged after ``keep_until_global_step`` (on resume, so no step is logged twice)."""
        lines = [r for r in self.read_metrics() if r.get('global_step', 0) <= keep_until_global_step]
        atomic_write_text(self.metrics_path, ''.join(json.dumps(r) + '\n' for r in lines))
