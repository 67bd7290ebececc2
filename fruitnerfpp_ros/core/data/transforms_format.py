"""The transforms.json dataset format (nerfstudio convention plus per-frame instance/semantic masks).

Layout of a dataset directory::

    transforms.json           # this module reads and writes it
    images/0000.png           # RGB
    instances/0000.png        # 16-bit instance ids, 0 = background, k = fruit k (per-image labels)
    semantics/0000.png        # fruit = 255, rest = 0 (optional: derived from instances when absent)
    masks/0000.png            # optional pixel mask (``mask_path``, 0 = no data), e.g. an undistorted frame's border
    depths/0000.png           # optional depth aligned to the image (``depth_file_path``): 16-bit, z along the optical
                              # axis in units of ``depth_unit_scale_factor`` metres (default 0.001: millimetres);
                              # 0 = no return. A float image (e.g. 32-bit TIFF) is read in the same unit.
    gt_fruits.json            # optional ground truth (synthetic data)
    sparse_pc.ply             # optional sparse geometry (``ply_file_path``), used for scene bounds

``transform_matrix`` is camera-to-world with OpenGL camera axes (x right, y up, z back); ``cx, cy`` put the
image's top-left corner at (0, 0). Intrinsics are global keys, and a frame may override them with its own
``fl_x, fl_y, cx, cy, w, h`` keys (as nerfstudio allows). Paths are relative to the dataset directory.

The top-level ``mask_source`` key says where the instance masks came from (:data:`MASK_SOURCE_KEY`): the
segmenter's method (``fallback``, ``torchscript``, ``sam``), ``topic`` (a node's mask topic), ``ground_truth``
(``fruitnerfpp synth``); several joined by ``+`` when a collection mixes them; absent when unknown.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['CameraIntrinsics', 'FrameEntry', 'TransformsFile', 'read_transforms', 'write_transforms',
           'TRANSFORMS_NAME', 'DEFAULT_DEPTH_UNIT_M', 'depth_path_of', 'MASK_SOURCE_KEY', 'joined_mask_source']

TRANSFORMS_NAME = 'transforms.json'
#: Metres per stored depth unit when transforms.json gives no ``depth_unit_scale_factor`` (nerfstudio's default:
#: millimetres, as RealSense / ZED / OAK-D 16UC1 depth images hold them).
DEFAULT_DEPTH_UNIT_M = 1e-3
#: Frame keys naming a depth image: nerfstudio's ``depth_file_path`` (written) and ``depth_path`` (read too).
_DEPTH_KEYS = ('depth_file_path', 'depth_path')
#: Top-level key naming where the instance masks came from (module doc).
MASK_SOURCE_KEY = 'mask_source'
_INTRINSIC_KEYS = ('fl_x', 'fl_y', 'cx', 'cy', 'w', 'h')
_DISTORTION_KEYS = ('k1', 'k2', 'k3', 'k4', 'p1', 'p2')


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels, principal point with the top-left image corner at (0, 0).

    ``distortion``: nerfstudio's coefficient keys (k1, k2, k3, k4, p1, p2) when the images are distorted;
    :func:`fruitnerfpp_ros.core.data.dataset.load_dataset` undoes the distortion (core/data/undistortion.py).
    """

    fl_x: float
    fl_y: float
    cx: float
    cy: float
    w: int
    h: int
    distortion: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {'fl_x': self.fl_x, 'fl_y': self.fl_y, 'cx': self.cx, 'cy': self.cy,
                               'w': int(self.w), 'h': int(self.h)}
        out.update({k: float(v) for k, v in self.distortion.items()})
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any], where: str) -> 'CameraIntrinsics':
        missing = [k for k in _INTRINSIC_KEYS if k not in data]
        if missing:
            raise DatasetError(f'{where}: missing intrinsic key(s) {", ".join(missing)}')
        try:
            values = {k: float(data[k]) for k in _INTRINSIC_KEYS}
            distortion = {k: float(data[k]) for k in _DISTORTION_KEYS if k in data}
        except (TypeError, ValueError) as err:
            raise DatasetError(f'{where}: non-numeric intrinsics: {err}') from err
        if not all(np.isfinite(list(values.values()))) or values['w'] <= 0 or values['h'] <= 0:
            raise DatasetError(f'{where}: invalid intrinsics {values}')
        return cls(values['fl_x'], values['fl_y'], values['cx'], values['cy'], int(values['w']),
                   int(values['h']), distortion)


