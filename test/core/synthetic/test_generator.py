"""generate_orchard outputs: the tiny training scene, the row trajectory, the preview, the CLI."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import cv2
import numpy as np

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.geometry import optical_from_opengl
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard


def _read_ply(path: Path) -> np.ndarray:
    data = path.read_bytes()
    header, body = data.split(b'end_header\n', 1)
    n = int(header.split(b'element vertex ')[1].split(b'\n')[0])
    assert b'binary_little_endian' in header and len(body) == n * 15
    rows = np.frombuffer(body, dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('rgb', 'u1', 3)])
    return np.stack([rows['x'], rows['y'], rows['z']], axis=1)


def test_tiny_training_scene_shows_every_fruit(tiny_apple_dataset: Path) -> None:
    """The shared 48-view 96 px scene: 20 apples, each seen by many views, several pixels wide."""
    tf = read_transforms(tiny_apple_dataset)
    K = tf.intrinsics
    assert (K.w, K.h, len(tf.frames)) == (96, 96, 48) and K.cx == 48.0
    gt = json.loads((tiny_apple_dataset / 'gt_fruits.json').read_text())['fruits']
    assert len(gt) == 20 and all(f['type'] == 'apple' for f in gt)
    assert min(f['n_views_visible'] for f in gt) >= 16
    areas = np.zeros(21)
    for frame in tf.frames:
        inst = cv2.imread(str(tiny_apple_dataset / frame.instance_path), cv2.IMREAD_UNCHANGED)
        assert cv2.imread(str(tiny_apple_dataset / frame.file_path)).shape == (96, 96, 3)
        areas += np.bincount(inst.reshape(-1), minlength=21)
    mean_area = areas[1:].sum() / len(tf.frames) / 20
    assert mean_area > 10  # visible pixels per fruit and view (an unoccluded apple is ~5-6 px wide here)
    points = _read_ply(tiny_apple_dataset / tf.ply_file_path)
    assert len(points) > 2000 and points[:, 2].min() > -0.01 and np.abs(points[:, :2]).max() < 2.0
    centers = np.array([f['center'] for f in gt])
    assert np.all(centers.min(0) > points.min(0)) and np.all(centers.max(0) < points.max(0))


def test_row_trajectory_drives_along_both_sides(tmp_path: Path) -> None:
    result = generate_orchard(SynthConfig(fruit='lemon', count=15, views=8, resolution=(64, 48),
                                          trajectory='row', seed=2), tmp_path)
    tf = read_transforms(tmp_path)
    eyes = np.array([f.T_world_camera[:3, 3] for f in tf.frames])
    forward = np.array([optical_from_opengl(f.T_world_camera)[:3, 2] for f in tf.frames])
    assert np.all(eyes[:4, 1] < 0) and np.all(eyes[4:, 1] > 0)            # both sides of the row
    assert np.all(np.diff(eyes[:4, 0]) > 0) and np.all(np.diff(eyes[4:, 0]) < 0)  # drive there and back
    assert np.all(np.sign(forward[:, 1]) == -np.sign(eyes[:, 1]))         # facing the tree
    assert np.all(np.abs(forward[:, 1]) > 0.99)                             # perpendicular to the row
    assert np.ptp(eyes[:, 2]) < 0.1                                          # constant mast height
    assert result.n_fruits_visible >= 13


def test_cli_writes_dataset_bag_and_preview(tmp_path: Path) -> None:
    config = Path(__file__).resolve().parents[3] / 'config' / 'synth.yaml'
    code = main(['synth', '--quiet', '--config', str(config), '--fruit', 'peach', '--count', '6', '--views', '4',
                 '--resolution', '40x32', '--seed', '5', '--out', str(tmp_path / 'ds'), '--bag',
                 str(tmp_path / 'bag'), '--preview', str(tmp_path / 'preview.png')])
    assert code == 0
    tf = read_transforms(tmp_path / 'ds')
    assert (tf.intrinsics.w, tf.intrinsics.h, len(tf.frames)) == (40, 32, 4)
    assert tf.extra['generator']['config']['fruit'] == 'peach'
    assert (tmp_path / 'bag' / 'metadata.yaml').exists()
    sheet = cv2.imread(str(tmp_path / 'preview.png'))
    assert sheet.shape == (3 * 32, 3 * 40, 3)  # 3 views x (RGB | instance | semantic)
    with open(tmp_path / 'preview.png', 'rb') as f:
        assert f.read(8) == b'\x89PNG\r\n\x1a\n' and struct.unpack('>II', f.read(16)[8:16]) == (120, 96)


def test_progress_events_and_stale_frames_removed(tmp_path: Path) -> None:
    events = []
    generate_orchard(SynthConfig(count=3, views=3, resolution=(16, 16)), tmp_path, progress=events.append)
    assert [(e.phase, e.step, e.total) for e in events] == [('synth:render', k, 3) for k in range(4)]
    result = generate_orchard(SynthConfig(count=3, views=1, resolution=(16, 16)), tmp_path)
    assert sorted(p.name for p in (tmp_path / 'images').iterdir()) == ['0000.png']
    assert len(read_transforms(tmp_path).frames) == 1 and result.bag_path is None
