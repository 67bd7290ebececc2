"""``fruitnerfpp segment``: masks for a dataset without them, refusal to overwrite, one-line errors, lazy torch."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.errors import DatasetError


@pytest.fixture
def unmasked(tmp_path: Path) -> Path:
    """A small synthetic lemon tree whose instance / semantic masks were removed."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
    dataset = tmp_path / 'lemons'
    generate_orchard(SynthConfig(fruit='lemon', count=12, views=4, resolution=(80, 64), seed=2), dataset)
    shutil.rmtree(dataset / 'instances')
    shutil.rmtree(dataset / 'semantics')
    data = json.loads((dataset / 'transforms.json').read_text())
    for frame in data['frames']:
        del frame['instance_path'], frame['semantic_path']
    (dataset / 'transforms.json').write_text(json.dumps(data))
    return dataset


def _one_line_error(capsys: pytest.CaptureFixture[str], message: str) -> None:
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('fruitnerfpp segment: error: ') and message in err, err
    assert 'Traceback' not in err


def test_segmented_dataset_loads(unmasked: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(DatasetError, match='no instance_path'):
        load_dataset(unmasked)
    assert main(['segment', str(unmasked), '--quiet']) == 0
    assert 'segmented 4 images' in capsys.readouterr().out
    frames = read_transforms(unmasked).frames
    assert [f.instance_path for f in frames] == [f'instances/{i:04d}.png' for i in range(4)]
    assert [f.semantic_path for f in frames] == [f'semantics/{i:04d}.png' for i in range(4)]
    dataset = load_dataset(unmasked)
    assert dataset.instance_masks.shape == (4, 64, 80) and int(dataset.instance_masks.max()) >= 1
    assert np.array_equal(dataset.semantic_masks.numpy(), dataset.instance_masks.numpy() > 0)
    assert dataset.mask_source == 'fallback'          # what the count's masks step checks
    assert not list(unmasked.rglob('*.tmp*'))


def test_existing_masks_are_not_overwritten_without_the_flag(unmasked: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['segment', str(unmasked), '--quiet']) == 0
    capsys.readouterr()
    before = (unmasked / 'instances/0000.png').stat().st_mtime_ns
    assert main(['segment', str(unmasked), '--quiet']) == 2
    _one_line_error(capsys, '4 of 4 frames already have instance masks')
    assert (unmasked / 'instances/0000.png').stat().st_mtime_ns == before
    assert main(['segment', str(unmasked), '--quiet', '--overwrite']) == 0


def test_missing_checkpoint_is_one_line(unmasked: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / 'fruit_model.pt'
    assert main(['segment', str(unmasked), '--method', 'torchscript', '--checkpoint', str(missing)]) == 2
    _one_line_error(capsys, f'TorchScript checkpoint not found: {missing}')
    assert main(['segment', str(unmasked), '--method', 'sam']) == 2
    _one_line_error(capsys, "method 'sam' needs a checkpoint")
    config = tmp_path / 'seg.yaml'
    config.write_text('method: torchscript\nchekpoint: x.pt\n')
    assert main(['segment', str(unmasked), '--config', str(config)]) == 2
    _one_line_error(capsys, 'chekpoint')
    assert read_transforms(unmasked).frames[0].instance_path is None


def test_help_does_not_import_torch() -> None:
    code = ('import sys\nfrom fruitnerfpp_ros.cli.main import main\n'
            'try:\n    main(["segment", "--help"])\nexcept SystemExit:\n    pass\n'
            'print("torch" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == 'False'


def test_frames_naming_deleted_masks_get_new_ones(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A dataset copied without its mask folders still names them: those frames have no masks."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
    dataset = tmp_path / 'apples'
    generate_orchard(SynthConfig(fruit='apple', count=8, views=3, resolution=(64, 64), seed=1), dataset)
    assert read_transforms(dataset).mask_source == 'ground_truth'
    shutil.rmtree(dataset / 'instances')
    shutil.rmtree(dataset / 'semantics')
    assert main(['segment', str(dataset), '--quiet']) == 0
    assert 'segmented 3 images' in capsys.readouterr().out
    assert load_dataset(dataset).instance_masks.shape == (3, 64, 64)
    assert read_transforms(dataset).mask_source == 'fallback'
    from fruitnerfpp_ros.core.segmentation.dataset_masks import segment_dataset
    segment_dataset(dataset, lambda rgb: np.zeros(rgb.shape[:2], np.uint16), overwrite=True)
    assert read_transforms(dataset).mask_source is None       # a segmenter that does not name itself: unknown
    segment_dataset(dataset, lambda rgb: np.zeros(rgb.shape[:2], np.uint16), overwrite=True, mask_source='mine')
    assert load_dataset(dataset).mask_source == 'mine'


def test_instances_from_the_datasets_own_fruit_masks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A dataset with binary fruit masks and no instances (FruitNeRF's layout): ``--method semantic`` splits them."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
    from test.core.segmentation.instance_metrics import score_views

    dataset = tmp_path / 'apples'
    generate_orchard(SynthConfig(fruit='apple', count=30, views=6, resolution=(128, 128), seed=7), dataset)
    truth = [cv2.imread(str(dataset / f.instance_path), cv2.IMREAD_UNCHANGED).astype(np.int64)
             for f in read_transforms(dataset).frames]
    semantics = {p.name: p.read_bytes() for p in (dataset / 'semantics').iterdir()}
    shutil.rmtree(dataset / 'instances')
    data = json.loads((dataset / 'transforms.json').read_text())
    for frame in data['frames']:
        del frame['instance_path']
    (dataset / 'transforms.json').write_text(json.dumps(data))
    with pytest.raises(DatasetError, match='--method semantic'):
        load_dataset(dataset)
    assert main(['segment', str(dataset), '--method', 'semantic', '--quiet']) == 0
    assert 'segmented 6 images' in capsys.readouterr().out
    loaded = load_dataset(dataset)
    assert loaded.mask_source == 'semantic'
    assert {p.name: p.read_bytes() for p in (dataset / 'semantics').iterdir()} == semantics   # kept as they were
    scores = score_views(truth, [m.numpy().astype(np.int64) for m in loaded.instance_masks])
    assert scores.pixel_iou >= 0.93 and scores.f1 >= 0.5, scores   # measured: 0.963, 0.599 (leaves cut fruit)
    assert main(['segment', str(dataset), '--method', 'semantic', '--quiet']) == 2
    _one_line_error(capsys, 'instance masks exist')
    data = json.loads((dataset / 'transforms.json').read_text())
    del data['frames'][2]['semantic_path']
    (dataset / 'transforms.json').write_text(json.dumps(data))
    assert main(['segment', str(dataset), '--method', 'semantic', '--quiet', '--overwrite']) == 2
    _one_line_error(capsys, '1 of 6 frames have no semantic_path (first: images/0002.png)')
