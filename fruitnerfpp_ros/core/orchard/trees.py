"""Trees of a row: from a planting map or found from the fruit; each fruit goes to the nearest crown.

Planting maps (:func:`read_planting_map`):

- CSV with a header: ``tree_id`` (or ``id``) and either ``x, y`` (world frame, m) or ``latitude, longitude`` (or
  ``lat, lon``; WGS84 degrees);
- GeoJSON (RFC 7946): a FeatureCollection of Point features ``[longitude, latitude]``, the id in
  ``properties.tree_id`` (or ``id``) or the feature's ``id``.

Latitude / longitude need the world <-> WGS84 relation (:mod:`.georef`).

Found from the data (:func:`find_trees`): a tree's fruit hang on its crown, a shell round the trunk's axis; along
a row whose canopies touch or overlap the fruit density has no gaps, but the crowns' shape does: the fruits'
distance from the crown centre. For K = 1, 2, ... trees, K spheres (centre, radius) are fitted to the fruit by
alternating assignment (each fruit to the sphere whose shell it lies closest to) and a linear least-squares sphere
fit; K is chosen by BIC (a known spacing restricts K to the row length / spacing +- 1). A trunk is the xy of its
sphere's centre.

Which tree a fruit hangs on (:func:`assign_to_trees`): where canopies overlap, the midpoint between two trunks is
not where one crown ends, a large crown reaches past it into a small neighbour's half. Each fruit goes to the crown
shell it lies closest to: per tree a sphere fitted to the fruit, started from the nearest trunk and refitted until
the assignment holds (``TreeConfig.assign: trunk`` keeps the nearest trunk; ``docs/results/orchard_rows.md``
compares the two).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.orchard.config import TreeConfig
from fruitnerfpp_ros.core.orchard.georef import WorldGeoref
from fruitnerfpp_ros.core.orchard.row_frame import RowFrame
from fruitnerfpp_ros.errors import OrchardError

__all__ = ['TreeMap', 'TreeCount', 'read_planting_map', 'find_trees', 'assign_to_trees', 'count_trees']


class TreeMap(NamedTuple):
    """Trees of a row.

    Attributes:
        ids: [T] tree ids.
        positions: [T, 3] trunk positions in the world frame, metres (z: the crown centre's height when found
            from the data, 0 from a planting map).
        source: ``planting_map`` or ``data``.
    """

    ids: np.ndarray
    positions: np.ndarray
    source: str

    def __len__(self) -> int:
        return len(self.ids)


class TreeCount(NamedTuple):
    """One tree's count.

    Attributes:
        id: tree id; position: [3] world (m); along_m: position along the row (m); count: fruits;
        diameter_mean_m / diameter_std_m: of its fruits whose diameter was measured (0 without any); complete: its
        whole crown lies in counted segments (live counts: a tree at the frontier is still being driven past).
    """

    id: int
    position: np.ndarray
    along_m: float
    count: int
    diameter_mean_m: float
    diameter_std_m: float
    complete: bool = True


def _column(header: list[str], *names: str) -> int | None:
    lowered = [h.strip().lower() for h in header]
    for name in names:
        if name in lowered:
            return lowered.index(name)
    return None


def _read_csv(path: Path) -> tuple[list[str], np.ndarray, bool]:
    with path.open(newline='') as handle:
        rows = [r for r in csv.reader(handle) if r and any(c.strip() for c in r)]
    if len(rows) < 2:
        raise OrchardError(f'{path}: a planting map needs a header and at least one tree')
    header, body = rows[0], rows[1:]
    id_col = _column(header, 'tree_id', 'id')
    xy = (_column(header, 'x'), _column(header, 'y'))
    ll = (_column(header, 'latitude', 'lat'), _column(header, 'longitude', 'lon', 'lng'))
    cols, geodetic = (xy, False) if None not in xy else (ll, True)
    if id_col is None or None in cols:
        raise OrchardError(f'{path}: expected columns tree_id and x, y (world) or latitude, longitude; got {header}')
    try:
        ids = [r[id_col].strip() for r in body]
        values = np.array([[float(r[cols[0]]), float(r[cols[1]])] for r in body])
    except (ValueError, IndexError) as err:
        raise OrchardError(f'{path}: unreadable row ({err})') from err
    return ids, values, geodetic


def _read_geojson(path: Path) -> tuple[list[str], np.ndarray]:
    try:
        data = json.loads(path.read_text())
        features = data['features'] if data.get('type') == 'FeatureCollection' else [data]
        ids, lonlat = [], []
        for i, feature in enumerate(features):
            geometry = feature.get('geometry') or {}
            if geometry.get('type') != 'Point':
                continue
            props = feature.get('properties') or {}
            ids.append(str(props.get('tree_id', props.get('id', feature.get('id', i + 1)))))
            lonlat.append([float(geometry['coordinates'][0]), float(geometry['coordinates'][1])])
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as err:
        raise OrchardError(f'{path}: not a GeoJSON FeatureCollection of points ({type(err).__name__}: {err})') \
            from err
    if not ids:
        raise OrchardError(f'{path}: no Point feature')
    return ids, np.array(lonlat)[:, ::-1]


def _numeric_ids(ids: list[str], path: Path) -> np.ndarray:
    try:
        out = np.array([int(float(i)) for i in ids], np.int64)
    except ValueError as err:
        raise OrchardError(f'{path}: tree ids must be integers ({err})') from err
    if len(set(out.tolist())) != len(out):
        raise OrchardError(f'{path}: tree ids repeat')
    return out


def read_planting_map(path: str | Path, georef: WorldGeoref | None = None) -> TreeMap:
    """Trunk positions of a planting map (CSV or GeoJSON, see the module docstring) in the world frame.

    Raises:
        OrchardError: unreadable file, missing columns, or WGS84 positions without ``georef``.
    """
    path = Path(path)
    if not path.is_file():
        raise OrchardError(f'{path}: no such planting map')
    if path.suffix.lower() in ('.geojson', '.json'):
        ids, values = _read_geojson(path)
        geodetic = True
    else:
        ids, values, geodetic = _read_csv(path)
    if geodetic:
        if georef is None:
            raise OrchardError(f'{path}: latitude / longitude trunks need the world <-> WGS84 relation: give a datum '
                               'or record GNSS fixes')
        positions = georef.world_of(np.c_[values, np.full(len(values), georef.world_origin.altitude_m)])
        positions[:, 2] = 0.0
    else:
        positions = np.c_[values, np.zeros(len(values))]
    return TreeMap(_numeric_ids(ids, path), positions, 'planting_map')


def _sphere_fit(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares sphere (centre [3], radius) through points [N >= 4, 3] (algebraic fit)."""
    A = np.c_[2.0 * p, np.ones(len(p))]
    sol, *_ = np.linalg.lstsq(A, (p ** 2).sum(axis=1), rcond=None)
    centre = sol[:3]
    return centre, float(np.sqrt(max(sol[3] + centre @ centre, 1e-6)))


