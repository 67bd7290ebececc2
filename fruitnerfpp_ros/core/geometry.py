"""Rigid transforms and camera conventions (numpy, float64).

Naming: ``T_a_b`` is the 4x4 homogeneous transform that maps points in frame ``b`` into frame ``a``
(``p_a = T_a_b @ p_b``). Two camera axis conventions meet in this package:

- OpenGL / nerfstudio (transforms.json): x right, y up, z backwards (the camera looks along -z).
- ROS optical (REP-103 ``*_optical``): x right, y down, z forwards.

``T_world_optical = T_world_opengl @ T_OPENGL_OPTICAL`` converts between them.

Pixel conventions: transforms.json puts the image's top-left *corner* at (0, 0), so a pixel centre is at
(u + 0.5, v + 0.5); ROS CameraInfo puts the *centre* of the top-left pixel at (0, 0). Hence
``cx_ros = cx_transforms - 0.5`` (same for cy).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = [
    'T_OPENGL_OPTICAL',
    'opengl_from_optical',
    'optical_from_opengl',
    'transform_from_quaternion',
    'quaternion_from_transform',
    'invert_transform',
    'rotation_angle_deg',
    'interpolate_transform',
    'principal_point_ros_from_transforms',
    'principal_point_transforms_from_ros',
]

#: Maps ROS optical camera axes to OpenGL camera axes (flip y and z); it is its own inverse.
T_OPENGL_OPTICAL = np.diag([1.0, -1.0, -1.0, 1.0])


def opengl_from_optical(T_world_optical: np.ndarray) -> np.ndarray:
    """Camera-to-world pose in OpenGL axes from one in ROS optical axes (works on [..., 4, 4])."""
    return np.asarray(T_world_optical, dtype=np.float64) @ T_OPENGL_OPTICAL


def optical_from_opengl(T_world_opengl: np.ndarray) -> np.ndarray:
    """Camera-to-world pose in ROS optical axes from one in OpenGL axes (works on [..., 4, 4])."""
    return np.asarray(T_world_opengl, dtype=np.float64) @ T_OPENGL_OPTICAL


def transform_from_quaternion(translation_xyz: np.ndarray, quaternion_xyzw: np.ndarray) -> np.ndarray:
    """4x4 transform from a translation and a (not necessarily unit) quaternion in ROS order x, y, z, w."""
    q = np.asarray(quaternion_xyzw, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    T[:3, 3] = np.asarray(translation_xyz, dtype=np.float64)
    return T


def quaternion_from_transform(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translation xyz, unit quaternion xyzw) of a 4x4 rigid transform."""
    T = np.asarray(T, dtype=np.float64)
    return T[:3, 3].copy(), Rotation.from_matrix(T[:3, :3]).as_quat()


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle (degrees) of the rotation between ``R_a`` and ``R_b`` ([..., 3, 3] each)."""
    relative = np.swapaxes(np.asarray(R_a, float), -1, -2) @ np.asarray(R_b, float)
    return np.degrees(Rotation.from_matrix(relative.reshape(-1, 3, 3)).magnitude()).reshape(relative.shape[:-2])


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform (exact for rotation + translation)."""
    T = np.asarray(T, dtype=np.float64)
    inv = np.eye(4)
    inv[:3, :3] = T[:3, :3].T
    inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inv


def interpolate_transform(T_a: np.ndarray, T_b: np.ndarray, fraction: float) -> np.ndarray:
    """Rigid transform between ``T_a`` (fraction 0) and ``T_b`` (fraction 1): lerp translation, slerp rotation."""
    rotations = Rotation.from_matrix(np.stack([T_a[:3, :3], T_b[:3, :3]]))
    T = np.eye(4)
    T[:3, :3] = Slerp([0.0, 1.0], rotations)([float(fraction)]).as_matrix()[0]
    T[:3, 3] = (1.0 - fraction) * T_a[:3, 3] + fraction * T_b[:3, 3]
    return T


def principal_point_ros_from_transforms(cx: float, cy: float) -> tuple[float, float]:
    """ROS CameraInfo principal point from a transforms.json one (half-pixel shift)."""
    return cx - 0.5, cy - 0.5


def principal_point_transforms_from_ros(cx: float, cy: float) -> tuple[float, float]:
    """transforms.json principal point from a ROS CameraInfo one (half-pixel shift)."""
    return cx + 0.5, cy + 0.5
