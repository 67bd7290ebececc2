"""Load a transforms.json dataset (images, instance/semantic masks, intrinsics, poses) into tensors.

Instance ids are per-image labels (0 = background): nothing here assumes the same fruit has the same id in two
views. Semantic masks are read when the frames name them, else derived from the instance masks (fruit = id > 0).

Distorted cameras (``k1``... in transforms.json, ``camera_model`` OPENCV or OPENCV_FISHEYE) are undistorted here,
keeping their camera matrix; pixels that then hold no data, and pixels a frame's ``mask_path`` marks 0, are
invalid: ``SceneDataset.valid_masks`` marks them, and the masks hold no fruit there.

Depth (optional, per frame ``depth_file_path``): an image aligned to the RGB image, z along the optical axis in
units of ``depth_unit_scale_factor`` metres; 0, NaN and negative values are no return. It goes through the same
undistortion as the masks (nearest neighbour: depths never blend across an edge) and is 0 on invalid pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, TransformsFile, read_transforms
from fruitnerfpp_ros.core.data.undistortion import LensUndistorter
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['SceneDataset', 'load_dataset', 'split_indices']


@dataclass(frozen=True)
class SceneDataset:
    """All views of a dataset, on the CPU.

    Attributes:
        dataset_dir: the directory holding ``transforms.json``.
        images: [V, H, W, 3] float32 RGB in [0, 1].
        instance_masks: [V, H, W] int32 per-image instance ids, 0 = background.
        semantic_masks: [V, H, W] bool, True on fruit pixels.
        intrinsics: [V, 4] float32 (fl_x, fl_y, cx, cy) in pixels, top-left image corner at (0, 0).
        T_world_camera: [V, 4, 4] float32 camera-to-world poses, OpenGL camera axes, metres.
        train_indices: [V_train] int64 view indices used for training.
        eval_indices: [V_eval] int64 held-out view indices.
        ply_path: the sparse point cloud named by ``ply_file_path`` when it exists, else None.
        file_paths: the V images as transforms.json names them.
        valid_masks: [V, H, W] bool, False where a pixel holds no data (an undistorted image's border, a frame's
            ``mask_path``); None when every pixel is valid.
        depths: [V, H, W] float32 depth along the optical axis, metres, 0 = no return (and for views without a
            depth image); None when no frame has one.
        mask_source: where the instance masks came from (transforms.json's ``mask_source``: ``fallback``,
            ``topic``, ``ground_truth``...), None when it does not say.
    """

    dataset_dir: Path
    images: torch.Tensor
    instance_masks: torch.Tensor
    semantic_masks: torch.Tensor
    intrinsics: torch.Tensor
    T_world_camera: torch.Tensor
    train_indices: torch.Tensor
    eval_indices: torch.Tensor
    ply_path: Path | None
    file_paths: tuple[str, ...] = ()
    valid_masks: torch.Tensor | None = None
    depths: torch.Tensor | None = None
    mask_source: str | None = None

    @property
    def num_views(self) -> int:
        return int(self.images.shape[0])

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])


def split_indices(num_views: int, eval_every: int) -> tuple[np.ndarray, np.ndarray]:
    """Train / held-out view indices: every ``eval_every``-th view (0, n, 2n...) is held out; 0 disables it.

    With fewer than two views nothing is held out.
    """
    index = np.arange(num_views)
    if eval_every <= 0 or num_views < 2:
        return index, index[:0]
    held = index % eval_every == 0
    return index[~held], index[held]


def _read_image(path: Path, *, flags: int, what: str) -> np.ndarray:
    if not path.is_file():
        raise DatasetError(f'{path}: {what} not found')
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DatasetError(f'{path}: cannot decode {what}')
    return image


def _read_rgb(path: Path) -> np.ndarray:
    image = _read_image(path, flags=cv2.IMREAD_UNCHANGED, what='image')
    scale = 65535.0 if image.dtype == np.uint16 else 255.0
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    if image.shape[2] == 4:  # composite on white, as nerfstudio does for RGBA
        alpha = image[..., 3:4].astype(np.float32) / scale
        rgb = image[..., 2::-1].astype(np.float32) / scale
        return rgb * alpha + (1.0 - alpha)
    return image[..., 2::-1].astype(np.float32) / scale


def _read_depth(path: Path, unit_m: float, size: tuple[int, int], image_path: Path) -> np.ndarray:
    """[H, W] float32 metres of a depth image (16-bit or float, ``unit_m`` metres per unit); 0 = no return."""
    raw = _read_image(path, flags=cv2.IMREAD_UNCHANGED, what='depth image')
    if raw.ndim != 2 or raw.dtype not in (np.uint16, np.float32, np.float64):
        channels = 1 if raw.ndim == 2 else raw.shape[2]
        raise DatasetError(f'{path}: depth image is {channels}-channel {raw.dtype}; expected one channel of 16-bit '
                           'integers (e.g. millimetres) or floats')
    if raw.shape != size:
        raise DatasetError(f'{path}: depth image is {raw.shape[1]}x{raw.shape[0]} but image {image_path} is '
                           f'{size[1]}x{size[0]}; depth must be aligned to the colour image (same size and camera)')
    metres = raw.astype(np.float32) * np.float32(unit_m)
    return np.where(np.isfinite(metres) & (metres > 0), metres, np.float32(0.0))


def _read_label_mask(path: Path, what: str) -> np.ndarray:
    """[H, W] int32 labels of a mask image: a grey one as stored; a colour-coded one (an id per colour, as
    annotation tools export them) numbered by colour, black = 0 (alpha ignored)."""
    mask = _read_image(path, flags=cv2.IMREAD_UNCHANGED, what=what)
    if mask.ndim == 3:
        colour = mask[..., :3]
        if (colour == colour[..., :1]).all():  # grey stored in three channels
            return colour[..., 0].astype(np.int32)
        packed = (colour[..., 0].astype(np.int64) << 32) | (colour[..., 1].astype(np.int64) << 16) | colour[..., 2]
        values, labels = np.unique(packed, return_inverse=True)
        return (labels.reshape(packed.shape) + int(values[0] != 0)).astype(np.int32)
    return mask.astype(np.int32)


_CAMERA_MODELS = {'OPENCV': 'plumb_bob', 'PINHOLE': 'plumb_bob', 'SIMPLE_PINHOLE': 'plumb_bob',
                  'OPENCV_FISHEYE': 'equidistant'}


class _Undistorters:
    """One :class:`LensUndistorter` per distinct distorted camera of a dataset (built on first use)."""

    def __init__(self, camera_model: str, where: Path) -> None:
        if camera_model not in _CAMERA_MODELS:
            raise DatasetError(f'{where}: camera_model {camera_model!r} is not supported; expected one of '
                               f'{", ".join(_CAMERA_MODELS)}')
        self._model = _CAMERA_MODELS[camera_model]
        self._cache: dict[tuple, LensUndistorter | None] = {}

    def __call__(self, cam: CameraIntrinsics) -> LensUndistorter | None:
        key = (cam.fl_x, cam.fl_y, cam.cx, cam.cy, cam.w, cam.h, tuple(sorted(cam.distortion.items())))
        if key not in self._cache:
            self._cache[key] = LensUndistorter.for_intrinsics(cam, self._model)
        return self._cache[key]


def load_dataset(dataset_dir: str | Path, *, eval_every: int = 8, require_instances: bool = True) -> SceneDataset:
    """Read a transforms.json dataset into tensors.

    Args:
        dataset_dir: directory holding ``transforms.json``.
        eval_every: hold out every n-th view for evaluation (0 = none).
        require_instances: raise when a frame lacks ``instance_path`` (instance training needs them).

    Raises:
        DatasetError: naming the file, for a missing/undecodable image, mask or depth image, an image/mask/depth
            size mismatch, a depth image that is not one channel of 16-bit integers or floats,
            views of different sizes, a non-finite pose, or a dataset without frames.
    """
    dataset_dir = Path(dataset_dir)
    transforms: TransformsFile = read_transforms(dataset_dir)
    undistorter_of = _Undistorters(str(transforms.extra.get('camera_model', 'OPENCV')), dataset_dir / 'transforms.json')
    images, instances, semantics, intrinsics, poses, valids, depths = [], [], [], [], [], [], []
    shape: tuple[int, int] | None = None
    for index, frame in enumerate(transforms.frames):
        image_path = dataset_dir / frame.file_path
        rgb = _read_rgb(image_path)
        size = rgb.shape[:2]
        if shape is None:
            shape = size
        elif size != shape:
            raise DatasetError(f'{image_path}: size {size[1]}x{size[0]} differs from the first view\'s '
                               f'{shape[1]}x{shape[0]}; all views must share one size')
        cam = transforms.intrinsics_of(index)
        if (cam.h, cam.w) != size:
            raise DatasetError(f'{image_path}: image is {size[1]}x{size[0]} but transforms.json says '
                               f'{cam.w}x{cam.h}')
        if frame.instance_path is None:
            if require_instances:
                raise DatasetError(f'{dataset_dir / "transforms.json"} frame {index} ({frame.file_path}): '
                                   'no instance_path (instance masks are required for training; make them with '
                                   '`fruitnerfpp segment DATA_DIR`, --method semantic from its fruit masks)')
            instance = np.zeros(size, np.int32)
        else:
            instance = _read_label_mask(dataset_dir / frame.instance_path, 'instance mask')
            if instance.shape != size:
                raise DatasetError(f'{dataset_dir / frame.instance_path}: instance mask is '
                                   f'{instance.shape[1]}x{instance.shape[0]} but image {image_path} is '
                                   f'{size[1]}x{size[0]}')
        if frame.semantic_path is not None:
            semantic = _read_label_mask(dataset_dir / frame.semantic_path, 'semantic mask') > 0
            if semantic.shape != size:
                raise DatasetError(f'{dataset_dir / frame.semantic_path}: semantic mask is '
                                   f'{semantic.shape[1]}x{semantic.shape[0]} but image {image_path} is '
                                   f'{size[1]}x{size[0]}')
        else:
            semantic = instance > 0
        valid = np.ones(size, bool)
        if frame.mask_path is not None:
            valid = _read_label_mask(dataset_dir / frame.mask_path, 'pixel mask') > 0
            if valid.shape != size:
                raise DatasetError(f'{dataset_dir / frame.mask_path}: pixel mask is {valid.shape[1]}x'
                                   f'{valid.shape[0]} but image {image_path} is {size[1]}x{size[0]}')
        depth = None
        if frame.depth_path is not None:
            depth = _read_depth(dataset_dir / frame.depth_path, transforms.depth_unit_m, size, image_path)
        undistorter = undistorter_of(cam)
        if undistorter is not None:
            rgb, instance = undistorter.image(rgb), undistorter.labels(instance)
            semantic = undistorter.labels(semantic.astype(np.uint8)) > 0
            valid = undistorter.labels(valid.astype(np.uint8)) > 0
            depth = None if depth is None else undistorter.labels(depth)
        if not valid.all():
            instance = np.where(valid, instance, 0)
            semantic = semantic & valid
            depth = None if depth is None else np.where(valid, depth, np.float32(0.0))
        depths.append(depth)
        images.append(rgb)
        valids.append(valid)
        instances.append(instance)
        semantics.append(semantic)
        intrinsics.append((cam.fl_x, cam.fl_y, cam.cx, cam.cy))
        poses.append(frame.T_world_camera)
    train, held = split_indices(len(images), eval_every)
    ply_path = dataset_dir / transforms.ply_file_path if transforms.ply_file_path else None
    if ply_path is not None and not ply_path.is_file():
        ply_path = None
    return SceneDataset(
        dataset_dir=dataset_dir,
        images=torch.from_numpy(np.stack(images)),  # _read_rgb gives float32
        instance_masks=torch.from_numpy(np.stack(instances)),
        semantic_masks=torch.from_numpy(np.stack(semantics)),
        intrinsics=torch.tensor(intrinsics, dtype=torch.float32),
        T_world_camera=torch.from_numpy(np.stack(poses).astype(np.float32)),
        train_indices=torch.from_numpy(train.astype(np.int64)),
        eval_indices=torch.from_numpy(held.astype(np.int64)),
        ply_path=ply_path,
        file_paths=tuple(frame.file_path for frame in transforms.frames),
        valid_masks=None if all(v.all() for v in valids) else torch.from_numpy(np.stack(valids)),
        depths=_stacked_depths(depths),
        mask_source=transforms.mask_source,
    )


def _stacked_depths(depths: list[np.ndarray | None]) -> torch.Tensor | None:
    """[V, H, W] float32 of the views' depths (zeros for a view without one), None when no view has depth."""
    shape = next((d.shape for d in depths if d is not None), None)
    if shape is None:
        return None
    return torch.from_numpy(np.stack([np.zeros(shape, np.float32) if d is None else d for d in depths]))
