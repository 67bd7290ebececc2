"""Message conversions, without a ROS graph: images, masks, cameras, poses, clouds, markers, report."""

from __future__ import annotations

import json
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from visualization_msgs.msg import Marker

from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.streams.tf_buffer import TfBuffer
from fruitnerfpp_ros.errors import ConversionError
from fruitnerfpp_ros.nodes import conversions as cv
from fruitnerfpp_ros.nodes import result_msgs as rm


def _image_msg(pixels: np.ndarray, encoding: str, pad: int = 0) -> Image:
    h, w = pixels.shape[:2]
    row = pixels.reshape(h, -1).view(np.uint8)
    padded = np.zeros((h, row.shape[1] + pad), np.uint8)
    padded[:, :row.shape[1]] = row
    return Image(height=h, width=w, encoding=encoding, step=padded.shape[1], data=padded.tobytes())


@pytest.fixture
def rgb() -> np.ndarray:
    return np.random.default_rng(0).integers(0, 255, (5, 7, 3), dtype=np.uint8)


@pytest.mark.parametrize('pad', [0, 3])
def test_image_encodings_honour_step(rgb: np.ndarray, pad: int) -> None:
    assert np.array_equal(cv.image_from_msg(_image_msg(rgb, 'rgb8', pad)), rgb)
    assert np.array_equal(cv.image_from_msg(_image_msg(np.ascontiguousarray(rgb[..., ::-1]), 'bgr8', pad)), rgb)
    mono = cv.image_from_msg(_image_msg(rgb[..., 0].copy(), 'mono8', pad))
    assert mono.shape == (5, 7, 3) and np.array_equal(mono[..., 2], rgb[..., 0])


def test_image_from_rosbags_style_message_with_numpy_data(rgb: np.ndarray) -> None:
    msg = SimpleNamespace(height=5, width=7, encoding='rgb8', step=21, is_bigendian=0, data=rgb.reshape(-1).copy())
    assert np.array_equal(cv.image_from_msg(msg), rgb)


def test_compressed_image(rgb: np.ndarray) -> None:
    ok, png = cv2.imencode('.png', rgb[..., ::-1])
    assert ok
    assert np.array_equal(cv.image_from_msg(CompressedImage(format='png', data=png.tobytes())), rgb)
    with pytest.raises(ConversionError, match='cannot decode'):
        cv.image_from_msg(CompressedImage(format='jpeg', data=b'garbage'), topic='/cam/compressed')


def test_unknown_encoding_and_short_data_are_named(rgb: np.ndarray) -> None:
    with pytest.raises(ConversionError, match=r"/cam: unsupported image encoding 'yuv422'"):
        cv.image_from_msg(_image_msg(rgb, 'yuv422'), topic='/cam')
    msg = _image_msg(rgb, 'rgb8')
    msg.data = msg.data[:-10]
    with pytest.raises(ConversionError, match='expected step'):
        cv.image_from_msg(msg)


def test_masks_mono16_and_32sc1() -> None:
    ids = np.array([[0, 1, 70000 % 65536], [3, 65535, 2]], np.uint16)
    assert np.array_equal(cv.mask_from_msg(_image_msg(ids, 'mono16', pad=2)), ids)
    signed = np.array([[-1, 5], [7, 0]], np.int32)
    assert np.array_equal(cv.mask_from_msg(_image_msg(signed, '32SC1')), [[0, 5], [7, 0]])
    with pytest.raises(ConversionError, match='does not fit in 16 bits'):
        cv.mask_from_msg(_image_msg(np.array([[70000]], np.int32), '32SC1'))
    with pytest.raises(ConversionError, match=r'/m: mask is 3x2 but the image is 4x4'):
        cv.mask_from_msg(_image_msg(ids, 'mono16'), topic='/m', expected_shape=(4, 4))
    big = _image_msg(ids.astype('>u2'), 'mono16')
    big.is_bigendian = 1
    assert np.array_equal(cv.mask_from_msg(big), ids)


