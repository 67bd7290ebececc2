"""The synthetic depth camera: a stereo camera's error statistics, holes and range; files and bag topic; the
dataset without depth stays as it was."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.core.synthetic.bag_writer import DEPTH_TOPIC
from fruitnerfpp_ros.core.synthetic.depth_sensor import LEAF_DROPOUT, sensed_depth, stereo_sigma_m
from fruitnerfpp_ros.core.synthetic.rasterizer import SURFACE_FRUIT, SURFACE_LEAF, SURFACE_SKY
from fruitnerfpp_ros.errors import SynthError

SENSOR = dict(max_range_m=6.0, disparity_noise_px=0.08, focal_px=640.0, baseline_m=0.05)


def _sense(depth: np.ndarray, surface: np.ndarray | None = None, model: str = 'stereo', seed: int = 0) -> np.ndarray:
    surface = np.full(depth.shape, SURFACE_FRUIT, np.uint8) if surface is None else surface
    return sensed_depth(depth, surface, model, np.random.default_rng(seed), **SENSOR)


def test_stereo_error_grows_with_range_squared() -> None:
    for z in (1.0, 2.0, 4.0):
        measured = _sense(np.full((200, 200), z, np.float32))
        assert (measured > 0).all()  # a flat wall: no edges, no leaves, in range
        error = measured.astype(np.float64) - z
        expected = stereo_sigma_m(z, disparity_noise_px=0.08, focal_px=640.0, baseline_m=0.05)
        assert expected == pytest.approx(0.08 * z * z / 32.0)
        assert abs(error.mean()) < 0.1 * expected  # unbiased
        assert error.std() == pytest.approx(expected, rel=0.05)


def test_holes_at_edges_on_leaves_beyond_range_and_in_the_sky() -> None:
    depth = np.full((100, 100), 2.0, np.float32)
    depth[:, 50:] = 3.0                 # a depth edge between columns 49 and 50
    depth[:10] = np.inf                 # sky
    depth[90:, :50] = 7.0               # beyond the maximum range
    surface = np.full(depth.shape, SURFACE_FRUIT, np.uint8)
    surface[:10] = SURFACE_SKY
    surface[40:60, 10:30] = SURFACE_LEAF
    measured = _sense(depth, surface)
    assert not measured[:10].any() and not measured[90:, :49].any()
    assert not measured[11:89, 50].any() and measured[11:89, 49].all()  # the farther side of the edge loses a strip
    assert measured[11:89, 51].all()
    leaf = measured[40:60, 10:30] > 0
    assert leaf.mean() == pytest.approx(1.0 - LEAF_DROPOUT, abs=0.1)
    exact = _sense(depth, surface, 'exact')
    assert np.array_equal(exact[10:90], depth[10:90]) and not exact[:10].any()
    garbage = _sense(depth, surface, 'random')
    assert (garbage[10:90] > 0).all() and abs(float(np.corrcoef(garbage[10:90].ravel(),
                                                                depth[10:90].ravel())[0, 1])) < 0.05
    with pytest.raises(SynthError, match='unknown depth model'):
        _sense(depth, surface, 'lidar')
    with pytest.raises(SynthError, match='unknown depth model'):
        SynthConfig(depth='lidar')


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob('*')) if p.is_file()}


def test_depth_files_and_bag_topic_leave_the_rest_unchanged(tmp_path: Path) -> None:
    config = SynthConfig(count=5, views=3, resolution=(32, 24), sparse_points=50)
    generate_orchard(config, tmp_path / 'plain', bag=tmp_path / 'plain_bag')
    code = main(['synth', '--quiet', '--count', '5', '--views', '3', '--resolution', '32x24', '--sparse-points', '50',
                 '--depth', '--depth-baseline', '0.06', '--depth-focal', '600', '--depth-disparity-noise', '0.1',
                 '--depth-max-range', '5', '--out', str(tmp_path / 'rgbd'), '--bag', str(tmp_path / 'rgbd_bag')])
    assert code == 0
    plain, rgbd = _files(tmp_path / 'plain'), _files(tmp_path / 'rgbd')
    assert 'depth' not in plain['transforms.json'].decode()
    assert {k: v for k, v in rgbd.items() if not k.startswith('depths/') and k != 'transforms.json'} == \
        {k: v for k, v in plain.items() if k != 'transforms.json'}
    tf = read_transforms(tmp_path / 'rgbd')
    assert tf.depth_unit_scale_factor == 0.001
    assert [f.depth_path for f in tf.frames] == [f'depths/{i:04d}.png' for i in range(3)]
    assert {k: tf.extra['generator']['config'][k] for k in ('depth', 'depth_baseline_m', 'depth_focal_px',
                                                            'depth_disparity_noise_px', 'depth_max_range_m')} == \
        {'depth': 'stereo', 'depth_baseline_m': 0.06, 'depth_focal_px': 600.0, 'depth_disparity_noise_px': 0.1,
         'depth_max_range_m': 5.0}
    with AnyReader([tmp_path / 'rgbd_bag']) as reader:
        depth_conns = [c for c in reader.connections if c.topic == DEPTH_TOPIC]
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(depth_conns)]
    with AnyReader([tmp_path / 'plain_bag']) as reader:
        assert DEPTH_TOPIC not in {c.topic for c in reader.connections}
    assert len(msgs) == 3 and msgs[0].encoding == '16UC1' and msgs[0].header.frame_id == 'camera_optical'
    for i, msg in enumerate(msgs):
        png = cv2.imread(str(tmp_path / 'rgbd' / 'depths' / f'{i:04d}.png'), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(np.frombuffer(msg.data.tobytes(), '<u2').reshape(24, 32), png)
        assert 0 < png.max() <= 5000
