"""Keyframe selection and persistence: posed images + instance masks become a transforms.json dataset on disk.

The ROS layer (live topics and bag replay alike) turns messages into :class:`Keyframe` records and offers them to
a :class:`KeyframeStore`. The store keeps a frame when the camera moved enough since the last kept one and the
image is sharp, and writes it immediately (so a crash loses nothing collected)::

    RUN_DIR/keyframes/
        frames.jsonl          one line per keyframe, appended once its images are on disk (keyframe_journal.py)
        transforms.json       rewritten atomically: after every keyframe while there are few, then at most every
                              ``index_period_s``, and on flush / snapshot / reset
        images/000000.png     RGB
        instances/000000.png  16-bit instance ids (0 = background)
        semantics/000000.png  fruit = 255
        depths/000000.png     (RGB-D cameras) 16-bit depth in millimetres aligned to the image, 0 = no return

Storing a keyframe costs O(1) however many there are (a journal line, not a rewritten index). A keyframe is
stored whole or not at all: when a write fails (a full disk), its files are removed, the store raises a
:class:`DatasetError` saying so and the keyframes stored before stay intact. Opening a directory resumes it:
``transforms.json`` plus the journal lines it lacks.

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

from fruitnerfpp_ros.core.data.depth_image import DEPTH_PNG_UNIT_M, write_depth_png
from fruitnerfpp_ros.core.data.keyframe_journal import JournalEntry, append_entry, read_entries, trim_torn_tail
from fruitnerfpp_ros.core.data.png_io import write_mask_png, write_rgb_png, write_uint16_png
from fruitnerfpp_ros.core.data.transforms_format import (MASK_SOURCE_KEY, TRANSFORMS_NAME, CameraIntrinsics,
                                                         FrameEntry, TransformsFile, joined_mask_source,
                                                         read_transforms, write_transforms)
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
        depth: [H, W] float32 depth along the optical axis aligned to ``rgb`` (undistorted like it), metres,
            0 = no return; None = no depth for this frame. Stored as ``depth_file_path`` (16-bit millimetres).
    """

    stamp_ns: int
    rgb: np.ndarray
    instance: np.ndarray | Callable[[], np.ndarray]
    T_world_optical: np.ndarray
    intrinsics: CameraIntrinsics
    valid: np.ndarray | None = None
    depth: np.ndarray | None = None


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
    DUPLICATE_STAMP = 'duplicate_stamp'
    """A kept keyframe has the same stamp (a repeated message)."""
    ALREADY_STORED = 'already_stored'
    """Not newer than the newest keyframe of a store opened with ``resume_after_newest`` (a resumed replay)."""


