"""Dataset loading: tensors, split, derived semantics, and every bad-input error naming its file."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.data.dataset import load_dataset, split_indices
from fruitnerfpp_ros.errors import DatasetError
from test.core.training.stand_in_scene import make_sphere_scene


@pytest.fixture(scope='module')
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sphere_scene(tmp_path_factory.mktemp('spheres'), views=10, size=32, fruits=6)


def _copy(scene: Path, tmp_path: Path) -> Path:
    out = tmp_path / 'copy'
    shutil.copytree(scene, out)
    return out


def test_loads_tensors_and_split(scene: Path) -> None:
    ds = load_dataset(scene, eval_every=4)
    assert ds.images.shape == (10, 32, 32, 3) and ds.images.dtype == torch.float32
    assert 0.0 <= float(ds.images.min()) and float(ds.images.max()) <= 1.0
    assert ds.instance_masks.shape == (10, 32, 32) and ds.instance_masks.dtype == torch.int32
    assert torch.equal(ds.semantic_masks, ds.instance_masks > 0)  # derived when no semantic_path
    assert ds.eval_indices.tolist() == [0, 4, 8]
    assert ds.train_indices.tolist() == [1, 2, 3, 5, 6, 7, 9]
    raw = json.loads((scene / 'transforms.json').read_text())
    assert np.allclose(ds.T_world_camera[3].numpy(), np.asarray(raw['frames'][3]['transform_matrix']), atol=1e-6)
    assert ds.intrinsics[0, 0] == pytest.approx(raw['fl_x'], rel=1e-6)


def test_split_every_eighth_and_disabled() -> None:
    train, held = split_indices(24, 8)
    assert held.tolist() == [0, 8, 16] and len(train) == 21
    train, held = split_indices(5, 0)
    assert len(held) == 0 and len(train) == 5


def test_semantic_masks_read_when_named(scene: Path, tmp_path: Path) -> None:
    data = _copy(scene, tmp_path)
    raw = json.loads((data / 'transforms.json').read_text())
    (data / 'semantics').mkdir()
    for i, frame in enumerate(raw['frames']):
        mask = np.zeros((32, 32), np.uint8)
        mask[:4] = 255
        cv2.imwrite(str(data / f'semantics/{i}.png'), mask)
        frame['semantic_path'] = f'semantics/{i}.png'
    (data / 'transforms.json').write_text(json.dumps(raw))
    ds = load_dataset(data)
    assert int(ds.semantic_masks.sum()) == 10 * 4 * 32


def test_colour_coded_masks_give_one_instance_per_colour(scene: Path, tmp_path: Path) -> None:
    """Annotation tools export an id per colour; two colours sharing a channel value stay two fruits."""
    data = _copy(scene, tmp_path)
    raw = json.loads((data / 'transforms.json').read_text())
    (data / 'semantics').mkdir()
    for i, frame in enumerate(raw['frames']):
        colour = np.zeros((32, 32, 3), np.uint8)
        colour[2:8, 2:8] = (0, 0, 255)                       # BGR: red
        colour[20:26, 10:16] = (0, 128, 255)                 # orange: the same blue and red as the red fruit
        cv2.imwrite(str(data / frame['instance_path']), colour)
        cv2.imwrite(str(data / f'semantics/{i}.png'), colour)   # a red-on-black fruit mask, no blue at all
        frame['semantic_path'] = f'semantics/{i}.png'
    (data / 'transforms.json').write_text(json.dumps(raw))
    ds = load_dataset(data)
    ids = ds.instance_masks[0].numpy()
    assert ids[0, 0] == 0 and ids[4, 4] > 0 and ids[22, 12] > 0 and ids[4, 4] != ids[22, 12]
    assert len(np.unique(ids)) == 3
    assert int(ds.semantic_masks[0].sum()) == 2 * 36


def test_missing_mask_names_file(scene: Path, tmp_path: Path) -> None:
    data = _copy(scene, tmp_path)
    (data / 'instances/0003.png').unlink()
    with pytest.raises(DatasetError, match='instances/0003.png'):
        load_dataset(data)


def test_missing_instance_path_names_frame(scene: Path, tmp_path: Path) -> None:
    data = _copy(scene, tmp_path)
    raw = json.loads((data / 'transforms.json').read_text())
    del raw['frames'][2]['instance_path']
    (data / 'transforms.json').write_text(json.dumps(raw))
    with pytest.raises(DatasetError, match='images/0002.png'):
        load_dataset(data)


def test_mask_size_mismatch_names_file(scene: Path, tmp_path: Path) -> None:
    data = _copy(scene, tmp_path)
    cv2.imwrite(str(data / 'instances/0005.png'), np.zeros((16, 32), np.uint16))
    with pytest.raises(DatasetError, match='instances/0005.png.*32x16'):
        load_dataset(data)


def test_nan_pose_names_frame(scene: Path, tmp_path: Path) -> None:
    data = _copy(scene, tmp_path)
    text = (data / 'transforms.json').read_text()
    raw = json.loads(text)
    raw['frames'][4]['transform_matrix'][0][3] = float('nan')
    (data / 'transforms.json').write_text(json.dumps(raw))
    with pytest.raises(DatasetError, match='images/0004.png'):
        load_dataset(data)


def test_empty_dataset_names_transforms(tmp_path: Path) -> None:
    empty = {'fl_x': 1, 'fl_y': 1, 'cx': 1, 'cy': 1, 'w': 2, 'h': 2, 'frames': []}
    (tmp_path / 'transforms.json').write_text(json.dumps(empty))
    with pytest.raises(DatasetError, match='transforms.json.*no frames'):
        load_dataset(tmp_path)
    with pytest.raises(DatasetError, match='transforms.json'):
        load_dataset(tmp_path / 'nowhere')