def _camera_info(model: str = 'plumb_bob', d: list[float] | None = None) -> CameraInfo:
    return CameraInfo(width=64, height=48, distortion_model=model, d=d or [0.0] * 5,
                      k=[50.0, 0.0, 31.5, 0.0, 52.0, 23.5, 0.0, 0.0, 1.0])


def test_intrinsics_half_pixel_convention() -> None:
    intr = cv.intrinsics_from_camera_info(_camera_info())
    assert (intr.fl_x, intr.fl_y, intr.cx, intr.cy, intr.w, intr.h) == (50.0, 52.0, 32.0, 24.0, 64, 48)
    back = cv.camera_info_msg_from_intrinsics(intr, 'cam', 5)
    assert back.k[2] == 31.5 and back.k[5] == 23.5 and back.header.frame_id == 'cam'
    with pytest.raises(ConversionError, match='not calibrated'):
        cv.camera_model_from_camera_info(CameraInfo(width=64, height=48))
    with pytest.raises(ConversionError, match="distortion model 'weird'"):
        cv.camera_model_from_camera_info(_camera_info('weird', [0.1, 0, 0, 0, 0]))


@pytest.mark.parametrize('model,d', [('plumb_bob', [-0.3, 0.1, 0.001, 0.002, 0.0]),
                                     ('rational_polynomial', [-0.3, 0.1, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0]),
                                     ('equidistant', [0.1, -0.05, 0.01, 0.0])])
def test_undistortion_moves_a_distorted_point_back(model: str, d: list[float]) -> None:
    camera = cv.camera_model_from_camera_info(_camera_info(model, d))
    undist = np.array([[52.0, 40.0]])  # an undistorted pixel, off-centre
    rays = cv2.undistortPoints(undist.reshape(1, 1, 2), camera.K, None).reshape(1, 1, 3 - 1)
    pts3 = np.concatenate([rays.reshape(1, 2), np.ones((1, 1))], axis=1)
    if model == 'equidistant':
        distorted = cv2.fisheye.distortPoints(rays, camera.K, np.array(d))
    else:
        distorted, _ = cv2.projectPoints(pts3, np.zeros(3), np.zeros(3), camera.K, np.array(d))
    u, v = distorted.reshape(2)
    image = np.zeros((48, 64, 3), np.uint8)
    cv2.circle(image, (int(round(u)), int(round(v))), 1, (255, 255, 255), -1)
    mask = np.zeros((48, 64), np.uint16)
    mask[int(round(v)) - 1:int(round(v)) + 2, int(round(u)) - 1:int(round(u)) + 2] = 7
    out = cv.undistort_image(image, camera)
    out_mask = cv.undistort_mask(mask, camera)
    ys, xs = np.nonzero(out[..., 0] > 60)
    assert abs(xs.mean() - 52.0) < 1.5 and abs(ys.mean() - 40.0) < 1.5
    assert set(np.unique(out_mask)) <= {0, 7} and out_mask.dtype == np.uint16 and (out_mask == 7).any()


def test_valid_pixels_of_a_pincushion_camera_exclude_the_corners() -> None:
    camera = cv.camera_model_from_camera_info(_camera_info('plumb_bob', [0.4, 0.1, 0.0, 0.0, 0.0]))
    valid = cv.valid_pixels(camera)
    assert valid is not None and valid.shape == (48, 64)
    assert not valid[0, 0] and not valid[47, 63] and valid[24, 32]
    assert cv.valid_pixels(cv.camera_model_from_camera_info(_camera_info())) is None


def test_no_distortion_is_identity() -> None:
    camera = cv.camera_model_from_camera_info(_camera_info())
    image = np.zeros((48, 64, 3), np.uint8)
    assert cv.undistort_image(image, camera) is image


def test_pose_round_trip_and_nan() -> None:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.1, 0.2, 0.3]))[0]
    T[:3, 3] = [1.0, -2.0, 0.5]
    msg = PoseStamped(pose=cv.pose_msg_from_transform(T))
    assert np.allclose(cv.transform_from_pose_msg(msg), T)
    msg.pose.position.x = float('nan')
    with pytest.raises(ConversionError, match='/p: pose is not finite'):
        cv.transform_from_pose_msg(msg, topic='/p')


