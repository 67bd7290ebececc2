"""The training run directory: resolved config, checkpoints and the metrics log."""

from __future__ import annotations

import json
import math
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