@dataclass(frozen=True)
class FrameEntry:
    """One frame of a transforms.json.

    Attributes:
        file_path: RGB image path, relative to the dataset directory.
        T_world_camera: 4x4 camera-to-world transform, OpenGL camera axes, metres.
        instance_path: 16-bit instance-id PNG (0 = background), relative path, or None.
        semantic_path: fruit mask PNG (255 = fruit), relative path, or None.
        intrinsics: per-frame intrinsics overriding the global ones, or None.
        stamp_ns: acquisition time in nanoseconds (ROS keyframes), or None.
        mask_path: nerfstudio's pixel mask (0 = no data: never trained on or evaluated), relative path, or None.
        depth_path: depth image aligned to the RGB image (``depth_file_path``), relative path, or None.
    """

    file_path: str
    T_world_camera: np.ndarray
    instance_path: str | None = None
    semantic_path: str | None = None
    intrinsics: CameraIntrinsics | None = None
    stamp_ns: int | None = None
    mask_path: str | None = None
    depth_path: str | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {'file_path': self.file_path,
                               'transform_matrix': np.asarray(self.T_world_camera, dtype=float).tolist()}
        if self.instance_path is not None:
            out['instance_path'] = self.instance_path
        if self.semantic_path is not None:
            out['semantic_path'] = self.semantic_path
        if self.intrinsics is not None:
            out.update(self.intrinsics.to_json())
        if self.stamp_ns is not None:
            out['stamp_ns'] = int(self.stamp_ns)
        if self.mask_path is not None:
            out['mask_path'] = self.mask_path
        if self.depth_path is not None:
            out['depth_file_path'] = self.depth_path
        return out


def joined_mask_source(*sources: str | None) -> str | None:
    """One ``mask_source`` value for masks of several sources: the distinct known ones, sorted, joined by ``+``
    (``'fallback+topic'``); None when none is known."""
    parts = sorted({p for s in sources if s for p in str(s).split('+') if p})
    return '+'.join(parts) if parts else None


def depth_path_of(raw: dict[str, Any]) -> str | None:
    """The depth image a raw transforms.json frame names (``depth_file_path`` or ``depth_path``), or None."""
    for key in _DEPTH_KEYS:
        if raw.get(key):
            return str(raw[key])
    return None


@dataclass
class TransformsFile:
    """The content of a transforms.json.

    Attributes:
        intrinsics: global intrinsics, or None when every frame has its own.
        frames: frames in file order.
        ply_file_path: optional sparse point cloud (relative path) for scene bounds.
        extra: other top-level keys, kept as they are (e.g. ``fruit_types``, ``generator``).
        depth_unit_scale_factor: metres per unit of the depth images (``depth_unit_scale_factor``, written when
            set); None = :data:`DEFAULT_DEPTH_UNIT_M`.
    """

    intrinsics: CameraIntrinsics | None
    frames: list[FrameEntry]
    ply_file_path: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    depth_unit_scale_factor: float | None = None

    @property
    def mask_source(self) -> str | None:
        """Where the instance masks came from (``mask_source``, module doc), or None when unknown."""
        value = self.extra.get(MASK_SOURCE_KEY)
        return str(value) if value else None

    @property
    def depth_unit_m(self) -> float:
        """Metres per stored depth unit."""
        return DEFAULT_DEPTH_UNIT_M if self.depth_unit_scale_factor is None else self.depth_unit_scale_factor

    def intrinsics_of(self, index: int) -> CameraIntrinsics:
        """Intrinsics of frame ``index`` (its own, else the global ones)."""
        own = self.frames[index].intrinsics
        if own is not None:
            return own
        if self.intrinsics is None:
            raise DatasetError(f'frame {index} ({self.frames[index].file_path}) has no intrinsics')
        return self.intrinsics

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.extra)
        if self.intrinsics is not None:
            out.update(self.intrinsics.to_json())
        if self.ply_file_path is not None:
            out['ply_file_path'] = self.ply_file_path
        if self.depth_unit_scale_factor is not None:
            out['depth_unit_scale_factor'] = float(self.depth_unit_scale_factor)
        out['frames'] = [f.to_json() for f in self.frames]
        return out


