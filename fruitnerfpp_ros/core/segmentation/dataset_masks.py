"""Segment every image of a transforms.json dataset and record the masks in it (what ``fruitnerfpp segment`` runs).

For frame ``images/0007.png`` the masks go to ``instances/0007.png`` (16-bit ids, 0 = background) and
``semantics/0007.png`` (8-bit, fruit = 255); the frame's ``instance_path`` / ``semantic_path`` are set and
transforms.json is rewritten atomically once every image is done (an interrupted run leaves it unchanged), with
the segmenter's ``method`` as its ``mask_source`` (what the count's masks step checks: core/clustering/
mask_check.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath
from typing import Callable

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.png_io import write_mask_png, write_uint16_png
from fruitnerfpp_ros.core.data.transforms_format import MASK_SOURCE_KEY, FrameEntry, TransformsFile, \
    read_transforms, write_transforms
from fruitnerfpp_ros.core.progress import Phase, ProgressCallback, ProgressEvent, ignore_progress
from fruitnerfpp_ros.core.segmentation.segmenter import Segmenter, segment
from fruitnerfpp_ros.errors import DatasetError, SegmentationError

__all__ = ['SegmentationSummary', 'mask_paths_for', 'check_no_masks', 'segment_dataset', 'record_instances']


@dataclass(frozen=True)
class SegmentationSummary:
    """What :func:`segment_dataset` did.

    Attributes:
        dataset_dir: the dataset.
        n_frames: images segmented.
        n_instances: instances found, summed over the images.
        empty_frames: images without any instance.
        seconds: wall time of the segmentation and writing.
    """

    dataset_dir: Path
    n_frames: int
    n_instances: int
    empty_frames: int
    seconds: float


def mask_paths_for(file_path: str) -> tuple[str, str]:
    """(instance, semantic) PNG paths, relative to the dataset, for the image ``file_path``.

    ``images/a/b.jpg`` -> ``instances/a/b.png``, ``semantics/a/b.png``; an image outside ``images/`` keeps its
    whole relative path under ``instances/`` and ``semantics/``.
    """
    parts = PurePosixPath(file_path.replace('\\', '/')).parts
    parts = tuple(p for p in parts if p not in ('.', ''))
    if parts and parts[0] == 'images' and len(parts) > 1:
        parts = parts[1:]
    if not parts or '..' in parts:
        raise DatasetError(f'image path {file_path!r}: cannot place its masks inside the dataset')
    rel = PurePosixPath(*parts).with_suffix('.png')
    return str(PurePosixPath('instances') / rel), str(PurePosixPath('semantics') / rel)


def _read_rgb8(path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DatasetError(f'{path}: image not found or not decodable')
    return np.ascontiguousarray(bgr[..., ::-1])


def _targets(dataset_dir: Path, transforms: TransformsFile) -> list[tuple[str, str]]:
    targets = [mask_paths_for(frame.file_path) for frame in transforms.frames]
    seen: dict[str, str] = {}
    for frame, (instance_path, _) in zip(transforms.frames, targets):
        if instance_path in seen:
            raise DatasetError(f'{dataset_dir}: images {seen[instance_path]} and {frame.file_path} would share the '
                               f'mask file {instance_path}; rename one of them')
        seen[instance_path] = frame.file_path
    return targets


def check_no_masks(dataset_dir: str | Path, transforms: TransformsFile | None = None) -> None:
    """Refuse a dataset whose frames' masks exist (the files they name, or the files the new masks would go to).

    A frame that names a mask file which does not exist (masks deleted, a dataset copied without them) counts as
    having none: its masks are made.

    Raises:
        SegmentationError: naming how many frames have masks and the first one.
        DatasetError: a malformed transforms.json.
    """
    dataset_dir = Path(dataset_dir)
    transforms = transforms if transforms is not None else read_transforms(dataset_dir)

    def exists(path: str | None) -> bool:
        return path is not None and (dataset_dir / path).exists()

    taken = [(frame.file_path, frame.instance_path if exists(frame.instance_path) else instance_path)
             for frame, (instance_path, semantic_path) in zip(transforms.frames, _targets(dataset_dir, transforms))
             if any(exists(p) for p in (frame.instance_path, frame.semantic_path, instance_path, semantic_path))]
    if taken:
        raise SegmentationError(f'{dataset_dir}: {len(taken)} of {len(transforms.frames)} frames already have '
                                f'instance masks (first: {taken[0][0]} -> {taken[0][1]}); pass --overwrite '
                                '(overwrite=True) to replace them')


def segment_dataset(dataset_dir: str | Path, segmenter: Segmenter, *, overwrite: bool = False,
                    progress: ProgressCallback = ignore_progress,
                    mask_source: str | None = None) -> SegmentationSummary:
    """Segment every frame's image with ``segmenter``, write its masks and record them in transforms.json.

    Args:
        dataset_dir: directory holding transforms.json.
        segmenter: ``rgb [H, W, 3] uint8 -> ids [H, W] uint16``.
        overwrite: replace masks that frames already name, or that exist where the new ones would go.
        progress: called after each image (phase ``segment``).
        mask_source: recorded as transforms.json's ``mask_source`` (default: the segmenter's ``method``; a
            segmenter without one leaves the key out).

    Raises:
        DatasetError: a malformed transforms.json, an unreadable image, two images whose masks would share a file.
        SegmentationError: masks exist and ``overwrite`` is False, or the segmenter fails or returns a wrong shape.
    """
    start = time.perf_counter()
    dataset_dir = Path(dataset_dir)
    transforms = read_transforms(dataset_dir)
    if not overwrite:
        check_no_masks(dataset_dir, transforms)

    def ids_of(frame: FrameEntry) -> np.ndarray:
        return segment(segmenter, _read_rgb8(dataset_dir / frame.file_path), frame.file_path)

    return record_instances(dataset_dir, transforms, ids_of, semantics=True, progress=progress, started=start,
                            mask_source=mask_source or getattr(segmenter, 'method', None))


def record_instances(dataset_dir: Path, transforms: TransformsFile, ids_of: Callable[[FrameEntry], np.ndarray], *,
                     semantics: bool, mask_source: str | None, progress: ProgressCallback = ignore_progress,
                     started: float | None = None) -> SegmentationSummary:
    """Write each frame's instance ids ``ids_of(frame)`` to ``instances/`` (with ``semantics``, the fruit mask
    to ``semantics/`` too), name them in its frame and rewrite transforms.json once at the end with ``mask_source``
    (None: the key left out; the old masks' source no longer holds).

    Raises:
        DatasetError: two images whose masks would share a file; what ``ids_of`` raises.
    """
    started = time.perf_counter() if started is None else started
    frames = transforms.frames
    new_frames, n_instances, empty = [], 0, 0
    for index, (frame, (instance_path, semantic_path)) in enumerate(zip(frames, _targets(dataset_dir, transforms))):
        ids = ids_of(frame)
        write_uint16_png(dataset_dir / instance_path, ids)
        if semantics:
            write_mask_png(dataset_dir / semantic_path, ids > 0)
        k = int(ids.max()) if ids.size else 0
        n_instances += k
        empty += int(k == 0)
        new_frames.append(replace(frame, instance_path=instance_path,
                                  semantic_path=semantic_path if semantics else frame.semantic_path))
        progress(ProgressEvent(Phase.SEGMENT, index + 1, len(frames), f'{k} fruits'))
    transforms.frames = new_frames
    transforms.extra.pop(MASK_SOURCE_KEY, None)
    if mask_source:
        transforms.extra[MASK_SOURCE_KEY] = str(mask_source)
    write_transforms(dataset_dir, transforms)
    return SegmentationSummary(dataset_dir, len(frames), n_instances, empty, time.perf_counter() - started)