def _count() -> tuple[FruitPointCloud, CountResult]:
    xyz = np.array([[0, 0, 0], [0.01, 0, 0], [1, 1, 1], [5, 5, 5]], np.float32)
    cloud = FruitPointCloud(xyz, np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [1, 2, 3]], np.uint8),
                            np.array([0.9, 0.8, 0.7, 0.1], np.float32), np.zeros((4, 2), np.float32))
    fruits = [Fruit(1, np.array([0.005, 0, 0]), 0.07, np.array([0.07] * 3), 2),
              Fruit(2, np.array([1.0, 1, 1]), 0.08, np.array([0.08] * 3), 1)]
    return cloud, CountResult(np.array([1, 1, 2, 0], np.int32), fruits)


def test_cloud_round_trip_keeps_instance_ids_and_colours() -> None:
    cloud, count = _count()
    msg = rm.cloud_msg_from_points(cloud, count.labels, 'map', 1_500_000_000)
    assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'rgb', 'instance_id', 'semantic']
    points = rm.points_from_cloud_msg(msg)
    assert np.array_equal(points['instance_id'], [1, 1, 2, 0])
    assert np.allclose(np.stack([points['x'], points['y'], points['z']], 1), cloud.xyz)
    rgb = points['rgb'].view(np.uint32)
    assert rgb[0] == 0xFF0000 and rgb[1] == 0x00FF00 and rgb[2] == 0x0000FF
    assert np.allclose(points['semantic'], cloud.semantic)
    assert msg.header.stamp.sec == 1 and msg.header.stamp.nanosec == 500_000_000


def test_centers_markers_and_report() -> None:
    cloud, count = _count()
    poses = rm.pose_array_from_centers(count.centers(), 'map', 0)
    assert len(poses.poses) == 2 and poses.poses[1].position.z == 1.0
    markers = rm.markers_from_fruits(count.fruits, 'map', 0).markers
    assert markers[0].action == Marker.DELETEALL
    spheres = [m for m in markers if m.ns == 'fruits']
    labels = [m for m in markers if m.ns == 'fruit_labels']
    assert [m.id for m in spheres] == [1, 2] and [m.text for m in labels] == ['1', '2']
    assert spheres[1].scale.x == pytest.approx(0.08)
    report = json.loads(rm.report_json(count, 'map', 2_000_000_001, 'run-x', {'keyframes': 9}))
    assert report['schema'] == rm.REPORT_SCHEMA and report['version'] == 1 and report['total'] == 2
    assert report['stamp'] == {'sec': 2, 'nanosec': 1} and report['frame_id'] == 'map'
    assert report['fruits'][1]['center'] == [1.0, 1.0, 1.0] and report['fruits'][0]['diameter'] == 0.07
    assert report['keyframes'] == 9 and report['run_id'] == 'run-x'


def _ts(parent: str, child: str, x: float) -> SimpleNamespace:
    return SimpleNamespace(header=SimpleNamespace(frame_id=parent, stamp=SimpleNamespace(sec=1, nanosec=0)),
                           child_frame_id=child, transform=SimpleNamespace(
                               translation=SimpleNamespace(x=x, y=0.0, z=0.0),
                               rotation=SimpleNamespace(x=0.0, y=0.0, z=0.0, w=1.0)))


def test_tf_message_with_a_nan_transform_keeps_the_good_ones() -> None:
    tf = TfBuffer()
    msg = SimpleNamespace(transforms=[_ts('map', 'a', 1.0), _ts('map', 'b', float('nan'))])
    with pytest.raises(ConversionError, match='map->b'):
        cv.add_tf_message(tf, msg)
    assert np.allclose(tf.lookup('map', 'a', 1_000_000_000)[:3, 3], [1, 0, 0])
