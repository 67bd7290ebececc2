"""A synthetic orchard row: N trees of varied size and fruit load along the x axis, canopies touching or
overlapping, driven on both sides (``fruitnerfpp synth --scene row --trees N [--tree-spacing M] [--gnss]``).

Each tree is a :func:`~fruitnerfpp_ros.core.synthetic.scene.build_scene` tree of its own seed and fruit count,
moved to its trunk position; their primitives are joined into one scene (fruit ids numbered through the row, a fruit
of a later tree that would pass through a fruit of an earlier one where the canopies overlap is left out). The
row is centred on the world origin, so the ``row`` trajectory of :mod:`.cameras` (``row_standoff_m``,
``camera_height_m``, ``camera_pitch_deg``) drives the whole row, out on y < 0 and back on y > 0.

Files beside the usual dataset (:mod:`.generator`):

    gt_fruits.json          each fruit also carries ``tree_id`` (the tree it grows on)
    gt_trees.json           {"trees": [{"id", "trunk": [x, y, 0], "crown_center", "crown_radius", "n_fruits",
                            "latitude", "longitude"}], "datum", "spacing_m", ...}
    planting_map.csv        the nominal planting grid (tree_id, x, y in the world frame; the trees stand within
                            ``planting_jitter_m`` of it), as a farm's planting plan gives it
    planting_map.geojson    the same grid as WGS84 points (RFC 7946)
    gnss.json               (``gnss``) the fixes also written to the bag as sensor_msgs/NavSatFix on /gnss/fix

transforms.json records ``datum`` (latitude, longitude, altitude of the world origin and the heading ``yaw_deg`` of
the world x axis, counter-clockwise from east) and ``scene: row``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.config_io import config_to_mapping
from fruitnerfpp_ros.core.orchard.geodesy import Datum, geodetic_from_enu
from fruitnerfpp_ros.core.orchard.georef import georef_from_datum
from fruitnerfpp_ros.core.orchard.gnss import GNSS_JSON, GnssFix, antenna_positions, write_gnss_json
from fruitnerfpp_ros.core.orchard.report import planting_map_geojson
from fruitnerfpp_ros.core.synthetic.bag_writer import BAG_START_NS, FRAME_PERIOD_NS
from fruitnerfpp_ros.core.synthetic.cameras import _CROWN_REACH, make_poses  # the crown's outer leaves' reach
from fruitnerfpp_ros.core.synthetic.config import SynthConfig
from fruitnerfpp_ros.core.synthetic.primitives import Cylinders, Ellipsoids, GtFruit, Leaves, Scene
from fruitnerfpp_ros.core.synthetic.scene import build_scene, fruit_type_counts
from fruitnerfpp_ros.errors import SynthError

__all__ = ['RowSceneConfig', 'RowScene', 'build_row_scene', 'row_gnss_fixes', 'generate_row', 'GT_TREES_NAME',
           'PLANTING_CSV_NAME', 'PLANTING_GEOJSON_NAME']

GT_TREES_NAME = 'gt_trees.json'
PLANTING_CSV_NAME = 'planting_map.csv'
PLANTING_GEOJSON_NAME = 'planting_map.geojson'
_FRUIT_GAP_M = 0.004


@dataclass(frozen=True)
class RowSceneConfig:
    """The row's own settings (the trees' fruit, the camera and the drive come from :class:`SynthConfig`, whose
    ``count`` is the mean number of fruits per tree)."""

    trees: int = 5
    """Number of trees in the row."""
    tree_spacing_m: float | None = None
    """Distance between neighbouring trunks along the row (m); None = canopies of the average tree overlap by
    ``crown_overlap``."""
    crown_overlap: float = 0.1
    """Automatic spacing: neighbouring canopies of average size overlap by this fraction of their width."""
    load_variation: float = 0.35
    """Each tree's fruit count is the mean count times a uniform factor in 1 +- this (tree size follows)."""
    planting_jitter_m: float = 0.04
    """Standard deviation (m) of each trunk's offset from the nominal planting grid, along and across the row."""
    gnss: bool = False
    """Also record GNSS fixes of an antenna on the robot (bag: sensor_msgs/NavSatFix on /gnss/fix; gnss.json)."""
    gnss_rate_hz: float = 5.0
    """Fixes per second."""
    gnss_noise_m: tuple[float, float] = (0.02, 0.04)
    """Standard deviation (m) of the fixes' horizontal and vertical error (RTK fixed: 1-2 cm / 2-4 cm)."""
    antenna_in_camera_m: tuple[float, float, float] = (0.0, -0.5, 0.0)
    """GNSS antenna position in the camera optical frame (x right, y down, z forward), metres: 0.5 m above it."""
    datum: tuple[float, float, float] = (49.5732, 11.0275, 290.0)
    """Latitude, longitude (degrees) and ellipsoidal height (m) of the world origin (the row's centre)."""
    datum_yaw_deg: float = 30.0
    """Heading of the world x axis (the row), degrees counter-clockwise from east."""

    def __post_init__(self) -> None:
        if isinstance(self.trees, bool) or not isinstance(self.trees, int) or not 1 <= self.trees <= 500:
            raise SynthError(f'trees must be an integer within 1..500, got {self.trees!r}')
        if self.tree_spacing_m is not None and not 0.1 <= float(self.tree_spacing_m) <= 50.0:
            raise SynthError(f'tree_spacing_m must be within 0.1..50 m, got {self.tree_spacing_m!r}')
        checks = {'crown_overlap': (self.crown_overlap, -1.0, 0.9),
                  'load_variation': (self.load_variation, 0.0, 0.9),
                  'planting_jitter_m': (self.planting_jitter_m, 0.0, 1.0),
                  'gnss_rate_hz': (self.gnss_rate_hz, 0.1, 100.0),
                  'datum_yaw_deg': (self.datum_yaw_deg, -360.0, 360.0)}
        for name, (value, lo, hi) in checks.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
                raise SynthError(f'{name} must be a number within {lo:g}..{hi:g}, got {value!r}')
        if len(self.gnss_noise_m) != 2 or min(self.gnss_noise_m) < 0 or len(self.antenna_in_camera_m) != 3:
            raise SynthError('gnss_noise_m must be (horizontal, vertical) >= 0 and antenna_in_camera_m 3 numbers')
        Datum(*self.datum).checked()


