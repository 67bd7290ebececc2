"""The geometry is right: visible GT fruit centres project into their instance masks, with the transforms.json
camera model and with the bag's ROS camera model (half-pixel convention included); poses round-trip."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.device import resolve_device
from fruitnerfpp_ros.core.geometry import (invert_transform, opengl_from_optical, optical_from_opengl,
                                           transform_from_quaternion)
from fruitnerfpp_ros.core.synthetic import T_BASE_LINK_CAMERA_OPTICAL, TOPICS, Renderer, SynthConfig, build_scene

from .conftest import SmallScene


def _gt(dataset: Path) -> tuple[np.ndarray, np.ndarray]:
    fruits = json.loads((dataset / 'gt_fruits.json').read_text())['fruits']
    return np.array([f['id'] for f in fruits]), np.array([f['center'] for f in fruits])


@functools.lru_cache(maxsize=2)
def _renderer(config: SynthConfig) -> Renderer:
    return Renderer(build_scene(config), resolve_device('cpu'))


def _centre_visible(small_scene: SmallScene, eye: np.ndarray, ids: np.ndarray, centers: np.ndarray,
                    pixel_dirs: np.ndarray) -> np.ndarray:
    """True where the view sees the fruit centre: the ray from ``eye`` to the centre and the ray through the
    centre of the pixel holding its projection (``pixel_dirs`` [N, 3], world) both first meet that same fruit
    (ray casting against the analytic scene, independent of the rasteriser)."""
    renderer = _renderer(small_scene.config)
    eyes = np.repeat(eye[None], len(centers), 0)
    t, inst = renderer.first_hit(eyes, centers - eye)
    _, inst_pixel = renderer.first_hit(eyes, pixel_dirs)
    return (inst == ids) & (t < 1.0) & (inst_pixel == ids)


def _read_bag(path: Path) -> dict[str, dict[int, object]]:
    """topic -> stamp_ns -> deserialised message."""
    out: dict[str, dict[int, object]] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp if hasattr(msg, 'header') else msg.transforms[0].header.stamp
            out.setdefault(conn.topic, {})[stamp.sec * 1_000_000_000 + stamp.nanosec] = msg
    return out


def test_visible_centres_project_into_masks_with_transforms_json(small_scene: SmallScene) -> None:
    dataset = small_scene.result.dataset_dir
    tf = read_transforms(dataset)
    ids, centers = _gt(dataset)
    checked = seen_pairs = 0
    for i, frame in enumerate(tf.frames):
        K = tf.intrinsics_of(i)
        inst = cv2.imread(str(dataset / frame.instance_path), cv2.IMREAD_UNCHANGED)
        assert inst.dtype == np.uint16 and inst.shape == (K.h, K.w)
        semantic = cv2.imread(str(dataset / frame.semantic_path), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(semantic == 255, inst > 0)
        # OpenGL camera: x right, y up, looks along -z; principal point with the top-left corner at (0, 0).
        p = (invert_transform(frame.T_world_camera) @ np.c_[centers, np.ones(len(centers))].T).T[:, :3]
        assert np.all(p[:, 2] < 0)
        u = K.fl_x * p[:, 0] / -p[:, 2] + K.cx
        v = -K.fl_y * p[:, 1] / -p[:, 2] + K.cy
        col, row = np.floor(u).astype(int), np.floor(v).astype(int)
        pixel_gl = np.stack([(col + 0.5 - K.cx) / K.fl_x, -(row + 0.5 - K.cy) / K.fl_y, -np.ones(len(col))], 1)
        visible = _centre_visible(small_scene, frame.T_world_camera[:3, 3], ids, centers,
                                  pixel_gl @ frame.T_world_camera[:3, :3].T)
        present = np.isin(ids, inst)
        seen_pairs += int(present.sum())
        for k in np.flatnonzero(visible):
            assert 0 <= col[k] < K.w and 0 <= row[k] < K.h
            assert inst[row[k], col[k]] == ids[k], f'view {i}: fruit {ids[k]} centre at ({u[k]:.2f}, {v[k]:.2f})'
            checked += 1
        # A fruit whose centre is visible is in the mask; the mask holds only GT ids.
        assert set(np.unique(inst)) - {0} <= set(ids.tolist())
    # Most fruits a view sees show their centre (leaves hide some): the check is not vacuous.
    assert checked >= 0.25 * seen_pairs and checked >= 4 * len(tf.frames)


def test_visible_centres_project_into_masks_with_bag_camera_model(small_scene: SmallScene) -> None:
    msgs = _read_bag(small_scene.result.bag_path)
    ids, centers = _gt(small_scene.result.dataset_dir)
    tf = read_transforms(small_scene.result.dataset_dir)
    stamps = sorted(msgs[TOPICS['image']])
    assert len(stamps) == len(tf.frames)
    checked = 0
    for i, stamp in enumerate(stamps):
        for topic in ('image', 'camera_info', 'pose', 'instance_mask', 'tf'):
            assert stamp in msgs[TOPICS[topic]], f'{topic} lacks stamp {stamp}'
        info, pose = msgs[TOPICS['camera_info']][stamp], msgs[TOPICS['pose']][stamp]
        mask_msg = msgs[TOPICS['instance_mask']][stamp]
        assert mask_msg.encoding == 'mono16' and mask_msg.header.frame_id == 'camera_optical'
        assert pose.header.frame_id == 'map' and info.header.frame_id == 'camera_optical'
        mask = np.frombuffer(mask_msg.data.tobytes(), dtype='<u2').reshape(mask_msg.height, mask_msg.step // 2)
        K = np.asarray(info.k).reshape(3, 3)
        p, q = pose.pose.position, pose.pose.orientation
        T_map_optical = transform_from_quaternion(np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w]))
        # ROS optical camera: z forward, x right, y down; the top-left pixel's centre is (0, 0).
        pc = (invert_transform(T_map_optical) @ np.c_[centers, np.ones(len(centers))].T).T[:, :3]
        uv = (K @ (pc / pc[:, 2:3]).T).T
        col, row = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        pixel_opt = (np.linalg.inv(K) @ np.stack([col, row, np.ones(len(col))]).astype(float)).T
        visible = _centre_visible(small_scene, T_map_optical[:3, 3], ids, centers,
                                  pixel_opt @ T_map_optical[:3, :3].T)
        for k in np.flatnonzero(visible):
            assert mask[row[k], col[k]] == ids[k], f'bag frame {i}: fruit {ids[k]}'
            checked += 1
        # The bag frame is the transforms.json frame in optical axes; cx_ros = cx - 0.5.
        np.testing.assert_allclose(T_map_optical, optical_from_opengl(tf.frames[i].T_world_camera), atol=1e-9)
        assert K[0, 2] == pytest.approx(tf.intrinsics.cx - 0.5) and K[1, 2] == pytest.approx(tf.intrinsics.cy - 0.5)
        assert K[0, 0] == pytest.approx(tf.intrinsics.fl_x) and K[1, 1] == pytest.approx(tf.intrinsics.fl_y)
    assert checked >= 4 * len(stamps)


def test_tf_chain_equals_optical_pose(small_scene: SmallScene) -> None:
    msgs = _read_bag(small_scene.result.bag_path)
    (static,) = msgs[TOPICS['tf_static']].values()
    st = static.transforms[0]
    assert (st.header.frame_id, st.child_frame_id) == ('base_link', 'camera_optical')

    def matrix(transform: object) -> np.ndarray:
        t, r = transform.translation, transform.rotation
        return transform_from_quaternion(np.array([t.x, t.y, t.z]), np.array([r.x, r.y, r.z, r.w]))

    T_base_optical = matrix(st.transform)
    np.testing.assert_allclose(T_base_optical, T_BASE_LINK_CAMERA_OPTICAL, atol=1e-9)
    assert not np.allclose(T_base_optical, np.eye(4))
    for stamp, tf_msg in msgs[TOPICS['tf']].items():
        dyn = tf_msg.transforms[0]
        assert (dyn.header.frame_id, dyn.child_frame_id) == ('map', 'base_link')
        p, q = (msgs[TOPICS['pose']][stamp].pose.position, msgs[TOPICS['pose']][stamp].pose.orientation)
        T_pose = transform_from_quaternion(np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w]))
        np.testing.assert_allclose(matrix(dyn.transform) @ T_base_optical, T_pose, atol=1e-9)


def test_transforms_optical_round_trip(small_scene: SmallScene) -> None:
    tf = read_transforms(small_scene.result.dataset_dir)
    for frame in tf.frames:
        T = frame.T_world_camera
        T_opt = optical_from_opengl(T)
        np.testing.assert_allclose(opengl_from_optical(T_opt), T, atol=1e-12)
        # Optical z (forward) is OpenGL -z; optical y (down) is OpenGL -y; same camera centre.
        np.testing.assert_allclose(T_opt[:3, 2], -T[:3, 2])
        np.testing.assert_allclose(T_opt[:3, 1], -T[:3, 1])
        np.testing.assert_allclose(T_opt[:3, 3], T[:3, 3])
        # Every camera looks at the tree: the trunk axis point at mid-height is in front of it.
        to_tree = np.array([0.0, 0.0, 0.5]) - T[:3, 3]
        assert to_tree @ T_opt[:3, 2] > 0
