"""Property-based tests of the message converters: any message gives a well-formed result or a ConversionError.

Messages are duck-typed (``SimpleNamespace``), as rosbags decodes them, so any field value can be tried.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fruitnerfpp_ros.core.streams.tf_buffer import TfBuffer
from fruitnerfpp_ros.errors import ConversionError
from fruitnerfpp_ros.nodes.conversions import (add_tf_message, camera_model_from_camera_info, image_from_msg,
                                               mask_from_msg, transform_from_pose_msg, undistort_image,
                                               undistort_mask)

PROPERTIES = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ENCODINGS = st.sampled_from(['rgb8', 'bgr8', 'rgba8', 'bgra8', 'mono8', '8UC1', '8UC3', 'mono16', '16UC1', '32SC1',
                             '32UC1', 'yuv422', 'bayer_rggb8', '', '32FC1'])
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)


@st.composite
def images(draw: st.DrawFn) -> SimpleNamespace:
    height, width = draw(st.integers(-1, 6)), draw(st.integers(-1, 6))
    step = draw(st.one_of(st.integers(0, 40), st.just(max(width, 0) * 3), st.just(max(width, 0) * 2)))
    data = draw(st.one_of(st.binary(max_size=300), st.just(bytes(max(step * height, 0)))))
    return SimpleNamespace(height=height, width=width, step=step, encoding=draw(ENCODINGS), data=data,
                           is_bigendian=draw(st.integers(0, 1)))


@PROPERTIES
@given(images())
def test_any_image_message_is_an_rgb_array_or_a_conversion_error(msg: SimpleNamespace) -> None:
    try:
        rgb = image_from_msg(msg, topic='img')
    except ConversionError as err:
        assert str(err).startswith('img: ')
        return
    assert rgb.dtype == np.uint8 and rgb.shape == (msg.height, msg.width, 3) and rgb.flags.c_contiguous


@PROPERTIES
@given(images(), st.one_of(st.none(), st.tuples(st.integers(0, 6), st.integers(0, 6))))
def test_any_mask_message_is_uint16_ids_or_a_conversion_error(msg: SimpleNamespace,
                                                              shape: tuple[int, int] | None) -> None:
    try:
        ids = mask_from_msg(msg, topic='mask', expected_shape=shape)
    except ConversionError:
        return
    assert ids.dtype == np.uint16 and ids.shape == (msg.height, msg.width)
    assert shape is None or ids.shape == shape


@PROPERTIES
@given(st.lists(st.one_of(FLOATS, st.floats(-100, 100)), min_size=9, max_size=9),
       st.lists(st.one_of(FLOATS, st.floats(-0.5, 0.5)), max_size=8),
       st.integers(-2, 12), st.integers(-2, 12),
       st.sampled_from(['plumb_bob', 'rational_polynomial', 'equidistant', 'fisheye', '']))
def test_any_camera_info_is_a_usable_camera_or_a_conversion_error(k: list[float], d: list[float], width: int,
                                                                  height: int, model: str) -> None:
    msg = SimpleNamespace(k=k, d=d, width=width, height=height, distortion_model=model,
                          header=SimpleNamespace(frame_id='cam'))
    try:
        camera = camera_model_from_camera_info(msg, topic='info')
    except ConversionError:
        return
    assert camera.intrinsics.fl_x > 0 and camera.intrinsics.fl_y > 0 and np.all(np.isfinite(camera.D))
    try:  # a camera that was accepted undistorts images and masks of its size
        image = undistort_image(np.zeros((height, width, 3), np.uint8), camera)
        mask = undistort_mask(np.ones((height, width), np.uint16), camera)
    except ConversionError:
        return
    assert image.shape == (height, width, 3) and mask.shape == (height, width) and mask.dtype == np.uint16


def _pose(values: list[float]) -> SimpleNamespace:
    return SimpleNamespace(position=SimpleNamespace(x=values[0], y=values[1], z=values[2]),
                           orientation=SimpleNamespace(x=values[3], y=values[4], z=values[5], w=values[6]))


@PROPERTIES
@given(st.lists(st.one_of(FLOATS, st.floats(-2, 2)), min_size=7, max_size=7))
def test_any_pose_is_a_rigid_transform_or_a_conversion_error(values: list[float]) -> None:
    try:
        T = transform_from_pose_msg(_pose(values), topic='pose')
    except ConversionError:
        return
    R = T[:3, :3]
    assert np.all(np.isfinite(T)) and np.allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert np.isclose(np.linalg.det(R), 1.0) and np.array_equal(T[3], [0, 0, 0, 1])
    assert abs(np.linalg.norm(values[3:]) - 1.0) <= 1e-3  # only (nearly) unit quaternions are accepted


@pytest.mark.parametrize('quaternion, accepted', [((0, 0, 0, 1), True), ((0, 0, 0, 1.0005), True),
                                                  ((0, 0, 0, 2), False), ((0, 0, 0, 0), False),
                                                  ((1e200, 1e200, 0, 0), False)])
def test_non_unit_quaternions_are_refused(quaternion: tuple[float, ...], accepted: bool) -> None:
    """Before: any non-zero quaternion was normalised silently, and a huge one raised a bare ValueError."""
    if accepted:
        transform_from_pose_msg(_pose([0, 0, 0, *quaternion]))
    else:
        with pytest.raises(ConversionError, match='quaternion'):
            transform_from_pose_msg(_pose([0, 0, 0, *quaternion]))


@PROPERTIES
@given(st.lists(st.tuples(st.sampled_from(['map', 'base', 'cam', '']), st.sampled_from(['base', 'cam', 'map']),
                          st.integers(-10**12, 10**12), st.lists(st.one_of(FLOATS, st.floats(-2, 2)), min_size=7,
                                                                 max_size=7)), max_size=6), st.booleans())
def test_any_tf_message_is_stored_or_refused_and_lookups_stay_rigid(transforms: list[tuple], static: bool) -> None:
    buffer = TfBuffer()
    msg = SimpleNamespace(transforms=[SimpleNamespace(
        header=SimpleNamespace(frame_id=parent, stamp=SimpleNamespace(sec=stamp // 10**9, nanosec=stamp % 10**9)),
        child_frame_id=child, transform=SimpleNamespace(
            translation=SimpleNamespace(x=v[0], y=v[1], z=v[2]),
            rotation=SimpleNamespace(x=v[3], y=v[4], z=v[5], w=v[6]))) for parent, child, stamp, v in transforms])
    try:
        add_tf_message(buffer, msg, static=static)
    except ConversionError:
        pass
    for target in buffer.frames:
        for source in buffer.frames:
            try:
                T = buffer.lookup(target, source, 0)
            except ConversionError:
                continue
            assert np.all(np.isfinite(T)) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6)