class RowScene(NamedTuple):
    """A row of trees.

    Attributes:
        scene: the joined render scene (fruit ids 1..N through the row, ``GtFruit.tree_id`` set).
        trunks: [T, 3] trunk positions on the ground (z = 0), metres, tree ids 1..T in x order.
        planted: [T, 3] the nominal planting grid the trunks stand near.
        crown_centers: [T, 3]; crown_radii: [T] horizontal crown radius, metres.
        spacing_m: the planting grid's spacing along the row.
    """

    scene: Scene
    trunks: np.ndarray
    planted: np.ndarray
    crown_centers: np.ndarray
    crown_radii: np.ndarray
    spacing_m: float


def _moved(scene: Scene, offset: np.ndarray, id_map: np.ndarray, tree_id: int) -> tuple[Scene, list[GtFruit]]:
    """``scene`` moved by ``offset`` [3], its fruit ids renumbered by ``id_map`` (old id -> new, 0 = dropped)."""
    e, lv, c = scene.ellipsoids, scene.leaves, scene.cylinders
    inst = id_map[e.instance]
    keep = (e.instance == 0) | (inst > 0)
    e = Ellipsoids(e.center[keep] + offset, e.rotation[keep], e.radii[keep], e.albedo[keep], e.blush[keep],
                   e.blush_amount[keep], inst[keep])
    fruits = [GtFruit(int(id_map[f.id]), f.type, f.center + offset, f.radii, f.rotation, tree_id)
              for f in scene.fruits if id_map[f.id] > 0]
    return scene._replace(ellipsoids=e, leaves=lv._replace(center=lv.center + offset),
                          cylinders=Cylinders(c.p0 + offset, c.p1 + offset, c.radius, c.albedo)), fruits


def _joined(parts: list[Scene], fruits: list[GtFruit], crown_c: np.ndarray, crown_r: np.ndarray) -> Scene:
    """One scene of the moved trees; a crown ellipsoid round the whole row (shading, the drive's length)."""
    def cat(name: str, field: str) -> np.ndarray:
        return np.concatenate([getattr(getattr(p, name), field) for p in parts])

    e = Ellipsoids(*(cat('ellipsoids', f) for f in Ellipsoids._fields))
    leaves = Leaves(*(cat('leaves', f) for f in Leaves._fields))
    cylinders = Cylinders(*(cat('cylinders', f) for f in Cylinders._fields))
    lo = np.min(crown_c - crown_r[:, None] * [1.0, 1.0, 0.85], axis=0)
    hi = np.max(crown_c + crown_r[:, None] * [1.0, 1.0, 0.85], axis=0)
    center, radii = 0.5 * (lo + hi), 0.5 * (hi - lo)
    top = float(hi[2]) * 1.1
    bound_center = np.array([center[0], center[1], 0.5 * top])
    bound_radius = float(max(np.hypot(radii[0] * _CROWN_REACH, center[2] - bound_center[2]), 0.5 * top))
    return Scene(e, leaves, cylinders, sorted(fruits, key=lambda f: f.id), center, radii, bound_center, bound_radius)


