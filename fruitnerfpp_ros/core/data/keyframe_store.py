"""Keyframe selection and persistence: posed images + instance masks become a transforms.json dataset on disk.

The ROS layer (live topics and bag replay alike) turns messages into :class:`Keyframe` records and offers them to
a :class:`KeyframeStore`. The store keeps a frame when the camera moved enough since the last kept one and the
image is sharp, and writes it immediately (so a crash loses nothing collected)::

    RUN_DIR/keyframes/
        transforms.json       rewritten atomically after every keyframe
        images/000000.png     RGB
        instances/000000.png  16-bit instance ids (0 = background)
        semantics/000000.png  fruit = 255

The directory is a dataset that ``fruitnerfpp train`` reads. :meth:`KeyframeStore.snapshot` writes a frozen
transforms.json elsewhere (pointing at the same image files) so training sees a fixed frame list while new
keyframes keep arriving.
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Callable, NamedTuple

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.png_io import write_mask_png, write_rgb_png, write_uint16_png
from fruitnerfpp_ros.core.data.transforms_format import (TRANSFORMS_NAME, CameraIntrinsics, FrameEntry,
                                                         TransformsFile, read_transforms, write_transforms)
from fruitnerfpp_ros.core.geometry import opengl_from_optical, optical_from_opengl
from fruitnerfpp_ros.errors import ConfigError, DatasetError

__all__ = ['KeyframeConfig', 'Keyframe', 'KeyframeDecision', 'KeyframeSnapshot', 'KeyframeStore',
           'sharpness_from_image', 'motion_between']


@dataclass(frozen=True)
class KeyframeConfig:
    """Keyframe selection.

    Attributes:
        min_translation_m: keep a frame when the camera moved at least this far (metres) since the last keyframe...
        min_rotation_deg: ...or turned at least this much (degrees).
        max_keyframes: stop collecting after this many keyframes (further frames are counted as rejected).
        blur_threshold: reject frames whose sharpness (variance of the Laplacian of the grey image, 8-bit scale)
            is below this; 0 disables blur rejection.
    """

    min_translation_m: float = 0.05
    min_rotation_deg: float = 5.0
    max_keyframes: int = 300
    blur_threshold: float = 0.0

    def __post_init__(self) -> None:
        if self.min_translation_m < 0 or self.min_rotation_deg < 0 or self.blur_threshold < 0:
            raise ConfigError('keyframe thresholds must be >= 0')
        if self.max_keyframes < 1:
            raise ConfigError(f'max_keyframes must be >= 1, got {self.max_keyframes}')


class Keyframe(NamedTuple):
    """One synchronised, undistorted camera frame.

    Attributes:
        stamp_ns: header stamp in nanoseconds.
        rgb: [H, W, 3] uint8 image.
        instance: [H, W] uint16 instance ids (0 = background), or a function computing them (a segmenter), which
            the store calls only for a frame it keeps.
        T_world_optical: 4x4 camera-to-world transform, ROS optical axes (z forward, x right, y down), metres.
        intrinsics: pinhole intrinsics in the transforms.json convention (top-left image corner at 0, 0).
        valid: [H, W] bool, False on pixels without data (the border of an undistorted image); None = all valid.
            Stored as the frame's ``mask_path`` (nerfstudio's pixel mask), so training never samples them.
    """

    stamp_ns: int
    rgb: np.ndarray
    instance: np.ndarray | Callable[[], np.ndarray]
    T_world_optical: np.ndarray
    intrinsics: CameraIntrinsics
    valid: np.ndarray | None = None


class KeyframeSnapshot(NamedTuple):
    """A frozen dataset of the keyframes collected so far (see :meth:`KeyframeStore.snapshot`).

    Attributes:
        dataset_dir: the folder holding its transforms.json.
        n_keyframes: keyframes in it.
        latest_stamp_ns: newest keyframe stamp (0 when none has one).
    """

    dataset_dir: Path
    n_keyframes: int
    latest_stamp_ns: int


class KeyframeDecision(str, Enum):
    """What the store did with an offered frame."""

    ACCEPTED = 'accepted'
    TOO_CLOSE = 'too_close'
    BLURRY = 'blurry'
    FULL = 'full'


def sharpness_from_image(rgb: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (8-bit scale); low values mean blur."""
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def motion_between(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation in metres, rotation in degrees) between two camera poses."""
    translation = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
    R = T_a[:3, :3].T @ T_b[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return translation, float(angle)


class KeyframeStore:
    """Selects keyframes and persists each one as it arrives (thread-safe).

    Args:
        directory: the dataset directory (created; an existing transforms.json there is resumed).
        config: selection thresholds.
    """

    def __init__(self, directory: str | Path, config: KeyframeConfig = KeyframeConfig()) -> None:
        self.directory = Path(directory)
        self.config = config
        self._lock = threading.Lock()
        self._frames: list[FrameEntry] = []
        self._intrinsics: CameraIntrinsics | None = None
        self._last_T: np.ndarray | None = None
        self.rejected = {d: 0 for d in KeyframeDecision if d is not KeyframeDecision.ACCEPTED}
        self._open()

    def _open(self) -> None:
        for sub in ('images', 'instances', 'semantics', 'masks'):
            (self.directory / sub).mkdir(parents=True, exist_ok=True)
        if (self.directory / TRANSFORMS_NAME).exists():
            try:
                existing = read_transforms(self.directory)
            except DatasetError:
                return  # an empty or broken file: start over (it is rewritten on the next keyframe)
            self._frames = list(existing.frames)
            self._intrinsics = existing.intrinsics
            self._last_T = optical_from_opengl(self._frames[-1].T_world_camera)

    def __len__(self) -> int:
        with self._lock:
            return len(self._frames)

    @property
    def frames(self) -> list[FrameEntry]:
        """A copy of the kept frames, in arrival order."""
        with self._lock:
            return list(self._frames)

    def offer(self, keyframe: Keyframe) -> KeyframeDecision:
        """Keep ``keyframe`` if it passes the selection; write it to disk at once when kept.

        A segmenter (``keyframe.instance`` callable) runs only for a kept frame, and outside the store's lock, so
        ``len``, ``frames`` and ``snapshot`` from other threads never wait for a model.
        """
        if callable(keyframe.instance):
            with self._lock:
                decision = self._decide(keyframe)
            if decision is not KeyframeDecision.ACCEPTED:
                with self._lock:
                    self.rejected[decision] += 1
                return decision
            keyframe = keyframe._replace(instance=keyframe.instance())
        with self._lock:
            decision = self._decide(keyframe)  # again: the store may have changed while the segmenter ran
            if decision is not KeyframeDecision.ACCEPTED:
                self.rejected[decision] += 1
                return decision
            self._write(keyframe)
            return decision

    def _decide(self, keyframe: Keyframe) -> KeyframeDecision:
        if len(self._frames) >= self.config.max_keyframes:
            return KeyframeDecision.FULL
        if self._last_T is not None:
            translation, rotation = motion_between(self._last_T, keyframe.T_world_optical)
            if translation < self.config.min_translation_m and rotation < self.config.min_rotation_deg:
                return KeyframeDecision.TOO_CLOSE
        if self.config.blur_threshold > 0 and sharpness_from_image(keyframe.rgb) < self.config.blur_threshold:
            return KeyframeDecision.BLURRY
        return KeyframeDecision.ACCEPTED

    def _write(self, keyframe: Keyframe) -> None:
        name = f'{len(self._frames):06d}.png'  # frames are only ever appended (reset starts a new folder)
        instance = np.asarray(keyframe.instance, dtype=np.uint16)
        write_rgb_png(self.directory / 'images' / name, keyframe.rgb)
        write_uint16_png(self.directory / 'instances' / name, instance)
        write_mask_png(self.directory / 'semantics' / name, instance > 0)
        mask_path = None
        if keyframe.valid is not None and not bool(np.all(keyframe.valid)):
            write_mask_png(self.directory / 'masks' / name, keyframe.valid)
            mask_path = f'masks/{name}'
        if self._intrinsics is None:
            self._intrinsics = keyframe.intrinsics
        own = None if keyframe.intrinsics == self._intrinsics else keyframe.intrinsics
        self._frames.append(FrameEntry(f'images/{name}', opengl_from_optical(keyframe.T_world_optical),
                                       f'instances/{name}', f'semantics/{name}', own, int(keyframe.stamp_ns),
                                       mask_path))
        self._last_T = np.asarray(keyframe.T_world_optical, dtype=np.float64)
        write_transforms(self.directory, self._transforms(self._frames))

    def _transforms(self, frames: list[FrameEntry]) -> TransformsFile:
        return TransformsFile(self._intrinsics, frames, extra={'generator': 'fruitnerfpp_ros keyframes'})

    def snapshot(self, dataset_dir: str | Path) -> KeyframeSnapshot:
        """Write a frozen transforms.json in ``dataset_dir`` that points at the current keyframes' files.

        Returns:
            The snapshot: a dataset the trainer can read while this store keeps growing, with the count and newest
            stamp of exactly the keyframes it holds.

        Raises:
            DatasetError: when no keyframe has been collected.
        """
        dataset_dir = Path(dataset_dir)
        dataset_dir.mkdir(parents=True, exist_ok=True)
        with self._lock:
            if not self._frames:
                raise DatasetError(f'{self.directory}: no keyframes collected yet')
            prefix = Path(os.path.relpath(self.directory, dataset_dir))
            frames = [FrameEntry(str(prefix / f.file_path), f.T_world_camera,
                                 str(prefix / f.instance_path) if f.instance_path else None,
                                 str(prefix / f.semantic_path) if f.semantic_path else None,
                                 f.intrinsics, f.stamp_ns, str(prefix / f.mask_path) if f.mask_path else None)
                      for f in self._frames]
            write_transforms(dataset_dir, self._transforms(frames))
            latest = max(f.stamp_ns or 0 for f in self._frames)
        return KeyframeSnapshot(dataset_dir, len(frames), latest)

    def reset(self) -> Path | None:
        """Start a new collection; the old keyframes are moved aside (``keyframes_reset_<unix time>``), not lost.

        Returns:
            where the old keyframes went, or None when there were none.
        """
        with self._lock:
            moved = None
            if self._frames:
                moved = self.directory.with_name(f'{self.directory.name}_reset_{time.time_ns()}')
                shutil.move(str(self.directory), str(moved))
            self._frames = []
            self._intrinsics = None
            self._last_T = None
            self.rejected = {d: 0 for d in self.rejected}
            self._open()
            return moved