def sharpness_from_image(rgb: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (8-bit scale); low values mean blur."""
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


#: Every PNG ends with its IEND chunk; a file cut by a full disk does not.
_PNG_END = b'IEND\xaeB`\x82'


def _check_complete(paths: list[Path]) -> None:
    """Raise DatasetError for a PNG that does not end with its IEND chunk.

    OpenCV's PNG writer may return success when the disk filled up while its buffer was flushed (a 0-byte or cut
    file); such a file must not become part of a keyframe.
    """
    for path in paths:
        with open(path, 'rb') as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - len(_PNG_END)))
            if f.read() != _PNG_END:
                raise DatasetError(f'cannot write image {path}: the file was cut short ({size} bytes)')


def motion_between(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation in metres, rotation in degrees) between two camera poses."""
    translation = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
    R = T_a[:3, :3].T @ T_b[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return translation, float(angle)


class KeyframeStore:
    """Selects keyframes and persists each one as it arrives (thread-safe).

    Args:
        directory: the dataset directory (created; the keyframes already there, transforms.json plus journal,
            are resumed).
        config: selection thresholds.
        resume_after_newest: reject frames not newer than the newest stored keyframe (``ALREADY_STORED``): a
            replay that reads a bag again from its start continues where it stopped.
        index_period_s: once ``index_every_frame_below`` keyframes are stored, transforms.json is rewritten at
            most this often (the journal holds every keyframe meanwhile).
        index_every_frame_below: rewrite transforms.json after every keyframe while there are fewer.
        mask_source: where the keyframes' instance masks come from (``topic``, ``fallback``...), recorded as
            transforms.json's ``mask_source``; resumed keyframes of another source make it a joined one
            (``fallback+topic``).

    Attributes:
        rejected: frames not kept, per decision.
        write_errors: failed writes (keyframes not stored, transforms.json rewrites deferred).
        last_write_error: the message of the last failed write ('' when none failed).
    """

    def __init__(self, directory: str | Path, config: KeyframeConfig = KeyframeConfig(), *,
                 resume_after_newest: bool = False, index_period_s: float = 2.0,
                 index_every_frame_below: int = 200, mask_source: str | None = None) -> None:
        self.directory = Path(directory)
        self._new_mask_source = mask_source
        self._mask_source = mask_source
        self.config = config
        self.index_period_s = index_period_s
        self.index_every_frame_below = index_every_frame_below
        self._lock = threading.Lock()  # the frame list and counters: held for short updates only
        self._write_lock = threading.RLock()  # one writer at a time: offers (files), index writes, reset
        self._frames: list[FrameEntry] = []
        self._stamps: set[int] = set()
        self._intrinsics: CameraIntrinsics | None = None
        self._last_T: np.ndarray | None = None
        self._index_dirty = False
        self._index_written = 0.0
        self.rejected = {d: 0 for d in KeyframeDecision if d is not KeyframeDecision.ACCEPTED}
        self.write_errors = 0
        self.last_write_error = ''
        self._open()
        self.resume_after_ns = max(self._stamps) if resume_after_newest and self._stamps else None

    def _open(self) -> None:
        for sub in ('images', 'instances', 'semantics', 'masks'):
            (self.directory / sub).mkdir(parents=True, exist_ok=True)
        if (self.directory / TRANSFORMS_NAME).exists():
            try:
                existing = read_transforms(self.directory)
                self._frames = list(existing.frames)
                self._intrinsics = existing.intrinsics
                if self._frames:
                    self._mask_source = joined_mask_source(existing.mask_source, self._new_mask_source)
            except DatasetError:
                pass  # an empty or broken index: the journal holds the frames
        recovered = 0
        trim_torn_tail(self.directory)
        for entry in read_entries(self.directory):
            if entry.index == len(self._frames) and (self.directory / entry.frame.file_path).is_file():
                if self._intrinsics is None:
                    self._intrinsics = entry.intrinsics or entry.frame.intrinsics
                self._frames.append(entry.frame)
                recovered += 1
        if self._frames:
            self._stamps = {f.stamp_ns for f in self._frames if f.stamp_ns is not None}
            self._last_T = optical_from_opengl(self._frames[-1].T_world_camera)
        if recovered:  # frames the index missed (a kill between two index writes): index them now
            self._index_dirty = True
            self._write_index(force=True)

    def __len__(self) -> int:
        with self._lock:
            return len(self._frames)

    @property
    def frames(self) -> list[FrameEntry]:
        """A copy of the kept frames, in arrival order."""
        with self._lock:
            return list(self._frames)

    @property
    def intrinsics(self) -> CameraIntrinsics | None:
        """The keyframes' shared intrinsics (a frame's own ``FrameEntry.intrinsics`` overrides them); None before
        the first keyframe."""
        with self._lock:
            return self._intrinsics

    def offer(self, keyframe: Keyframe) -> KeyframeDecision:
        """Keep ``keyframe`` if it passes the selection; write it to disk at once when kept.

        A segmenter (``keyframe.instance`` callable) runs only for a kept frame. The segmenter and the file writes
        run outside the state lock, so ``len`` and ``frames`` from other threads (diagnostics, services) never wait
        for them; ``snapshot``, ``flush`` and ``reset`` wait for the keyframe being written.
        """
        with self._write_lock:
            with self._lock:
                decision = self._decide(keyframe)
                if decision is not KeyframeDecision.ACCEPTED:
                    self.rejected[decision] += 1
                    return decision
            if callable(keyframe.instance):
                keyframe = keyframe._replace(instance=keyframe.instance())
            self._write(keyframe)
            return decision

    def _decide(self, keyframe: Keyframe) -> KeyframeDecision:
        if self.resume_after_ns is not None and keyframe.stamp_ns <= self.resume_after_ns:
            return KeyframeDecision.ALREADY_STORED
        if int(keyframe.stamp_ns) in self._stamps:
            return KeyframeDecision.DUPLICATE_STAMP
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
        """Store one keyframe whole (images, then a journal line) or not at all (files removed, DatasetError)."""
        index = len(self._frames)  # frames are only ever appended (reset starts a new folder)
        name = f'{index:06d}.png'
        instance = np.asarray(keyframe.instance, dtype=np.uint16)
        paths = [self.directory / sub / name for sub in ('images', 'instances', 'semantics', 'masks', 'depths')]
        partial = keyframe.valid is not None and not bool(np.all(keyframe.valid))
        intrinsics = self._intrinsics or keyframe.intrinsics
        own = None if keyframe.intrinsics == intrinsics else keyframe.intrinsics
        if keyframe.depth is not None and np.shape(keyframe.depth) != keyframe.rgb.shape[:2]:
            (h, w), shape = keyframe.rgb.shape[:2], np.shape(keyframe.depth)
            raise DatasetError(f'keyframe at {keyframe.stamp_ns} ns: depth is {shape[1]}x{shape[0]} but the image '
                               f'is {w}x{h}; depth must be aligned to the colour image')
        entry = FrameEntry(f'images/{name}', opengl_from_optical(keyframe.T_world_optical), f'instances/{name}',
                           f'semantics/{name}', own, int(keyframe.stamp_ns), f'masks/{name}' if partial else None,
                           None if keyframe.depth is None else f'depths/{name}')
        try:
            write_rgb_png(paths[0], keyframe.rgb)
            write_uint16_png(paths[1], instance)
            write_mask_png(paths[2], instance > 0)
            if partial:
                write_mask_png(paths[3], keyframe.valid)
            if keyframe.depth is not None:
                write_depth_png(paths[4], keyframe.depth)
            _check_complete([p for p in paths if p.exists()])  # OpenCV may report a cut file as written
            append_entry(self.directory, JournalEntry(index, entry, intrinsics if index == 0 else None))
        except (OSError, DatasetError) as err:
            for path in paths:
                path.unlink(missing_ok=True)
            self.write_errors += 1
            reason = self._write_failure(err)
            self.last_write_error = (f'{self.directory}: keyframe {index} not stored ({reason}); the {index} '
                                     'keyframe(s) stored before are intact')
            raise DatasetError(self.last_write_error) from err
        with self._lock:
            self._intrinsics = intrinsics
            self._frames.append(entry)
            self._stamps.add(int(keyframe.stamp_ns))
            self._last_T = np.asarray(keyframe.T_world_optical, dtype=np.float64)
        self._index_dirty = True
        self._write_index()

    def _write_failure(self, err: Exception) -> str:
        """Why a write failed, and the room left on the disk (a full disk is the usual cause)."""
        reason = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
        if isinstance(err.__cause__, OSError) and err.__cause__.strerror:
            reason = err.__cause__.strerror
        try:
            reason += f'; {shutil.disk_usage(self.directory).free // 1024} KiB free on its disk'
        except OSError:
            pass
        return reason

    def _write_index(self, *, force: bool = False) -> None:
        """Rewrite transforms.json when due (every keyframe while few, then every ``index_period_s``) or forced.

        A failure is counted (``write_errors``) and retried later: the journal already holds every frame.
        """
        now = time.monotonic()
        due = len(self._frames) < self.index_every_frame_below or now - self._index_written >= self.index_period_s
        if not self._index_dirty or not self._frames or not (due or force):
            return
        try:
            write_transforms(self.directory, self._transforms(self._frames))
        except OSError as err:
            self.write_errors += 1
            self.last_write_error = (f'{self.directory}: cannot rewrite {TRANSFORMS_NAME} '
                                     f'({self._write_failure(err)}); the keyframes are safe in the journal and it '
                                     'is retried')
            return
        self._index_dirty = False
        self._index_written = now

    def flush(self) -> None:
        """Write transforms.json now if keyframes arrived since it was last written."""
        with self._write_lock:
            self._write_index(force=True)

    def _transforms(self, frames: list[FrameEntry]) -> TransformsFile:
        depth_unit = DEPTH_PNG_UNIT_M if any(f.depth_path for f in frames) else None
        extra: dict[str, str] = {'generator': 'fruitnerfpp_ros keyframes'}
        if self._mask_source:
            extra[MASK_SOURCE_KEY] = self._mask_source
        return TransformsFile(self._intrinsics, frames, extra=extra, depth_unit_scale_factor=depth_unit)

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
        with self._write_lock:  # no keyframe is being added meanwhile
            self._write_index(force=True)
            if not self._frames:
                raise DatasetError(f'{self.directory}: no keyframes collected yet')
            prefix = Path(os.path.relpath(self.directory, dataset_dir))
            frames = [FrameEntry(str(prefix / f.file_path), f.T_world_camera,
                                 str(prefix / f.instance_path) if f.instance_path else None,
                                 str(prefix / f.semantic_path) if f.semantic_path else None,
                                 f.intrinsics, f.stamp_ns, str(prefix / f.mask_path) if f.mask_path else None,
                                 str(prefix / f.depth_path) if f.depth_path else None)
                      for f in self._frames]
            write_transforms(dataset_dir, self._transforms(frames))
            latest = max(f.stamp_ns or 0 for f in self._frames)
        return KeyframeSnapshot(dataset_dir, len(frames), latest)

    def reset(self) -> Path | None:
        """Start a new collection; the old keyframes are moved aside (``keyframes_reset_<unix time>``), not lost.

        Returns:
            where the old keyframes went, or None when there were none.
        """
        with self._write_lock, self._lock:
            moved = None
            if self._frames:
                self._write_index(force=True)
                moved = self.directory.with_name(f'{self.directory.name}_reset_{time.time_ns()}')
                shutil.move(str(self.directory), str(moved))
            self._frames = []
            self._stamps = set()
            self._intrinsics = None
            self._last_T = None
            self._mask_source = self._new_mask_source
            self.resume_after_ns = None
            self.rejected = {d: 0 for d in self.rejected}
            self._open()
            return moved
