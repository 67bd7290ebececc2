"""TorchScript adapter round trips with scripted toy models; Segment Anything adapter errors and mask filtering."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.segmentation import SegmenterConfig, build_segmenter
from fruitnerfpp_ros.core.segmentation.sam import fruit_like_masks, instance_map_from_sam_records
from fruitnerfpp_ros.errors import SegmentationError

# This torch announces the TorchScript API's deprecation; the adapter's contract is TorchScript files.
pytestmark = pytest.mark.filterwarnings('ignore:`torch.jit.*` is deprecated:DeprecationWarning')


class RedIdMap(torch.nn.Module):
    """Integer instance map: 5 = red pixels of the left half, 9 = red pixels of the right half."""

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        red = (image[0, 0] > 0.5) & (image[0, 1] < 0.3)
        half = image.shape[3] // 2
        ids = torch.zeros(image.shape[2:], dtype=torch.int64)
        ids[:, :half] = torch.where(red[:, :half], 5, 0)
        ids[:, half:] = torch.where(red[:, half:], 9, 0)
        return ids


class RedMasksWithScores(torch.nn.Module):
    """[N, H, W] logits (left / right red halves, plus a whole-image mask) and [N] scores."""

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        red = ((image[0, 0] > 0.5) & (image[0, 1] < 0.3)).float()
        half = image.shape[3] // 2
        left, right = red.clone(), red.clone()
        left[:, half:] = 0.0
        right[:, :half] = 0.0
        masks = torch.stack([left, right, torch.ones_like(red)]) * 20.0 - 10.0   # logits
        return masks, torch.tensor([0.9, 0.8, 0.1])                               # the whole-image mask scores low


class RedMaskDict(torch.nn.Module):
    def forward(self, image: torch.Tensor) -> dict[str, torch.Tensor]:
        red = ((image[0, 0] > 0.5) & (image[0, 1] < 0.3)).float()
        return {'masks': red[None] * 0.9, 'scores': torch.tensor([0.7])}


class WrongSize(torch.nn.Module):
    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return torch.zeros(3, 3, dtype=torch.int64)


def _image() -> np.ndarray:
    rgb = np.zeros((12, 16, 3), np.uint8)
    rgb[:] = (30, 120, 40)
    rgb[2:6, 2:6] = (220, 20, 20)     # left fruit
    rgb[6:10, 10:14] = (220, 20, 20)  # right fruit
    return rgb


def _save(module: torch.nn.Module, path: Path) -> Path:
    torch.jit.script(module).save(str(path))
    return path


@pytest.mark.parametrize('module', [RedIdMap(), RedMasksWithScores()], ids=['id-map', 'masks+scores'])
def test_torchscript_round_trip(module: torch.nn.Module, tmp_path: Path) -> None:
    path = _save(module, tmp_path / 'model.pt')
    segmenter = build_segmenter(SegmenterConfig(method='torchscript', checkpoint=str(path), device='cpu'))
    ids = segmenter(_image())
    assert ids.dtype == np.uint16 and ids.shape == (12, 16)
    assert np.array_equal(np.unique(ids), [0, 1, 2])
    assert (ids[2:6, 2:6] == 1).all() and (ids[6:10, 10:14] == 2).all() and (ids > 0).sum() == 32


def test_torchscript_dict_output_and_thresholds(tmp_path: Path) -> None:
    path = _save(RedMaskDict(), tmp_path / 'dict.pt')
    ids = build_segmenter(SegmenterConfig(method='torchscript', checkpoint=str(path), device='cpu'))(_image())
    assert ids.max() == 1 and (ids > 0).sum() == 32       # probabilities 0.9 >= mask_threshold, one mask
    strict = SegmenterConfig(method='torchscript', checkpoint=str(path), device='cpu', score_threshold=0.8)
    assert build_segmenter(strict)(_image()).max() == 0     # score 0.7 < 0.8


@pytest.mark.parametrize('method, kind', [('torchscript', 'TorchScript'), ('sam', 'Segment Anything')])
def test_learned_methods_name_a_missing_checkpoint(tmp_path: Path, method: str, kind: str) -> None:
    with pytest.raises(SegmentationError, match=f"'{method}' needs a checkpoint: the path of a local {kind} file"):
        build_segmenter(SegmenterConfig(method=method))
    with pytest.raises(SegmentationError, match=f'{kind} checkpoint not found: .*missing.pt'):
        build_segmenter(SegmenterConfig(method=method, checkpoint=str(tmp_path / 'missing.pt')))


def test_torchscript_errors(tmp_path: Path) -> None:
    junk = tmp_path / 'junk.pt'
    junk.write_bytes(b'not a model')
    with pytest.raises(SegmentationError, match='junk.pt: not a loadable TorchScript model'):
        build_segmenter(SegmenterConfig(method='torchscript', checkpoint=str(junk)))
    path = _save(WrongSize(), tmp_path / 'wrong.pt')
    segmenter = build_segmenter(SegmenterConfig(method='torchscript', checkpoint=str(path), device='cpu'))
    with pytest.raises(SegmentationError, match=r'output has size \(3, 3\), the image \(12, 16\)'):
        segmenter(_image())


def test_sam_errors_name_the_package(tmp_path: Path) -> None:
    checkpoint = tmp_path / 'sam_vit_b.pth'
    checkpoint.write_bytes(b'weights')
    if importlib.util.find_spec('segment_anything') is None:
        with pytest.raises(SegmentationError, match="package 'segment_anything'.*pip install segment-anything"):
            build_segmenter(SegmenterConfig(method='sam', checkpoint=str(checkpoint)))
    else:  # installed: the dummy file is not a SAM checkpoint
        with pytest.raises(SegmentationError, match='cannot load as a SAM vit_b checkpoint'):
            build_segmenter(SegmenterConfig(method='sam', checkpoint=str(checkpoint)))


def test_sam_masks_are_filtered_to_fruit_like_ones() -> None:
    h, w = 60, 80
    yy, xx = np.mgrid[:h, :w]
    fruit = (xx - 20) ** 2 + (yy - 20) ** 2 <= 6 ** 2
    fruit2 = (xx - 50) ** 2 + (yy - 40) ** 2 <= 5 ** 2
    branch = np.zeros((h, w), bool)
    branch[10:50, 60:62] = True
    branch[48:50, 30:62] = True                   # an L-shaped branch: not solid
    ground = yy > 45                              # too large
    speck = (xx == 5) & (yy == 5)                 # too small
    masks = np.stack([fruit, branch, ground, speck, fruit2])
    config = SegmenterConfig(method='sam')
    assert fruit_like_masks(masks, config).tolist() == [True, False, False, False, True]
    records = [{'segmentation': m, 'predicted_iou': s} for m, s in zip(masks, (0.95, 0.99, 0.99, 0.9, 0.4))]
    ids = instance_map_from_sam_records(records, h, w, config)
    assert ids.max() == 1 and (ids == 1).sum() == fruit.sum()   # fruit2 scores 0.4 < score_threshold
    assert instance_map_from_sam_records([], h, w, config).shape == (h, w)


def test_sam_adapter_drives_the_packages_api(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With a stand-in ``segment_anything`` (the real one is not installable offline here): the adapter builds
    the model from the local checkpoint, runs the automatic generator on the RGB image and keeps the fruit."""
    import sys
    import types

    calls: dict[str, object] = {}

    class FakeModel:
        def to(self, device: object) -> 'FakeModel':
            calls['device'] = str(device)
            return self

    class FakeGenerator:
        def __init__(self, model: FakeModel, points_per_side: int) -> None:
            calls['points_per_side'] = points_per_side

        def generate(self, image: np.ndarray) -> list[dict[str, object]]:
            calls['image'] = image.shape, image.dtype
            yy, xx = np.mgrid[:image.shape[0], :image.shape[1]]
            fruit = (xx - 30) ** 2 + (yy - 20) ** 2 <= 4 ** 2
            return [{'segmentation': fruit, 'predicted_iou': 0.97}, {'segmentation': yy > 30, 'predicted_iou': 0.99}]

    def build(checkpoint: str) -> FakeModel:
        calls['checkpoint'] = checkpoint
        return FakeModel()

    fake = types.ModuleType('segment_anything')
    fake.sam_model_registry = {'vit_b': build}  # type: ignore[attr-defined]
    fake.SamAutomaticMaskGenerator = FakeGenerator  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, 'segment_anything', fake)
    checkpoint = tmp_path / 'sam_vit_b.pth'
    checkpoint.write_bytes(b'weights')
    segmenter = build_segmenter(SegmenterConfig(method='sam', checkpoint=str(checkpoint), device='cpu'))
    ids = segmenter(np.zeros((40, 60, 3), np.uint8))
    assert calls['checkpoint'] == str(checkpoint) and calls['device'] == 'cpu'
    assert calls['image'] == ((40, 60, 3), np.uint8)
    assert ids.dtype == np.uint16 and ids.max() == 1 and (ids == 1).sum() == 49  # the disc; the ground is too big
