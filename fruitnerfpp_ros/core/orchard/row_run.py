"""A whole row, offline: cut -> one job per segment (a runner: in-process or Ray) -> merge -> trees -> georeference
-> files for farm software.

Run directory::

    RUN/row.json                the row frame, the fruit stretch, every segment (stretches, keyframes, outcome)
    RUN/segments/seg_NNN/       dataset/transforms.json (the segment's keyframes), run/ (its training run: cloud,
                                counts.json...), result.json, attempts.jsonl
    RUN/trees.csv  RUN/trees.geojson  RUN/fruits.geojson
    RUN/row_report.json         the report (schema fruitnerfpp_ros/fruit_report version 2)
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import TransformsFile, read_transforms
from fruitnerfpp_ros.core.orchard.config import OrchardConfig
from fruitnerfpp_ros.core.orchard.geodesy import Datum
from fruitnerfpp_ros.core.orchard.georef import WorldGeoref, fit_georef_to_drive, georef_from_datum, parse_datum
from fruitnerfpp_ros.core.orchard.gnss import GnssFix
from fruitnerfpp_ros.core.orchard.jobs import SegmentJob, SegmentOutcome, SegmentRunner
from fruitnerfpp_ros.core.orchard.merge import RowFruits, merge_segments
from fruitnerfpp_ros.core.orchard.report import (fruits_geojson, row_report, trees_csv, trees_geojson,
                                                 write_json)
from fruitnerfpp_ros.core.orchard.row_frame import RowFrame, estimate_row_frame, viewed_intervals
from fruitnerfpp_ros.core.orchard.segments import (Segment, edges_between_trees, fruit_extent, plan_segments,
                                                   search_box, segment_edges, write_segment_dataset)
from fruitnerfpp_ros.core.orchard.trees import TreeCount, TreeMap, count_trees, find_trees, read_planting_map
from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.errors import OrchardError

__all__ = ['RowPlan', 'RowResult', 'plan_row', 'resolve_georef', 'run_row', 'finish_row', 'ROW_REPORT_NAME']

ROW_REPORT_NAME = 'row_report.json'
Log = Callable[[str], None]


class RowPlan(NamedTuple):
    """How the row is cut.

    Attributes:
        frame: row coordinates; extent: (s_min, s_max) of the fruit stretch; segments: the segments;
        intervals: [N, 2] the stretch each keyframe sees; trees: the planting map's trees (None: found later).
    """

    frame: RowFrame
    extent: tuple[float, float]
    segments: list[Segment]
    intervals: np.ndarray
    trees: TreeMap | None


class RowResult(NamedTuple):
    """A counted row: plan, every segment's outcome, the fruits, the trees and their counts, the output paths."""

    plan: RowPlan
    outcomes: list[SegmentOutcome]
    fruits: RowFruits
    trees: TreeMap
    tree_counts: list[TreeCount]
    fruit_trees: np.ndarray
    georef: WorldGeoref | None
    report: dict[str, Any]
    paths: dict[str, Path]


def _poses(transforms: TransformsFile) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    T = np.stack([f.T_world_camera for f in transforms.frames])
    K = [transforms.intrinsics_of(i) for i in range(len(transforms.frames))]
    return T, np.array([k.fl_x for k in K]), np.array([k.w for k in K])


def resolve_georef(config: OrchardConfig, transforms: TransformsFile, fixes: Sequence[GnssFix] | None,
                   antenna: np.ndarray | None, log: Log = print) -> WorldGeoref | None:
    """The world <-> WGS84 relation: the ``datum`` setting, else a fit to GNSS fixes, else the datum the dataset
    records (``transforms.json`` ``datum``), else None (no WGS84 output).

    Raises:
        OrchardError: a malformed datum, or fixes that cannot be fitted.
    """
    geo = config.geo
    if geo.datum is not None:
        datum, yaw = parse_datum(list(geo.datum))
        return georef_from_datum(datum, yaw)
    if fixes:
        georef = fit_georef_to_drive([f.stamp_ns or 0 for f in transforms.frames],
                                     np.stack([f.T_world_camera for f in transforms.frames]), fixes, geo, antenna)
        log(f'georeferenced from {georef.n_fixes} GNSS fixes ({georef.n_rejected} rejected): residual '
            f'{georef.residual_rms_m:.3f} m horizontal, {georef.residual_vertical_rms_m:.3f} m vertical')
        return georef
    recorded = transforms.extra.get('datum')
    if isinstance(recorded, dict):
        try:
            datum = Datum(recorded['latitude'], recorded['longitude'], recorded['altitude'])
            return georef_from_datum(datum, float(recorded.get('yaw_deg', 0.0)))
        except (KeyError, TypeError, ValueError) as err:
            raise OrchardError(f'transforms.json datum is malformed: {err}') from err
    log('no datum and no GNSS fixes: trees.csv and the report carry world coordinates only (no GeoJSON)')
    return None