def build_row_scene(config: SynthConfig, row: RowSceneConfig) -> RowScene:
    """The row of ``row.trees`` trees (deterministic in ``config.seed``)."""
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x120]))
    mean = sum(fruit_type_counts(config).values())
    counts = np.maximum(1, np.round(mean * (1.0 + row.load_variation * rng.uniform(-1.0, 1.0, row.trees))))
    seeds = np.random.SeedSequence([config.seed, 0x121]).generate_state(row.trees)
    trees = [build_scene(dataclasses.replace(config, count=int(n), seed=int(s))) for n, s in zip(counts, seeds)]
    reach = np.array([_CROWN_REACH * t.crown_radii[0] for t in trees])
    spacing = row.tree_spacing_m or float(2.0 * reach.mean() * (1.0 - row.crown_overlap))
    planted = np.zeros((row.trees, 3))
    planted[:, 0] = (np.arange(row.trees) - 0.5 * (row.trees - 1)) * spacing
    trunks = planted + np.c_[row.planting_jitter_m * rng.normal(size=(row.trees, 2)), np.zeros(row.trees)]
    parts, fruits = [], []
    placed_c, placed_r = np.zeros((0, 3)), np.zeros(0)
    next_id = 1
    for k, tree in enumerate(trees):
        centers = np.array([f.center for f in tree.fruits]) + trunks[k]
        bounds = np.array([max(f.radii) for f in tree.fruits])
        clear = np.ones(len(centers), bool)
        if len(placed_c):  # where canopies overlap, a fruit may not pass through a neighbour's fruit
            near = cKDTree(placed_c).query_ball_point(centers, r=bounds + placed_r.max() + _FRUIT_GAP_M)
            clear = np.array([all(np.linalg.norm(placed_c[j] - c) >= b + placed_r[j] + _FRUIT_GAP_M for j in js)
                              for c, b, js in zip(centers, bounds, near)], bool)
        id_map = np.zeros(len(tree.fruits) + 1, np.int64)
        id_map[1:][clear] = next_id + np.arange(int(clear.sum()))
        next_id += int(clear.sum())
        moved, moved_fruits = _moved(tree, trunks[k], id_map, k + 1)
        parts.append(moved)
        fruits += moved_fruits
        placed_c, placed_r = np.r_[placed_c, centers[clear]], np.r_[placed_r, bounds[clear]]
    crown_c = np.array([t.crown_center for t in trees]) + trunks
    crown_r = np.array([t.crown_radii[0] for t in trees])
    return RowScene(_joined(parts, fruits, crown_c, crown_r), trunks, planted, crown_c, crown_r, spacing)


