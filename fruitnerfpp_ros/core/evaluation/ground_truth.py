"""Ground-truth fruits (``gt_fruits.json``) and predicted counts (``counts.json``) for evaluation.

``gt_fruits.json``: ``{"fruits": [{"id", "type", "center": [x, y, z], "radius": r | "radii": [a, b, c] (optional
"diameter"), "views_visible": [view indices], "n_views_visible"}, ...], "view_stamps_ns": [...]}`` in metres, world
frame of the dataset. ``views_visible`` (optional) lists every view showing at least one pixel of the fruit -
training and held-out views alike, since the generator knows no split; ``n_views_visible`` (optional) counts them.
``view_stamps_ns`` (optional) is the stamp of each view (its index in the list), as the synthetic bag and
transforms.json carry it, to find the views of keyframes collected from a bag.

Which fruits count as seen is a question about the *training* views: pass them as ``train_views`` (e.g. the
train indices of ``core.data.dataset.split_indices``) and ``GroundTruth.seen`` marks the fruits at least one
training view shows; a fruit seen only by held-out views is then unseen.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, NamedTuple

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
        n_views_visible: [G] number of views seeing the fruit (-1 when unknown): all views of the file, or only
            the training views after :meth:`restricted_to_views` (``load_ground_truth(..., train_views=...)``).
        types: [G] fruit type names.
        views_visible: per fruit, the int64 view indices seeing it (sorted), or None when the file does not list
            them.
        view_stamps_ns: [V] int64 stamp of each view, or None when the file does not give them.
    """

    ids: np.ndarray
    centers: np.ndarray
    diameters: np.ndarray
    n_views_visible: np.ndarray
    types: list[str]
    views_visible: tuple[np.ndarray, ...] | None = None
    view_stamps_ns: np.ndarray | None = None

    @property
    def seen(self) -> np.ndarray:
        """[G] bool: seen by at least one view counted in ``n_views_visible`` (unknown counts as seen)."""
        return self.n_views_visible != 0

    def __len__(self) -> int:
        return len(self.ids)

    def seen_by(self, views: Iterable[int]) -> np.ndarray:
        """[G] bool: the fruit is visible in at least one of ``views`` (view indices). Without ``views_visible``
        in the file, a fruit no view sees is unseen and any other counts as seen (unknown)."""
        return self.restricted_to_views(views).seen

    def restricted_to_views(self, views: Iterable[int]) -> 'GroundTruth':
        """This ground truth with visibility counted over ``views`` only (e.g. the training views):
        ``n_views_visible`` counts the listed views seeing each fruit, ``views_visible`` keeps only them. Without
        ``views_visible`` in the file, ``n_views_visible`` stays 0 where no view sees the fruit and becomes -1
        (unknown, counted as seen) elsewhere."""
        keep = np.unique(np.asarray(list(views), dtype=np.int64))
        # (NamedTuple._replace cannot be used: __len__ counts fruits, not fields.)
        if self.views_visible is None:
            n = np.where(self.n_views_visible == 0, 0, -1).astype(np.int64)
            return GroundTruth(self.ids, self.centers, self.diameters, n, self.types, None, self.view_stamps_ns)
        kept = tuple(v[np.isin(v, keep)] for v in self.views_visible)
        return GroundTruth(self.ids, self.centers, self.diameters, np.array([len(v) for v in kept], np.int64),
                           self.types, kept, self.view_stamps_ns)

    def views_at_stamps(self, stamps_ns: Iterable[int]) -> np.ndarray:
        """View indices (sorted) whose stamp is one of ``stamps_ns`` (e.g. the keyframes trained on, collected from
        the synthetic bag).

        Raises:
            EvaluationError: the file gives no ``view_stamps_ns``.
        """
        if self.view_stamps_ns is None:
            raise EvaluationError('the ground truth gives no view_stamps_ns: cannot map stamps to views')
        return np.flatnonzero(np.isin(self.view_stamps_ns, np.asarray(list(stamps_ns), dtype=np.int64)))


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as err:
        raise EvaluationError(f'{path}: {what} file not found') from err
    except IsADirectoryError as err:
        raise EvaluationError(f'{path}: a directory, not the {what} file') from err
    except OSError as err:
        raise EvaluationError(f'{path}: cannot read the {what} file ({err.strerror or err})') from err
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise EvaluationError(f'{path}: not valid JSON: {err}') from err