def plan_row(dataset_dir: Path, transforms: TransformsFile, config: OrchardConfig,
             trees: TreeMap | None) -> RowPlan:
    """Row frame, fruit stretch and segments of a dataset (one segment per tree of a planting map when
    ``segments.length_m`` is None).

    Raises:
        OrchardError: the cameras show no row (no movement, no fruit in the masks).
    """
    seg = config.segments
    T, fl_x, width = _poses(transforms)
    frame = estimate_row_frame(T, standoff_m=seg.standoff_m, default_standoff_m=seg.default_standoff_m)
    intervals = viewed_intervals(frame, T, fl_x, width, crown_half_depth_m=seg.crown_half_depth_m,
                                 max_range_m=seg.max_range_m)
    extent = fruit_extent(transforms, dataset_dir, frame)
    if extent is None:
        raise OrchardError(f'{dataset_dir}: no fruit in the instance masks: nothing to count along the row')
    if trees is not None and seg.length_m is None:
        edges = edges_between_trees(frame.along(trees.positions))
    else:
        edges = segment_edges(extent[0], extent[1], seg.length_m or seg.default_length_m)
    return RowPlan(frame, extent, plan_segments(intervals, edges, seg), intervals, trees)


def run_row(dataset_dir: str | Path, out_dir: str | Path, runner: SegmentRunner, *,
            config: OrchardConfig = OrchardConfig(), train_config: Any = None, export_config: Any = None,
            cluster_config: Any = None, device: str = 'auto', planting_map: str | Path | None = None,
            fixes: Sequence[GnssFix] | None = None, antenna_in_camera_m: np.ndarray | None = None,
            frame_id: str = 'map', extra: dict[str, Any] | None = None, log: Log = print,
            progress: Callable[[int, int], None] | None = None) -> RowResult:
    """Count a row: plan it, run one job per segment on ``runner``, join the counts, write the outputs.

    Args:
        dataset_dir: the row's transforms.json dataset (keyframes in drive order, with instance masks).
        out_dir: the run directory (created).
        runner: :class:`~.jobs.InProcessRunner` or :class:`~.jobs.RayRunner`.
        config: segments, merge, trees, georeferencing.
        train_config / export_config / cluster_config / device: each segment's pipeline.
        planting_map: CSV / GeoJSON of trunk positions (None: trees found from the fruit).
        fixes / antenna_in_camera_m: GNSS fixes of the drive and the antenna's offset in the camera frame.
        frame_id: the world frame's name in the report.
        extra: more report keys (e.g. ``keyframes``, ``preset``).
        log: receives a line per step; progress: ``(segments finished, segment jobs)`` once planned and after each.

    Raises:
        OrchardError: the row cannot be planned or georeferenced; DatasetError: an unreadable dataset.
    """
    dataset_dir, out_dir = Path(dataset_dir), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    transforms = read_transforms(dataset_dir)
    georef = resolve_georef(config, transforms, fixes, antenna_in_camera_m, log)
    trees = read_planting_map(planting_map, georef) if planting_map is not None else None
    plan = plan_row(dataset_dir, transforms, config, trees)
    poses = np.stack([f.T_world_camera for f in transforms.frames])
    jobs, skipped = [], []
    for segment in plan.segments:
        seg_dir = out_dir / 'segments' / segment.name
        if len(segment.frames) < config.segments.min_views:
            skipped.append(segment.index)
            continue
        write_segment_dataset(transforms, dataset_dir, segment.frames, seg_dir / 'dataset', segment.to_json())
        box = search_box(plan.frame, segment, poses, config.segments)
        jobs.append(SegmentJob(segment.index, str(seg_dir / 'dataset'), str(seg_dir), train_config, export_config,
                               cluster_config, device, tuple(float(v) for v in box.reshape(-1))))
    log(f'row of {plan.extent[1] - plan.extent[0]:.2f} m with fruit: {len(plan.segments)} segment(s) '
        f'({len(skipped)} with fewer than {config.segments.min_views} keyframes), '
        f'{max((len(s.frames) for s in plan.segments), default=0)} keyframes at most per segment')
    started = time.perf_counter()
    finished = 0
    if progress is not None:
        progress(0, len(jobs))

    def done(outcome: SegmentOutcome) -> None:
        nonlocal finished
        finished += 1
        state = f'{len(outcome.fruits.centers)} fruits' if outcome.ok else f'FAILED ({outcome.error})'
        log(f'segment {outcome.index}: {state} after {outcome.attempts} attempt(s), {outcome.seconds:.0f} s')
        if progress is not None:
            progress(finished, len(jobs))

    outcomes = runner.run(jobs, done)
    outcomes += [SegmentOutcome(i, None, f'fewer than {config.segments.min_views} keyframes', 0) for i in skipped]
    outcomes.sort(key=lambda o: o.index)
    log(f'{sum(o.ok for o in outcomes)} of {len(outcomes)} segment(s) counted in {time.perf_counter() - started:.0f} s')
    return finish_row(plan, outcomes, out_dir, config, georef, frame_id=frame_id, extra=extra)


