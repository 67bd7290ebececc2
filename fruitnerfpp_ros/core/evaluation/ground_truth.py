"""Ground-truth fruits (``gt_fruits.json``) and predicted counts (``counts.json``) for evaluation.

``gt_fruits.json``: ``{"fruits": [{"id", "type", "center": [x, y, z], "radius": r | "radii": [a, b, c] (optional
"diameter"), "n_views_visible"}, ...]}`` in metres, world frame of the dataset.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fruitnerfpp_ros.errors import EvaluationError

__all__ = ['GroundTruth', 'load_ground_truth', 'parse_ground_truth', 'load_predicted_centers']


class GroundTruth(NamedTuple):
    """Ground-truth fruits.

    Attributes:
        ids: [G] fruit ids.
        centers: [G, 3] centres (m).
        diameters: [G] diameters (m): ``diameter`` when given, else twice the radius, or twice the largest
            semi-axis.
        n_views_visible: [G] number of training views seeing the fruit (-1 when unknown).
        types: [G] fruit type names.
    """

    ids: np.ndarray
    centers: np.ndarray
    diameters: np.ndarray
    n_views_visible: np.ndarray
    types: list[str]

    @property
    def seen(self) -> np.ndarray:
        """[G] bool: seen by at least one view (unknown counts as seen)."""
        return self.n_views_visible != 0

    def __len__(self) -> int:
        return len(self.ids)


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as err:
        raise EvaluationError(f'{path}: {what} file not found') from err
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise EvaluationError(f'{path}: not valid JSON: {err}') from err


def parse_ground_truth(data: Any, source: str = 'gt_fruits.json') -> GroundTruth:
    """Validate and convert a parsed ``gt_fruits.json`` mapping.

    Raises:
        EvaluationError: naming ``source`` and the offending key / fruit.
    """
    if not isinstance(data, dict) or not isinstance(data.get('fruits'), list):
        raise EvaluationError(f'{source}: expected an object with a "fruits" list')
    ids, centers, diameters, views, types = [], [], [], [], []
    for i, fruit in enumerate(data['fruits']):
        where = f'{source}: fruits[{i}]'
        if not isinstance(fruit, dict):
            raise EvaluationError(f'{where}: expected an object')
        center = fruit.get('center')
        if not isinstance(center, (list, tuple)) or len(center) != 3:
            raise EvaluationError(f'{where}: "center" must be [x, y, z]')
        try:
            center = [float(v) for v in center]
            if 'diameter' in fruit:
                diameter = float(fruit['diameter'])
            elif 'radius' in fruit:
                diameter = 2.0 * float(fruit['radius'])
            elif 'radii' in fruit and len(fruit['radii']) == 3:
                diameter = 2.0 * max(float(v) for v in fruit['radii'])
            else:
                raise EvaluationError(f'{where}: needs "radius" or "radii": [a, b, c]')
            n_views = int(fruit.get('n_views_visible', -1))
        except (TypeError, ValueError) as err:
            raise EvaluationError(f'{where}: non-numeric value: {err}') from err
        if not np.all(np.isfinite(center)) or not np.isfinite(diameter) or diameter <= 0:
            raise EvaluationError(f'{where}: centre must be finite and radius positive')
        ids.append(int(fruit.get('id', i)))
        centers.append(center)
        diameters.append(diameter)
        views.append(n_views)
        types.append(str(fruit.get('type', 'fruit')))
    return GroundTruth(np.asarray(ids, np.int64), np.asarray(centers, np.float64).reshape(-1, 3),
                       np.asarray(diameters, np.float64), np.asarray(views, np.int64), types)


def load_ground_truth(path: str | Path) -> GroundTruth:
    """Read ``gt_fruits.json``.

    Raises:
        EvaluationError: missing or malformed file.
    """
    path = Path(path)
    return parse_ground_truth(_read_json(path, 'ground truth'), str(path))


def load_predicted_centers(path: str | Path) -> np.ndarray:
    """[P, 3] fruit centres (m) from a ``counts.json``.

    Raises:
        EvaluationError: missing file, no "fruits" list, or a fruit without a 3-number "center"; or a "total"
            disagreeing with the number of fruits.
    """
    path = Path(path)
    data = _read_json(path, 'counts')
    if not isinstance(data, dict) or not isinstance(data.get('fruits'), list):
        raise EvaluationError(f'{path}: expected a counts.json object with a "fruits" list')
    centers = []
    for i, fruit in enumerate(data['fruits']):
        center = fruit.get('center') if isinstance(fruit, dict) else None
        if not isinstance(center, (list, tuple)) or len(center) != 3:
            raise EvaluationError(f'{path}: fruits[{i}] has no "center": [x, y, z]')
        centers.append([float(v) for v in center])
    if 'total' in data and int(data['total']) != len(centers):
        raise EvaluationError(f'{path}: "total" {data["total"]} disagrees with {len(centers)} listed fruits')
    return np.asarray(centers, np.float64).reshape(-1, 3)
