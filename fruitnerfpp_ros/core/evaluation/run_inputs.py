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

from fruitnerfpp_ros.errors import EvaluationError

__all__ = ['RunEvalInputs', 'run_eval_inputs', 'GT_FILE', 'COUNTS_FILE']

#: The ground truth's file name in a synthetic dataset, and a run's count.
GT_FILE, COUNTS_FILE = 'gt_fruits.json', 'counts.json'


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
        found = counts / COUNTS_FILE
        if not found.is_file():
            raise EvaluationError(f'{counts}: no {COUNTS_FILE} in this directory; count the run first '
                                  f'(`fruitnerfpp count {counts}`)')
        return found
    if not counts.is_file():
        raise EvaluationError(f'{counts}: no such run directory or counts file')
    return counts


def _run_dataset(run_dir: Path) -> tuple[Path | None, int | None]:
    """(the dataset the run in ``run_dir`` trained on, its held-out spacing ``data.eval_every``); (None, None)
    when ``run_dir`` holds no readable training run."""
    from fruitnerfpp_ros.core.training import RunDir
    from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
    from fruitnerfpp_ros.errors import CheckpointError

    run = RunDir(run_dir)
    if not run.latest_checkpoint.is_file():
        return None, None
    try:
        state = load_checkpoint(run.latest_checkpoint)
        return run.find_dataset(state), int(state['config']['data']['eval_every'])
    except (CheckpointError, KeyError, TypeError, ValueError):
        return None, None


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
    run_dataset, eval_every = _run_dataset(counts_json.parent)
    dataset_dir = Path(dataset) if dataset is not None else run_dataset
    if gt is None:
        if dataset_dir is None:
            raise EvaluationError(f'give --gt ({GT_FILE}): no dataset found for {counts_json} (not in a trained '
                                  'run whose dataset is at hand; --dataset names one)')
        if not (dataset_dir / GT_FILE).is_file():
            raise EvaluationError(f'give --gt: the dataset {dataset_dir} holds no {GT_FILE}')
        gt_json = dataset_dir / GT_FILE
    else:
        gt_json = Path(gt) / GT_FILE if Path(gt).is_dir() else Path(gt)
    train_views = None
    if dataset_dir is not None and (dataset_dir / 'transforms.json').is_file():
        from fruitnerfpp_ros.core.pipeline import training_views  # torch: imported only when a dataset is scored

        train_views = training_views(dataset_dir, eval_every or default_eval_every, gt_json)
    return RunEvalInputs(counts_json, gt_json, dataset_dir, train_views)
