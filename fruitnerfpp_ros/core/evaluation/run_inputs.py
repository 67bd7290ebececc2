"""What a run is scored on: its ``counts.json``, the ground truth beside the dataset it trained on, and the views
it trained on.

``fruitnerfpp eval RUN`` scores a run as :func:`~fruitnerfpp_ros.core.pipeline.run_pipeline` scored it when it
ran: recall leaves out the fruit no *training* view saw (a fruit only the held-out views show cannot be counted),
so the figures of ``RUN/eval.json`` and of a later ``eval`` agree. Given a ``counts.json`` outside a run, or a run
whose dataset is gone, the ground truth's views all count as seen unless a dataset is named.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.pipeline import COUNTS_JSON, GT_JSON, training_views
from fruitnerfpp_ros.errors import EvaluationError

__all__ = ['RunEvalInputs', 'run_eval_inputs', 'run_eval_every']


@dataclass(frozen=True)
class RunEvalInputs:
    """The files and views one evaluation reads.

    Attributes:
        counts_json: the count scored.
        gt_json: the ground truth.
        dataset_dir: the dataset the count came from (its training views decide which fruit were seen), or None.
        train_views: the ground truth's view indices of those training views, or None (every view counts).
    """

    counts_json: Path
    gt_json: Path
    dataset_dir: Path | None
    train_views: np.ndarray | None


def _counts_file(counts: Path) -> Path:
    if counts.is_dir():
        found = counts / COUNTS_JSON
        if not found.is_file():
            raise EvaluationError(f'{counts}: no {COUNTS_JSON} in this directory; count the run first '
                                  f'(`fruitnerfpp count {counts}`)')
        return found
    if not counts.is_file():
        raise EvaluationError(f'{counts}: no such run directory or counts file')
    return counts


def run_eval_every(run_dir: Path, default: int) -> int:
    """The held-out spacing ``data.eval_every`` of the run in ``run_dir`` (its config.yaml), else ``default``."""
    from fruitnerfpp_ros.core.config_io import load_config
    from fruitnerfpp_ros.core.training import RunDir, TrainConfig

    path = RunDir(run_dir).config_path
    return load_config(TrainConfig, path).data.eval_every if path.is_file() else default


def _run_dataset(run_dir: Path) -> Path | None:
    """The dataset the run in ``run_dir`` trained on (its checkpoint names it); None without a readable run."""
    from fruitnerfpp_ros.core.training import RunDir
    from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
    from fruitnerfpp_ros.errors import CheckpointError

    run = RunDir(run_dir)
    if not run.latest_checkpoint.is_file():
        return None
    try:
        return run.find_dataset(load_checkpoint(run.latest_checkpoint))
    except (CheckpointError, KeyError, TypeError):
        return None


def run_eval_inputs(counts: str | Path, gt: str | Path | None = None, dataset: str | Path | None = None,
                    default_eval_every: int = 8) -> RunEvalInputs:
    """Resolve what :func:`~fruitnerfpp_ros.core.pipeline.evaluate_run` reads.

    Args:
        counts: a run directory (its ``counts.json``) or a ``counts.json``.
        gt: ``gt_fruits.json`` or the directory holding it; None: the one beside the run's dataset.
        dataset: the dataset the count came from (overrides the run's); its training views are every view but each
            ``eval_every``-th (the run's ``data.eval_every``, else ``default_eval_every``).

    Raises:
        EvaluationError: no counts file; no ground truth given and none beside the run's dataset.
    """
    counts_json = _counts_file(Path(counts))
    dataset_dir = Path(dataset) if dataset is not None else _run_dataset(counts_json.parent)
    if gt is None:
        if dataset_dir is None:
            raise EvaluationError(f'give --gt ({GT_JSON}): no dataset found for {counts_json} (not in a trained '
                                  'run whose dataset is at hand; --dataset names one)')
        if not (dataset_dir / GT_JSON).is_file():
            raise EvaluationError(f'give --gt: the dataset {dataset_dir} holds no {GT_JSON}')
        gt_json = dataset_dir / GT_JSON
    else:
        gt_json = Path(gt) / GT_JSON if Path(gt).is_dir() else Path(gt)
    train_views = None
    if dataset_dir is not None and (dataset_dir / 'transforms.json').is_file():
        train_views = training_views(dataset_dir, run_eval_every(counts_json.parent, default_eval_every), gt_json)
    return RunEvalInputs(counts_json, gt_json, dataset_dir, train_views)