def _fit_k(p: np.ndarray, s: np.ndarray, k: int, config: TreeConfig
           ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """K spheres fitted to points p [N, 3] (row coordinates s, l, z); returns (centres, labels, RSS, median
    radius).

    Radii stay within 0.8..1.25 x their median (trees of one row differ in size, not by factors: a sphere through
    a few fruits of one crown is no tree), centres between the fruits they hold.
    """
    best = None
    for edges in (np.quantile(s, np.linspace(0.0, 1.0, k + 1)), np.linspace(s.min(), s.max(), k + 1)):
        labels = np.clip(np.searchsorted(edges, s, side='right') - 1, 0, k - 1)
        fit = _fit_from(p, labels, k, config)
        if best is None or fit[2] < best[2]:
            best = fit
    assert best is not None
    return best


def _crown_spheres(p: np.ndarray, labels: np.ndarray, k: int, min_fruits: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float | None]:
    """One crown per label with at least ``min_fruits`` points: (centres [k, 3], radii [k], fitted [k], median).

    A fitted crown is a least-squares sphere through its points, its centre kept within their bounds and its radius
    within 0.8..1.25 x the median radius (trees of one row differ in size, not by factors: a sphere through a few
    fruits of one crown is no tree); the rows of unfitted labels are zero, ``median`` None when none is fitted.
    """
    fitted = np.bincount(labels, minlength=k) >= min_fruits
    centres, radii = np.zeros((k, 3)), np.zeros(k)
    for j in np.flatnonzero(fitted):
        members = p[labels == j]
        centres[j], radii[j] = _sphere_fit(members)
        centres[j] = np.clip(centres[j], members.min(axis=0), members.max(axis=0))
    if not fitted.any():
        return centres, radii, fitted, None
    median = float(np.median(radii[fitted]))
    radii[fitted] = np.clip(radii[fitted], 0.8 * median, 1.25 * median)
    return centres, radii, fitted, median


def _fit_from(p: np.ndarray, labels: np.ndarray, k: int, config: TreeConfig
              ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """:func:`_fit_k` from one initial assignment."""
    s = p[:, 0]
    centres = np.zeros((k, 3))
    residual = np.zeros((len(p), k))
    radii = np.zeros(k)
    for _ in range(config.iterations):
        fit_c, radii, fitted, median = _crown_spheres(p, labels, k, 6)
        centres[fitted] = fit_c[fitted]  # an empty label keeps its last centre
        for j in np.flatnonzero(~fitted & (np.bincount(labels, minlength=k) > 0)):
            centres[j] = np.median(p[labels == j], axis=0)
        median = median if median is not None else float(np.ptp(s)) / (2 * k) + 1e-3
        radii = np.where(fitted, radii, median)
        residual = np.abs(np.linalg.norm(p[:, None, :] - centres[None], axis=2) - radii[None])
        new = np.argmin(residual, axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
    rss = float((residual[np.arange(len(p)), labels] ** 2).sum())
    return centres, labels, rss, float(np.median(radii))


def find_trees(centers: np.ndarray, frame: RowFrame, config: TreeConfig = TreeConfig()) -> TreeMap:
    """Trunks found from fruit centres [N, 3] (world): sphere fits, the number of trees by BIC.

    Raises:
        OrchardError: fewer fruits than ``min_fruits_per_tree``.
    """
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    if len(centers) < config.min_fruits_per_tree:
        raise OrchardError(f'{len(centers)} fruit(s): too few to find trees (give a planting map)')
    s, lat = frame.along(centers), frame.across(centers)
    p = np.c_[s, lat, centers[:, 2]]
    extent = float(np.ptp(s))
    k_max = max(1, min(int(extent / config.min_spacing_m) + 1, len(p) // config.min_fruits_per_tree))
    candidates = range(1, k_max + 1)
    if config.spacing_m is not None:
        k0 = max(1, int(round(extent / config.spacing_m)))  # the crowns reach about half a spacing beyond
        candidates = range(max(1, k0 - 1), min(k_max, k0 + 1) + 1)
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    n = len(p)
    for k in candidates:
        centres, labels, rss, radius = _fit_k(p, s, k, config)
        sizes = np.bincount(labels, minlength=k)
        gaps = np.diff(np.sort(centres[:, 0]))
        if k > 1 and (sizes.min() < config.min_fruits_per_tree or gaps.min() < max(config.min_spacing_m, radius)):
            continue  # an empty tree, or two crowns overlapping by more than half: one tree split in two
        bic = n * np.log(max(rss, 1e-9) / n) + 4 * k * np.log(n)
        if best is None or bic < best[0]:
            best = (bic, centres, labels)
    assert best is not None
    centres = best[1][np.argsort(best[1][:, 0])]
    xy = frame.world_xy(centres[:, 0], centres[:, 1])
    return TreeMap(np.arange(1, len(centres) + 1), np.c_[xy, centres[:, 2]], 'data')


def _nearest_trunks(centers: np.ndarray, positions: np.ndarray, k: int) -> np.ndarray:
    """[N, k] indices of the ``k`` trunks nearest to each fruit (horizontal distance), nearest first."""
    k = min(k, len(positions))
    _, index = cKDTree(positions[:, :2]).query(centers[:, :2], k=k)
    return np.asarray(index, np.int64).reshape(len(centers), k)


def _crown_shells(centers: np.ndarray, positions: np.ndarray, config: TreeConfig) -> np.ndarray:
    """[N] tree index of each fruit: the crown shell it lies closest to, crowns refitted from the fruit.

    Starts from the nearest trunk; each tree with ``crown_min_fruits`` or more gets a crown fitted to its fruit
    (:func:`_crown_spheres`); one with fewer a sphere of the median radius on its trunk's vertical at its fruits'
    median height; then every fruit goes to the nearest shell of the three trees whose trunks are nearest to it,
    until the assignment holds.
    """
    candidates = _nearest_trunks(centers, positions, 3)                       # [N, C]
    labels = candidates[:, 0]
    k = len(positions)
    for _ in range(config.iterations):
        centres, radii, fitted, median = _crown_spheres(centers, labels, k, config.crown_min_fruits)
        if median is None:
            return labels
        radii[~fitted] = median
        height = float(np.median(centres[fitted, 2]))
        sizes = np.bincount(labels, minlength=k)
        for j in np.flatnonzero(~fitted):
            z = np.median(centers[labels == j, 2]) if sizes[j] else height
            centres[j] = [positions[j, 0], positions[j, 1], z]
        residual = np.abs(np.linalg.norm(centers[:, None, :] - centres[candidates], axis=2) - radii[candidates])
        new = candidates[np.arange(len(centers)), np.argmin(residual, axis=1)]
        if np.array_equal(new, labels):
            break
        labels = new
    return labels


def assign_to_trees(centers: np.ndarray, trees: TreeMap, config: TreeConfig = TreeConfig()) -> np.ndarray:
    """[N] index into ``trees`` of each fruit centre [N, 3]: the nearest crown shell or trunk (``config.assign``)."""
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    if len(trees) == 0 or len(centers) == 0:
        return np.zeros(len(centers), np.int64)
    if config.assign == 'trunk' or len(trees) == 1:
        return _nearest_trunks(centers, trees.positions, 1)[:, 0]
    return _crown_shells(centers, trees.positions, config)


def count_trees(trees: TreeMap, frame: RowFrame, fruit_centers: np.ndarray, fruit_diameters: np.ndarray,
                counted: tuple[float, float] | list[tuple[float, float]] | None = None,
                config: TreeConfig = TreeConfig(), measured: np.ndarray | None = None,
                ) -> tuple[list[TreeCount], np.ndarray]:
    """Per-tree counts and each fruit's tree index.

    Args:
        counted: the stretch(es) of the row already counted (live: the finished segments); a tree is complete
            when its crown (trunk +- half the distance to its neighbours) plus ``complete_margin_m`` lies inside.
        measured: [K] bool, the fruits whose diameter was measured (from their cloud points; the fruits the masks
            added carry the scene's diameter): only these enter the diameter mean and spread. None: all.
    """
    index = assign_to_trees(fruit_centers, trees, config)
    along = frame.along(trees.positions) if len(trees) else np.zeros(0)
    order = np.argsort(along)
    gaps = np.diff(along[order]) if len(trees) > 1 else np.zeros(0)
    half = np.full(len(trees), 0.5 * (float(np.median(gaps)) if len(gaps) else 1.0))
    if len(gaps):
        half[order[:-1]] = np.minimum(half[order[:-1]], 0.5 * gaps)
        half[order[1:]] = np.minimum(half[order[1:]], 0.5 * gaps)
    spans = [counted] if isinstance(counted, tuple) else counted
    result = []
    sized = np.ones(len(index), bool) if measured is None else np.asarray(measured, bool)
    for t in range(len(trees)):
        d = np.asarray(fruit_diameters)[(index == t) & sized]
        lo, hi = along[t] - half[t] - config.complete_margin_m, along[t] + half[t] + config.complete_margin_m
        complete = spans is None or any(a <= lo and hi <= b for a, b in spans)
        result.append(TreeCount(int(trees.ids[t]), trees.positions[t], float(along[t]), int(np.sum(index == t)),
                                float(d.mean()) if len(d) else 0.0, float(d.std()) if len(d) else 0.0, complete))
    return result, index