def _view_list(value: Any, where: str, key: str) -> np.ndarray:
    if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
        raise EvaluationError(f'{where}: "{key}" must be a list of integers')
    return np.asarray(value, dtype=np.int64)


def _views_of(fruit: dict[str, Any], where: str) -> tuple[np.ndarray | None, int]:
    """(sorted view indices or None, n_views_visible or -1) of one fruit record."""
    try:
        n_views = int(fruit.get('n_views_visible', -1))
    except (TypeError, ValueError) as err:
        raise EvaluationError(f'{where}: non-numeric value: {err}') from err
    if 'views_visible' not in fruit:
        return None, n_views
    views = _view_list(fruit['views_visible'], where, 'views_visible')
    if np.any(views < 0) or np.any(np.diff(views) <= 0):
        raise EvaluationError(f'{where}: "views_visible" must list distinct view indices >= 0 in increasing order')
    if n_views != -1 and n_views != len(views):
        raise EvaluationError(f'{where}: "n_views_visible" {n_views} disagrees with {len(views)} "views_visible"')
    return views, len(views)


def parse_ground_truth(data: Any, source: str = 'gt_fruits.json', *,
                       train_views: Iterable[int] | None = None) -> GroundTruth:
    """Validate and convert a parsed ``gt_fruits.json`` mapping.

    Args:
        data: the parsed file.
        source: name used in error messages.
        train_views: when given, visibility counts these view indices only (:meth:`GroundTruth.restricted_to_views`).

    Raises:
        EvaluationError: naming ``source`` and the offending key / fruit.
    """
    if not isinstance(data, dict) or not isinstance(data.get('fruits'), list):
        raise EvaluationError(f'{source}: expected an object with a "fruits" list')
    ids, centers, diameters, counts, lists, types = [], [], [], [], [], []
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
        except (TypeError, ValueError) as err:
            raise EvaluationError(f'{where}: non-numeric value: {err}') from err
        if not np.all(np.isfinite(center)) or not np.isfinite(diameter) or diameter <= 0:
            raise EvaluationError(f'{where}: centre must be finite and radius positive')
        views, n_views = _views_of(fruit, where)
        ids.append(int(fruit.get('id', i)))
        centers.append(center)
        diameters.append(diameter)
        counts.append(n_views)
        lists.append(views)
        types.append(str(fruit.get('type', 'fruit')))
    has_lists = bool(lists) and all(v is not None for v in lists)
    if any(v is not None for v in lists) and not has_lists:
        raise EvaluationError(f'{source}: "views_visible" must be given for every fruit or for none')
    stamps = data.get('view_stamps_ns')
    gt = GroundTruth(np.asarray(ids, np.int64), np.asarray(centers, np.float64).reshape(-1, 3),
                     np.asarray(diameters, np.float64), np.asarray(counts, np.int64), types,
                     tuple(lists) if has_lists else None,
                     None if stamps is None else _view_list(stamps, source, 'view_stamps_ns'))
    return gt if train_views is None else gt.restricted_to_views(train_views)


def load_ground_truth(path: str | Path, *, train_views: Iterable[int] | None = None) -> GroundTruth:
    """Read ``gt_fruits.json``.

    Args:
        path: the file.
        train_views: the view indices the model was trained on; when given, ``seen`` / ``n_views_visible`` count
            only these views, so recall can exclude fruits no training view saw (held-out views do not count).

    Raises:
        EvaluationError: missing or malformed file.
    """
    path = Path(path)
    return parse_ground_truth(_read_json(path, 'ground truth'), str(path), train_views=train_views)


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