def row_gnss_fixes(poses: np.ndarray, stamps_ns: np.ndarray, row: RowSceneConfig, seed: int) -> list[GnssFix]:
    """Fixes of the antenna at ``row.gnss_rate_hz`` during each pass (none during the turn between them).

    Args:
        poses: [V, 4, 4] true camera-to-world poses (OpenGL), the first ceil(V / 2) on the way out.
        stamps_ns: [V] their stamps.
        row: datum, heading, noise, antenna offset.
        seed: the scene's seed (the fixes' noise has its own random stream).
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x6A5]))
    georef = georef_from_datum(Datum(*row.datum), row.datum_yaw_deg)
    n_out = (len(poses) + 1) // 2
    period = int(round(1e9 / row.gnss_rate_hz))
    fixes: list[GnssFix] = []
    sigma_h, sigma_v = row.gnss_noise_m
    covariance = (sigma_h ** 2, 0.0, 0.0, 0.0, sigma_h ** 2, 0.0, 0.0, 0.0, sigma_v ** 2)
    for first, last in ((0, n_out), (n_out, len(poses))):
        if last - first < 2:
            continue
        fix_stamps = np.arange(stamps_ns[first], stamps_ns[last - 1] + 1, period, dtype=np.int64)
        world, _ = antenna_positions(stamps_ns[first:last], poses[first:last], fix_stamps,
                                     np.asarray(row.antenna_in_camera_m), max_gap_s=1e9)
        enu = georef.enu_of(world) + rng.normal(size=(len(world), 3)) * [sigma_h, sigma_h, sigma_v]
        geo = geodetic_from_enu(enu, georef.enu_datum)
        fixes += [GnssFix(int(s), float(g[0]), float(g[1]), float(g[2]), covariance, 2)
                  for s, g in zip(fix_stamps, geo)]
    return fixes


def _write_trees(out_dir: Path, row_scene: RowScene, row: RowSceneConfig) -> None:
    georef = georef_from_datum(Datum(*row.datum), row.datum_yaw_deg)
    geo = georef.geodetic_of(row_scene.trunks)
    counts = np.bincount([f.tree_id for f in row_scene.scene.fruits], minlength=len(row_scene.trunks) + 1)[1:]
    trees = [{'id': k + 1, 'trunk': [round(float(v), 6) for v in row_scene.trunks[k]],
              'crown_center': [round(float(v), 6) for v in row_scene.crown_centers[k]],
              'crown_radius': round(float(row_scene.crown_radii[k]), 6), 'n_fruits': int(counts[k]),
              'latitude': round(float(geo[k, 0]), 10), 'longitude': round(float(geo[k, 1]), 10)}
             for k in range(len(row_scene.trunks))]
    data = {'units': 'm', 'frame': 'world (z up, ground z = 0), same as transforms.json', 'trees': trees,
            'spacing_m': round(row_scene.spacing_m, 6), 'row_axis': [1.0, 0.0, 0.0],
            'datum': {'latitude': row.datum[0], 'longitude': row.datum[1], 'altitude': row.datum[2],
                      'yaw_deg': row.datum_yaw_deg}}
    (out_dir / GT_TREES_NAME).write_text(json.dumps(data, indent=1, sort_keys=True) + '\n')
    lines = ['tree_id,x,y'] + [f'{k + 1},{p[0]:.4f},{p[1]:.4f}' for k, p in enumerate(row_scene.planted)]
    (out_dir / PLANTING_CSV_NAME).write_text('\n'.join(lines) + '\n')
    planted_geo = georef.geodetic_of(row_scene.planted)
    (out_dir / PLANTING_GEOJSON_NAME).write_text(json.dumps(planting_map_geojson(
        list(range(1, len(planted_geo) + 1)), planted_geo), indent=1) + '\n')


def generate_row(config: SynthConfig, row: RowSceneConfig, out_dir: str | Path, *, bag: str | Path | None = None,
                 bag_storage: str = 'mcap', preview: str | Path | None = None, progress: Any = None) -> Any:
    """Generate a row of trees (dataset, ground truth per fruit and per tree, planting map, optional bag and GNSS).

    ``config.trajectory`` is taken as ``row``; ``config.count`` is the mean number of fruits per tree.

    Returns:
        the :class:`~fruitnerfpp_ros.core.synthetic.generator.SynthResult`.

    Raises:
        SynthError: as :func:`~fruitnerfpp_ros.core.synthetic.generator.generate_orchard`.
    """
    from fruitnerfpp_ros.core.synthetic.generator import generate_orchard

    config = dataclasses.replace(config, trajectory='row')
    out_dir = Path(out_dir)
    row_scene = build_row_scene(config, row)
    fixes: list[GnssFix] = []
    if row.gnss:
        poses = make_poses(row_scene.scene, config)
        stamps = BAG_START_NS + FRAME_PERIOD_NS * np.arange(len(poses), dtype=np.int64)
        fixes = row_gnss_fixes(poses, stamps, row, config.seed)
    extra = {'scene': 'row', 'row': config_to_mapping(row),
             'datum': {'latitude': row.datum[0], 'longitude': row.datum[1], 'altitude': row.datum[2],
                       'yaw_deg': row.datum_yaw_deg},
             'frame': 'world: z up, metres, ground at z = 0, the row along x centred on the origin'}
    result = generate_orchard(config, out_dir, bag=bag, bag_storage=bag_storage, preview=preview,
                              progress=progress, scene=row_scene.scene, transforms_extra=extra, gnss_fixes=fixes)
    _write_trees(out_dir, row_scene, row)
    if row.gnss:
        write_gnss_json(out_dir / GNSS_JSON, fixes, row.antenna_in_camera_m)
    return result
