"""TF buffer: chains, interpolation, errors."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.geometry import transform_from_quaternion
from fruitnerfpp_ros.core.streams.tf_buffer import TfBuffer, TfFutureError, TfLookupError


def _T(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    half = np.radians(yaw_deg) / 2
    return transform_from_quaternion([x, 0.0, 0.0], [0.0, 0.0, np.sin(half), np.cos(half)])


def test_chain_interpolation_and_inverse() -> None:
    tf = TfBuffer()
    tf.set_transform('map', 'odom', 0, np.eye(4), static=True)
    tf.set_transform('odom', 'base_link', 0, _T(0.0, 0.0))
    tf.set_transform('odom', 'base_link', 1000, _T(2.0, 90.0))
    tf.set_transform('base_link', 'camera_optical', 0, _T(0.5), static=True)
    T = tf.lookup('map', 'camera_optical', 500)
    assert np.allclose(T, _T(1.0, 45.0) @ _T(0.5))
    assert np.allclose(tf.lookup('camera_optical', 'map', 500) @ T, np.eye(4))
    assert np.allclose(tf.lookup('base_link', 'camera_optical', 123), _T(0.5))


def test_future_unknown_and_disconnected() -> None:
    tf = TfBuffer(tolerance_ns=0)
    tf.set_transform('map', 'base', 100, np.eye(4))
    with pytest.raises(TfFutureError, match='no transform yet'):
        tf.lookup('map', 'base', 200)
    with pytest.raises(TfLookupError, match="unknown frame 'cam'"):
        tf.lookup('map', 'cam', 100)
    tf.set_transform('other', 'cam', 0, np.eye(4), static=True)
    with pytest.raises(TfLookupError, match='not connected'):
        tf.lookup('map', 'cam', 100)
