"""generate_orchard outputs: the tiny training scene, the preview, the CLI and its flags."""

from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard

from .conftest import SmallScene


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


def test_cli_flags_reach_every_new_option(tmp_path: Path) -> None:
    code = main(['synth', '--quiet', '--fruit', 'plum', '--count', '8', '--views', '4', '--resolution', '40', '30',
                 '--trajectory', 'row', '--row-standoff', '1.6', '--camera-height', '0.9', '--camera-pitch', '3',
                 '--row-jitter', '0', '--row-length', '2.5', '--fov', '60', '--fy-scale', '1.02',
                 '--principal-offset', '1.5', '-1', '--distortion', '-0.05', '0.01', '0.001', '0',
                 '--appearance-variation', '0.5', '--leaf-scale', '0.5', '--cluster-scale', '0', '--sparse-points',
                 '100', '--bag-image-format', 'jpeg', '--jpeg-quality', '80', '--world-frame', 'odom',
                 '--out', str(tmp_path / 'ds'), '--bag', str(tmp_path / 'bag')])
    assert code == 0
    tf = read_transforms(tmp_path / 'ds')
    K = tf.intrinsics
    assert (K.w, K.h, K.cx, K.cy, K.fl_y) == (40, 30, 21.5, 14.0, pytest.approx(1.02 * K.fl_x))
    assert K.distortion == {'k1': -0.05, 'k2': 0.01, 'p1': 0.001, 'p2': 0.0}
    recorded = tf.extra['generator']['config']
    assert {k: recorded[k] for k in ('row_standoff_m', 'camera_height_m', 'camera_pitch_deg', 'row_jitter',
                                     'row_length_m', 'fov_deg', 'appearance_variation', 'leaf_scale',
                                     'cluster_scale', 'sparse_points', 'bag_image_format', 'bag_jpeg_quality',
                                     'world_frame', 'principal_offset_px', 'distortion')} == {
        'row_standoff_m': 1.6, 'camera_height_m': 0.9, 'camera_pitch_deg': 3.0, 'row_jitter': 0.0,
        'row_length_m': 2.5, 'fov_deg': 60.0, 'appearance_variation': 0.5, 'leaf_scale': 0.5, 'cluster_scale': 0.0,
        'sparse_points': 100, 'bag_image_format': 'jpeg', 'bag_jpeg_quality': 80, 'world_frame': 'odom',
        'principal_offset_px': [1.5, -1.0], 'distortion': [-0.05, 0.01, 0.001, 0.0, 0.0]}
    eyes = np.array([f.T_world_camera[:3, 3] for f in tf.frames])
    np.testing.assert_allclose(eyes, [[-1.25, -1.6, 0.9], [1.25, -1.6, 0.9], [1.25, 1.6, 0.9], [-1.25, 1.6, 0.9]])


def test_progress_events_and_stale_frames_removed(tmp_path: Path) -> None:
    events = []
    generate_orchard(SynthConfig(count=3, views=3, resolution=(16, 16)), tmp_path, progress=events.append)
    assert [(e.phase, e.step, e.total) for e in events] == [('synth:render', k, 3) for k in range(4)]
    result = generate_orchard(SynthConfig(count=3, views=1, resolution=(16, 16)), tmp_path)
    assert sorted(p.name for p in (tmp_path / 'images').iterdir()) == ['0000.png']
    assert len(read_transforms(tmp_path).frames) == 1 and result.bag_path is None


def test_views_visible_lists_every_view_showing_the_fruit(small_scene: SmallScene) -> None:
    """gt_fruits.json: views_visible = the views whose instance mask holds the fruit (all views, no split);
    n_views_visible = their number; view_stamps_ns = the frames' stamps."""
    dataset = small_scene.result.dataset_dir
    tf = read_transforms(dataset)
    data = json.loads((dataset / 'gt_fruits.json').read_text())
    assert data['view_stamps_ns'] == [f.stamp_ns for f in tf.frames]
    in_masks = {}
    for i, frame in enumerate(tf.frames):
        ids = np.unique(cv2.imread(str(dataset / frame.instance_path), cv2.IMREAD_UNCHANGED))
        for fruit_id in ids[ids > 0]:
            in_masks.setdefault(int(fruit_id), []).append(i)
    for fruit in data['fruits']:
        assert fruit['views_visible'] == in_masks.get(fruit['id'], [])
        assert fruit['n_views_visible'] == len(fruit['views_visible'])
    # Evaluation on a training split: a fruit shown only by held-out views is unseen.
    some = next(f for f in data['fruits'] if 0 < f['n_views_visible'] < len(tf.frames))
    others = [v for v in range(len(tf.frames)) if v not in some['views_visible']]
    gt = load_ground_truth(dataset / 'gt_fruits.json', train_views=others)
    assert not gt.seen[list(gt.ids).index(some['id'])]


def test_config_yaml_lists_every_option_at_its_default() -> None:
    path = Path(__file__).resolve().parents[3] / 'config' / 'synth.yaml'
    assert load_config(SynthConfig, path) == SynthConfig()
    assert set(yaml.safe_load(path.read_text())) == {f.name for f in dataclasses.fields(SynthConfig)}
