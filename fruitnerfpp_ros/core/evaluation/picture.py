"""A picture of a count against ground truth that a person can judge at a glance (issue #11).

Two panels and a legend: the dataset view that sees most fruits with the counted centres projected into it, and a
top view (x-y plane, metres, scale bar) of counted and ground-truth centres. Hits (counted fruits matched to a
ground-truth fruit, joined to it by a line), misses (unmatched ground truth) and false counts (unmatched counted
fruits) have their own colours; the legend gives count / GT, precision, recall and F1 of the matching used.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import cv2
import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_path
from fruitnerfpp_ros.core.data.transforms_format import TransformsFile, read_transforms
from fruitnerfpp_ros.core.evaluation.ground_truth import GroundTruth
from fruitnerfpp_ros.core.evaluation.metrics import EvalMetrics, evaluate_counts
from fruitnerfpp_ros.core.tracking.camera import PinholeView
from fruitnerfpp_ros.errors import DatasetError, EvaluationError

__all__ = ['MarkerKind', 'Marker', 'CountPicture', 'MARKER_BGR', 'write_count_picture', 'keyframe_index']


class MarkerKind(StrEnum):
    """What a marker shows."""

    HIT = 'hit'
    """A counted fruit matched to a ground-truth fruit (drawn at the counted centre)."""
    MISS = 'miss'
    """A ground-truth fruit no counted fruit matched (drawn at its centre)."""
    FALSE = 'false count'
    """A counted fruit matched to no ground-truth fruit."""
    UNSEEN = 'unseen GT'
    """An unmatched ground-truth fruit that no view saw, left out of the recall (``exclude_unseen``)."""


#: Marker colours, OpenCV BGR: green hits, red misses, magenta false counts, grey unseen ground truth.
MARKER_BGR: dict[MarkerKind, tuple[int, int, int]] = {
    MarkerKind.HIT: (40, 170, 40), MarkerKind.MISS: (40, 40, 220), MarkerKind.FALSE: (210, 60, 200),
    MarkerKind.UNSEEN: (150, 150, 150)}
_BACKGROUND = (255, 255, 255)
_INK = (30, 30, 30)
_FAINT = (200, 200, 200)
_NICE_LENGTHS_M = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)


@dataclass(frozen=True)
class Marker:
    """One drawn marker.

    Attributes:
        kind: hit, miss, false count or unseen ground truth.
        panel: ``keyframe`` or ``top``.
        index: index of the counted fruit (hit, false count) or of the ground-truth fruit (miss, unseen).
        xy_px: (x, y) of the marker's centre in the whole picture, pixels.
    """

    kind: MarkerKind
    panel: str
    index: int
    xy_px: tuple[int, int]


@dataclass(frozen=True)
class CountPicture:
    """What :func:`write_count_picture` drew.

    Attributes:
        path: the written image.
        width: picture width, pixels.
        height: picture height, pixels.
        keyframe: index (in transforms.json) of the view drawn, or None without a dataset.
        markers: every marker drawn, in drawing order (later ones may cover earlier ones).
    """

    path: Path
    width: int
    height: int
    keyframe: int | None
    markers: list[Marker]


@dataclass(frozen=True)
class _Classes:
    """Indices per marker kind: hit pairs [M, 2] (count, GT), false counts, misses, unseen GT."""

    hits: np.ndarray
    false: np.ndarray
    misses: np.ndarray
    unseen: np.ndarray


def _classify(centers: np.ndarray, gt: GroundTruth, metrics: EvalMetrics) -> _Classes:
    pairs = np.asarray(metrics.hungarian.pairs, np.int64).reshape(-1, 2)
    if len(pairs) and (pairs[:, 0].max() >= len(centers) or pairs[:, 1].max() >= len(gt)):
        raise EvaluationError(f'the match pairs {len(centers)} counted fruits with {len(gt)} ground-truth fruits '
                              'but names indices beyond them: it was computed for other inputs')
    matched_gt = np.zeros(len(gt), bool)
    matched_gt[pairs[:, 1]] = True
    unmatched = np.flatnonzero(~matched_gt)
    unseen = unmatched[~gt.seen[unmatched]] if metrics.exclude_unseen else unmatched[:0]
    return _Classes(pairs, np.setdiff1d(np.arange(len(centers)), pairs[:, 0]), np.setdiff1d(unmatched, unseen),
                    unseen)


def keyframe_index(dataset_dir: Path, transforms: TransformsFile, gt_centers: np.ndarray) -> int:
    """The view that sees most fruits: most instance ids in its mask when every frame has one, else most
    ground-truth centres projecting into the image (in front of the camera); the first such view on ties."""
    if all(frame.instance_path for frame in transforms.frames):
        seen = []
        for frame in transforms.frames:
            mask = cv2.imread(str(dataset_dir / str(frame.instance_path)), cv2.IMREAD_UNCHANGED)
            if mask is None:
                raise DatasetError(f'{dataset_dir / str(frame.instance_path)}: cannot read instance mask')
            seen.append(len(np.unique(mask[..., 0] if mask.ndim == 3 else mask)) - int((mask == 0).any()))
        return int(np.argmax(seen))
    inside = []
    for index, frame in enumerate(transforms.frames):
        view = PinholeView.from_intrinsics(frame.T_world_camera, transforms.intrinsics_of(index))
        uv, depth = view.project(gt_centers)
        with np.errstate(invalid='ignore'):
            inside.append(int(np.sum((depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < view.width)
                                     & (uv[:, 1] >= 0) & (uv[:, 1] < view.height))))
    return int(np.argmax(inside))


def _disc(canvas: np.ndarray, xy: tuple[int, int], kind: MarkerKind, radius: int) -> None:
    cv2.circle(canvas, xy, radius + 1, _INK, -1, cv2.LINE_AA)
    cv2.circle(canvas, xy, radius, MARKER_BGR[kind], -1, cv2.LINE_AA)


def _draw_points(canvas: np.ndarray, panel: str, to_px: np.ndarray, valid: np.ndarray, gt_px: np.ndarray,
                 gt_valid: np.ndarray, classes: _Classes, radius: int) -> list[Marker]:
    """Hit lines, then markers (unseen, misses, false counts, hits); ``to_px``/``gt_px``: [N, 2] positions in the
    picture of the counted / ground-truth centres, ``valid``/``gt_valid`` which of them are drawable."""
    def xy(p: np.ndarray) -> tuple[int, int]:
        return int(round(p[0])), int(round(p[1]))

    for c, g in classes.hits:
        if valid[c] and gt_valid[g]:
            cv2.line(canvas, xy(to_px[c]), xy(gt_px[g]), MARKER_BGR[MarkerKind.HIT], 1, cv2.LINE_AA)
    markers = []
    for kind, indices, points, ok in ((MarkerKind.UNSEEN, classes.unseen, gt_px, gt_valid),
                                      (MarkerKind.MISS, classes.misses, gt_px, gt_valid),
                                      (MarkerKind.FALSE, classes.false, to_px, valid),
                                      (MarkerKind.HIT, classes.hits[:, 0], to_px, valid)):
        for i in indices:
            if ok[i]:
                _disc(canvas, xy(points[i]), kind, radius)
                markers.append(Marker(kind, panel, int(i), xy(points[i])))
    return markers


def _keyframe_panel(dataset_dir: Path, centers: np.ndarray, gt: GroundTruth, classes: _Classes, panel_px: int,
                    radius: int) -> tuple[np.ndarray, list[Marker], int]:
    transforms = read_transforms(dataset_dir)
    index = keyframe_index(dataset_dir, transforms, gt.centers)
    frame = transforms.frames[index]
    image_path = dataset_dir / frame.file_path
    image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
    if image is None:
        raise DatasetError(f'{image_path}: cannot read the keyframe image')
    view = PinholeView.from_intrinsics(frame.T_world_camera, transforms.intrinsics_of(index))

    def place(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uv, depth = view.project(points)
        with np.errstate(invalid='ignore'):
            ok = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < view.width) & (uv[:, 1] >= 0) & (uv[:, 1] < view.height)
        return np.nan_to_num(uv), ok

    (to_uv, valid), (gt_uv, gt_valid) = place(centers), place(gt.centers)
    x0, y0, crop_h = _zoom(np.vstack([to_uv[valid], gt_uv[gt_valid]]), image.shape[1], image.shape[0])
    crop_w = int(round(crop_h * image.shape[1] / image.shape[0]))
    scale = panel_px / crop_h
    canvas = cv2.resize(image[y0:y0 + crop_h, x0:x0 + crop_w], (round(image.shape[1] * panel_px / image.shape[0]),
                        panel_px), interpolation=cv2.INTER_NEAREST)
    shift = np.array([x0, y0], np.float64)
    markers = _draw_points(canvas, 'keyframe', (to_uv - shift) * scale, valid, (gt_uv - shift) * scale, gt_valid,
                           classes, radius)
    zoom = image.shape[0] / crop_h
    _title(canvas, f'view {index} ({frame.file_path})' + (f', zoom {zoom:.1f}x' if zoom > 1.0 else ''), panel_px)
    return canvas, markers, index


def _zoom(uv: np.ndarray, width: int, height: int) -> tuple[int, int, int]:
    """(left, top, height) in pixels of the crop of the image (same aspect ratio) that frames the points ``uv``
    [N, 2] with a margin, at most the whole image and at least a quarter of it."""
    if len(uv) == 0:
        return 0, 0, height
    lo, hi = uv.min(0), uv.max(0)
    aspect = width / height
    crop_h = 1.3 * max(hi[1] - lo[1], (hi[0] - lo[0]) / aspect) + 0.05 * height
    crop_h = int(np.clip(np.ceil(crop_h), max(1, height // 4), height))
    crop_w = min(width, int(round(crop_h * aspect)))
    middle = 0.5 * (lo + hi)
    x0 = int(np.clip(round(middle[0] - 0.5 * crop_w), 0, width - crop_w))
    y0 = int(np.clip(round(middle[1] - 0.5 * crop_h), 0, height - crop_h))
    return x0, y0, crop_h


def _top_panel(centers: np.ndarray, gt: GroundTruth, classes: _Classes, panel_px: int, radius: int,
               ) -> tuple[np.ndarray, list[Marker]]:
    canvas = np.full((panel_px, panel_px, 3), _BACKGROUND, np.uint8)
    xy = np.vstack([centers[:, :2], gt.centers[:, :2]])
    reach = float(gt.diameters.max(initial=0.05))
    lo, hi = (xy.min(0), xy.max(0)) if len(xy) else (np.zeros(2), np.zeros(2))
    extent = max(float((hi - lo).max()) + 2.0 * reach, 0.2)
    middle = 0.5 * (lo + hi)
    pad = 0.06 * panel_px
    scale = (panel_px - 2.0 * pad) / extent  # pixels per metre

    def to_px(points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, np.float64).reshape(-1, 3)
        return np.stack([0.5 * panel_px + (points[:, 0] - middle[0]) * scale,
                         0.5 * panel_px - (points[:, 1] - middle[1]) * scale], axis=1)

    gt_px = to_px(gt.centers)
    for p, d in zip(gt_px, gt.diameters):  # each ground-truth fruit's outline, true to scale
        cv2.circle(canvas, (int(round(p[0])), int(round(p[1]))), max(1, int(round(0.5 * d * scale))), _FAINT, 1,
                   cv2.LINE_AA)
    pred_px = to_px(centers)
    markers = _draw_points(canvas, 'top', pred_px, np.ones(len(centers), bool), gt_px, np.ones(len(gt), bool),
                           classes, radius)
    length = max([v for v in _NICE_LENGTHS_M if v <= 0.3 * extent], default=_NICE_LENGTHS_M[0])
    x0, y0 = int(pad), int(panel_px - pad)
    x1 = x0 + int(round(length * scale))
    cv2.line(canvas, (x0, y0), (x1, y0), _INK, 2)
    for x in (x0, x1):
        cv2.line(canvas, (x, y0 - 4), (x, y0 + 4), _INK, 2)
    _text(canvas, f'{length:g} m', (x0, y0 - 8), panel_px)
    _title(canvas, 'top view (x right, y up, metres)', panel_px)
    return canvas, markers


def _font(panel_px: int) -> float:
    return 0.45 * panel_px / 480.0


def _text(canvas: np.ndarray, text: str, origin: tuple[int, int], panel_px: int, colour: tuple[int, ...] = _INK,
          ) -> None:
    cv2.putText(canvas, text, origin, cv2.FONT_HERSHEY_SIMPLEX, _font(panel_px), colour, 1, cv2.LINE_AA)


def _title(canvas: np.ndarray, text: str, panel_px: int) -> None:
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, _font(panel_px), 1)
    cv2.rectangle(canvas, (0, 0), (w + 8, h + base + 8), _BACKGROUND, -1)
    _text(canvas, text, (4, h + 4), panel_px)


def _legend(width: int, panel_px: int, metrics: EvalMetrics, classes: _Classes, radius: int) -> np.ndarray:
    height = int(round(0.16 * panel_px))
    canvas = np.full((height, width, 3), _BACKGROUND, np.uint8)
    s = metrics.hungarian
    _text(canvas, f'count {metrics.count} / GT {metrics.gt_count}   TP {s.tp}   P {s.precision:.3f}   '
                  f'R {s.recall:.3f}   F1 {s.f1:.3f}   (one-to-one within {metrics.tolerance:g} GT diameter)',
          (8, int(0.38 * height)), panel_px)
    x = 8 + radius
    y = int(0.75 * height)
    counts = {MarkerKind.HIT: len(classes.hits), MarkerKind.MISS: len(classes.misses),
              MarkerKind.FALSE: len(classes.false), MarkerKind.UNSEEN: len(classes.unseen)}
    for kind, n in counts.items():
        if kind is MarkerKind.UNSEEN and n == 0:
            continue
        _disc(canvas, (x, y), kind, radius)
        label = f'{kind.value} ({n})'
        _text(canvas, label, (x + radius + 6, y + radius // 2), panel_px)
        x += radius + 6 + cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, _font(panel_px), 1)[0][0] + 4 * radius
    return canvas


def write_count_picture(path: str | Path, dataset_dir: str | Path | None, counts_centers: np.ndarray,
                        gt_fruits: GroundTruth, match: EvalMetrics | None = None, *, panel_px: int = 480,
                        ) -> CountPicture:
    """Draw counted fruit centres against the ground truth and write the picture (PNG or JPEG, by extension).

    Args:
        path: the image to write (parent folders created; written atomically).
        dataset_dir: the transforms.json dataset for the keyframe panel (the view seeing most fruits, its pose and
            intrinsics), or None for the top view only.
        counts_centers: [K, 3] counted fruit centres (m, world frame of the dataset).
        gt_fruits: the ground truth.
        match: the evaluation whose Hungarian matching is drawn (default: :func:`evaluate_counts` with its
            defaults).
        panel_px: height of each panel in pixels (the top view is square; the keyframe keeps its aspect ratio).

    Returns:
        what was drawn where (size, keyframe, markers).

    Raises:
        EvaluationError: non-finite or malformed centres, a match computed for other inputs, or an unwritable path.
        DatasetError: an unreadable dataset, mask or keyframe image.
    """
    path = Path(path)
    centers = np.asarray(counts_centers, np.float64)
    if centers.size == 0:
        centers = centers.reshape(0, 3)
    if centers.ndim != 2 or centers.shape[1] != 3 or not np.all(np.isfinite(centers)):
        raise EvaluationError(f'counted centres must be a finite [K, 3] array, got shape {centers.shape}')
    if panel_px < 120:
        raise EvaluationError(f'panel_px must be >= 120, got {panel_px}')
    metrics = match if match is not None else evaluate_counts(centers, gt_fruits)
    classes = _classify(centers, gt_fruits, metrics)
    radius = max(4, panel_px // 80)
    panels, markers, keyframe = [], [], None
    if dataset_dir is not None:
        panel, drawn, keyframe = _keyframe_panel(Path(dataset_dir), centers, gt_fruits, classes, panel_px, radius)
        panels.append(panel)
        markers += drawn
    top, drawn = _top_panel(centers, gt_fruits, classes, panel_px, radius)
    offset = sum(p.shape[1] for p in panels)
    markers += [Marker(m.kind, m.panel, m.index, (m.xy_px[0] + offset, m.xy_px[1])) for m in drawn]
    panels.append(top)
    picture = np.hstack(panels)
    picture = np.vstack([picture, _legend(picture.shape[1], panel_px, metrics, classes, radius)])
    try:
        with atomic_path(path, suffix=f'.tmp{path.suffix}') as tmp:
            if not cv2.imwrite(str(tmp), picture):
                raise EvaluationError(f'cannot write picture {path}')
    except (OSError, cv2.error) as err:
        raise EvaluationError(f'cannot write picture {path}: {str(err).strip().splitlines()[-1]} (use .png or '
                              '.jpg)') from err
    return CountPicture(path, picture.shape[1], picture.shape[0], keyframe, markers)
