"""Run the tracking counter over a transforms.json dataset (frames in recording order) and write counts.json."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.data.transforms_format import TRANSFORMS_NAME, TransformsFile, read_transforms
from fruitnerfpp_ros.core.tracking.camera import PinholeView
from fruitnerfpp_ros.core.tracking.config import TrackConfig
from fruitnerfpp_ros.core.tracking.detections import detect_blobs
from fruitnerfpp_ros.core.tracking.result import TrackCount
from fruitnerfpp_ros.core.tracking.tracker import FruitTracker
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['frame_order', 'read_instance_mask', 'track_dataset', 'write_track_counts']


def frame_order(transforms: TransformsFile, order: str = 'time') -> np.ndarray:
    """Indices of the frames in processing order: by ``stamp_ns`` (stable) when ``order`` is ``time`` and every
    frame has a stamp, else the file order."""
    stamps = [frame.stamp_ns for frame in transforms.frames]
    if order == 'time' and all(s is not None for s in stamps):
        return np.argsort(np.asarray(stamps, np.int64), kind='stable')
    return np.arange(len(transforms.frames))


def read_instance_mask(dataset_dir: Path, transforms: TransformsFile, index: int) -> np.ndarray:
    """[H, W] int32 instance ids of frame ``index``.

    Raises:
        DatasetError: the frame has no ``instance_path``, the mask is missing or undecodable, or its size
            disagrees with the frame's intrinsics.
    """
    frame = transforms.frames[index]
    where = f'{dataset_dir / TRANSFORMS_NAME} frame {index} ({frame.file_path})'
    if frame.instance_path is None:
        raise DatasetError(f'{where}: no instance_path (the tracker counts instance masks; run `fruitnerfpp '
                           'segment` first)')
    path = dataset_dir / frame.instance_path
    if not path.is_file():
        raise DatasetError(f'{path}: instance mask not found')
    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None:
        raise DatasetError(f'{path}: cannot decode instance mask')
    if mask.ndim == 3:  # colour-coded masks: the first channel holds the ids, as core/data/dataset.py reads them
        mask = mask[..., 0]
    cam = transforms.intrinsics_of(index)
    if mask.shape != (cam.h, cam.w):
        raise DatasetError(f'{path}: instance mask is {mask.shape[1]}x{mask.shape[0]} but {where} says '
                           f'{cam.w}x{cam.h}')
    return mask.astype(np.int32)


def track_dataset(dataset_dir: str | Path, config: TrackConfig | None = None) -> TrackCount:
    """Count the fruits of a dataset by tracking its instance masks from frame to frame.

    Args:
        dataset_dir: a transforms.json dataset with per-frame ``instance_path`` masks.
        config: tracking settings.

    Raises:
        DatasetError: missing / malformed transforms.json or masks.
    """
    dataset_dir = Path(dataset_dir)
    config = config or TrackConfig()
    transforms = read_transforms(dataset_dir)
    order = frame_order(transforms, config.frame_order)
    tracker = FruitTracker(config)
    start = time.perf_counter()
    for index in map(int, order):
        view = PinholeView.from_intrinsics(transforms.frames[index].T_world_camera, transforms.intrinsics_of(index))
        detections = detect_blobs(read_instance_mask(dataset_dir, transforms, index),
                                  source=str(transforms.frames[index].instance_path))
        tracker.update(index, view, detections)
    result = tracker.result()
    result.stats['seconds'] = time.perf_counter() - start
    result.stats['frame_order'] = [int(i) for i in order] if np.any(np.diff(order) != 1) else 'file'
    return result


def write_track_counts(path: str | Path, result: TrackCount, config: TrackConfig | None = None, *,
                       source: str = '') -> Path:
    """Write the ``counts.json`` of a tracking count (atomic)."""
    return atomic_write_text(Path(path), json.dumps(result.to_json(config, source=source), indent=1))