def read_transforms(dataset_dir: str | Path) -> TransformsFile:
    """Parse ``dataset_dir/transforms.json`` (does not open images).

    Raises:
        DatasetError: the file is missing, not JSON, has no frames, or a frame is malformed (NaN pose...).
    """
    path = Path(dataset_dir) / TRANSFORMS_NAME
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError as err:
        raise DatasetError(f'{path}: not found (expected a nerfstudio-style transforms.json)') from err
    except json.JSONDecodeError as err:
        raise DatasetError(f'{path}: not valid JSON: {err}') from err
    if not isinstance(data, dict) or not isinstance(data.get('frames'), list):
        raise DatasetError(f'{path}: expected an object with a "frames" list')
    if not data['frames']:
        raise DatasetError(f'{path}: the dataset has no frames')
    has_global = all(k in data for k in _INTRINSIC_KEYS)
    intrinsics = CameraIntrinsics.from_json(data, str(path)) if has_global else None
    frames = []
    for i, raw in enumerate(data['frames']):
        where = f'{path} frame {i}'
        if not isinstance(raw, dict) or 'file_path' not in raw or 'transform_matrix' not in raw:
            raise DatasetError(f'{where}: needs "file_path" and "transform_matrix"')
        try:
            T = np.asarray(raw['transform_matrix'], dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise DatasetError(f'{where} ({raw["file_path"]}): transform_matrix is not numeric') from err
        if T.shape == (3, 4):
            T = np.vstack([T, [0.0, 0.0, 0.0, 1.0]])
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DatasetError(f'{where} ({raw["file_path"]}): transform_matrix must be a finite 4x4 matrix')
        own = CameraIntrinsics.from_json(raw, where) if any(k in raw for k in _INTRINSIC_KEYS) else None
        if own is None and intrinsics is None:
            raise DatasetError(f'{where} ({raw["file_path"]}): no intrinsics (neither global nor per frame)')
        frames.append(FrameEntry(str(raw['file_path']), T, raw.get('instance_path'), raw.get('semantic_path'),
                                 own, raw.get('stamp_ns'), raw.get('mask_path'), depth_path_of(raw)))
    known = set(_INTRINSIC_KEYS) | set(_DISTORTION_KEYS) | {'frames', 'ply_file_path', 'depth_unit_scale_factor'}
    extra = {k: v for k, v in data.items() if k not in known}
    return TransformsFile(intrinsics, frames, data.get('ply_file_path'), extra, _depth_unit(data, path))


def _depth_unit(data: dict[str, Any], path: Path) -> float | None:
    """``depth_unit_scale_factor`` of a transforms.json (metres per depth unit), checked; None when absent."""
    value = data.get('depth_unit_scale_factor')
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < float(value) < 1e3:
        raise DatasetError(f'{path}: depth_unit_scale_factor must be a positive number of metres per depth unit '
                           f'(0.001 for millimetres), got {value!r}')
    return float(value)


def write_transforms(dataset_dir: str | Path, transforms: TransformsFile) -> Path:
    """Write ``dataset_dir/transforms.json`` atomically (write a temp file, then rename); returns its path."""
    return atomic_write_text(Path(dataset_dir) / TRANSFORMS_NAME, json.dumps(transforms.to_json(), indent=1),
                             fsync=True)