def _segment_records(plan: RowPlan, outcomes: Sequence[SegmentOutcome], fruits: RowFruits) -> list[dict[str, Any]]:
    by_index = {o.index: o for o in outcomes}
    records = []
    for seg in plan.segments:
        o = by_index.get(seg.index)
        state = 'pending' if o is None else ('done' if o.ok else 'failed')
        kept = int(np.count_nonzero(fruits.segments == seg.index))
        records.append({'index': seg.index, 'core': [round(v, 3) for v in seg.core], 'keyframes': len(seg.frames),
                        'state': state, 'fruits_counted': None if o is None or not o.ok else len(o.fruits.centers),
                        'fruits_kept': kept, 'error': '' if o is None else o.error,
                        'attempts': 0 if o is None else o.attempts,
                        'seconds': None if o is None else round(o.seconds, 1)})
    return records


def finish_row(plan: RowPlan, outcomes: Sequence[SegmentOutcome], out_dir: Path, config: OrchardConfig,
               georef: WorldGeoref | None, *, frame_id: str = 'map', stamp_ns: int = 0, run_id: str = '',
               extra: dict[str, Any] | None = None, write_files: bool = True) -> RowResult:
    """Join finished segments into the row's fruits, trees, counts and report (and its files)."""
    fruits = merge_segments(plan.frame, plan.segments, [o.fruits for o in outcomes], config.merge)
    trees = plan.trees
    if trees is None:
        trees = find_trees(fruits.centers, plan.frame, config.trees) if len(fruits) >= \
            config.trees.min_fruits_per_tree else TreeMap(np.zeros(0, np.int64), np.zeros((0, 3)), 'data')
    ok = {o.index for o in outcomes if o.ok}
    finished = [s.core for s in plan.segments if s.index in ok]
    tree_counts, index = count_trees(trees, plan.frame, fruits.centers, fruits.diameters, _spans(finished),
                                     config.trees, measured=fruits.n_points > 0)
    tree_ids = trees.ids[index] if len(trees) else np.zeros(len(fruits), np.int64)
    fruit_geo = georef.geodetic_of(fruits.centers) if georef is not None and len(fruits) else None
    tree_geo = georef.geodetic_of(trees.positions) if georef is not None and len(trees) else None
    row_id = config.geo.row_id
    row = {'id': row_id, **plan.frame.to_json(), 'fruit_extent_m': [round(v, 3) for v in plan.extent],
           'trees_source': trees.source, 'duplicates_removed': int(fruits.matched.sum()),
           'dropped_off_row': fruits.dropped_off_row, 'dropped_untrusted': fruits.dropped_untrusted,
           'dropped_unsupported': fruits.dropped_unsupported}
    report = row_report(run_id=run_id or out_dir.name, frame_id=frame_id, stamp_ns=stamp_ns, fruits=fruits,
                        tree_ids=tree_ids, trees=tree_counts, fruit_geodetic=fruit_geo, tree_geodetic=tree_geo,
                        row=row, segments=_segment_records(plan, outcomes, fruits),
                        georef=None if georef is None else georef.to_json(), extra=extra)
    paths: dict[str, Path] = {}
    if write_files:
        paths['report'] = write_json(out_dir / ROW_REPORT_NAME, report)
        paths['trees_csv'] = atomic_write_text(out_dir / 'trees.csv', trees_csv(tree_counts, tree_geo, row_id))
        if georef is not None:
            paths['trees_geojson'] = write_json(out_dir / 'trees.geojson', trees_geojson(
                tree_counts, tree_geo if tree_geo is not None else np.zeros((0, 3)), row_id))
            paths['fruits_geojson'] = write_json(out_dir / 'fruits.geojson', fruits_geojson(
                fruits, tree_ids, fruit_geo if fruit_geo is not None else np.zeros((0, 3)), row_id))
        paths['row'] = write_json(out_dir / 'row.json', {'frame': plan.frame.to_json(), 'extent': list(plan.extent),
                                                         'segments': [s.to_json() for s in plan.segments],
                                                         'outcomes': [_outcome_json(o) for o in outcomes]})
    return RowResult(plan, list(outcomes), fruits, trees, tree_counts, tree_ids, georef, report, paths)


def _spans(cores: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Adjacent stretches joined (a tree spanning two finished segments is complete)."""
    spans: list[tuple[float, float]] = []
    for a, b in sorted(cores):
        if spans and a <= spans[-1][1] + 1e-6:
            spans[-1] = (spans[-1][0], max(spans[-1][1], b))
        else:
            spans.append((a, b))
    return spans


def _outcome_json(o: SegmentOutcome) -> dict[str, Any]:
    return {'index': o.index, 'ok': o.ok, 'error': o.error, 'attempts': o.attempts, 'seconds': round(o.seconds, 2),
            'worker': o.worker, 'peak_rss_mib': o.peak_rss_mib,
            'fruits': None if o.fruits is None else len(o.fruits.centers)}
