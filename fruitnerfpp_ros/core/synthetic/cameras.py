"""Camera intrinsics and trajectories around the synthetic tree: upper hemisphere (BlenderNeRF style) and an
orchard row driven on both sides.

Poses are camera-to-world in OpenGL camera axes (x right, y up, z backwards), as in transforms.json.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.synthetic.config import SynthConfig
from fruitnerfpp_ros.core.synthetic.lens import DISTORTION_KEYS
from fruitnerfpp_ros.core.synthetic.primitives import Scene
from fruitnerfpp_ros.errors import SynthError

__all__ = ['look_at', 'make_intrinsics', 'hemisphere_poses', 'row_poses', 'make_poses', 'RowDrive', 'row_drive',
           'ROW_JITTER_STD']

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))
#: Standard deviations of the drive's jitter at ``row_jitter = 1``: height (m), standoff (m), yaw, pitch, roll
#: (degrees).
ROW_JITTER_STD = (0.02, 0.03, 1.5, 0.7, 1.0)
#: The crown's outer leaves reach this far beyond the crown ellipsoid (relative, see scene._foliage).
_CROWN_REACH = 1.08


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """4x4 camera-to-world pose (OpenGL axes) of a camera at ``eye`` looking at ``target`` (metres)."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight up/down
        right = np.array([1.0, 0.0, 0.0])
    right = right / np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, cam_up, -forward, eye
    return T


def make_intrinsics(config: SynthConfig) -> CameraIntrinsics:
    """Intrinsics (transforms.json convention: top-left image corner at 0, 0): ``fov_deg`` across the shorter side
    sets ``fl_x``, ``fl_y = fl_x * fy_scale``, principal point at the centre plus ``principal_offset_px``, and the
    ``distortion`` coefficients under nerfstudio's OPENCV keys (none when all are zero; k3 only when non-zero)."""
    w, h = config.resolution
    focal = 0.5 * min(w, h) / np.tan(np.radians(config.fov_deg) / 2.0)
    dx, dy = config.principal_offset_px
    distortion = {}
    if any(config.distortion):
        distortion = {k: float(v) for k, v in zip(DISTORTION_KEYS, config.distortion) if k != 'k3' or v != 0.0}
    return CameraIntrinsics(float(focal), float(focal * config.fy_scale), w / 2.0 + dx, h / 2.0 + dy, w, h,
                            distortion)


def hemisphere_poses(scene: Scene, config: SynthConfig, rng: np.random.Generator) -> np.ndarray:
    """[V, 4, 4] random views on the upper hemisphere, stratified in azimuth and height, framing the tree."""
    n = config.views
    half_fov = np.radians(config.fov_deg) / 2.0
    distance = scene.bound_radius / np.sin(half_fov)
    sin_lo, sin_hi = np.sin(np.radians(5.0)), np.sin(np.radians(70.0))
    strata = (np.arange(n) + rng.uniform(size=n)) / n
    elevation = np.arcsin(sin_lo + rng.permutation(strata) * (sin_hi - sin_lo))
    azimuth = rng.uniform(0.0, 2.0 * np.pi) + _GOLDEN_ANGLE * np.arange(n)
    dist = distance * rng.uniform(1.0, 1.12, n)
    poses = np.zeros((n, 4, 4))
    for i in range(n):
        direction = np.array([np.cos(elevation[i]) * np.cos(azimuth[i]),
                              np.cos(elevation[i]) * np.sin(azimuth[i]), np.sin(elevation[i])])
        target = scene.bound_center + rng.normal(scale=0.03 * scene.bound_radius, size=3)
        poses[i] = look_at(scene.bound_center + dist[i] * direction, target)
    return poses


class RowDrive(NamedTuple):
    """The ``row`` trajectory's nominal geometry.

    Attributes:
        length_m: length of each pass (centred on the tree at x = 0), metres.
        standoff_m: nominal distance of the camera from the row centre line (y = 0), metres.
        height_m: nominal camera height above the ground, metres.
        pitch_deg: nominal pitch above the horizon, degrees.
    """

    length_m: float
    standoff_m: float
    height_m: float
    pitch_deg: float


def row_drive(scene: Scene, config: SynthConfig) -> RowDrive:
    """The nominal drive of ``config`` around ``scene``.

    Raises:
        SynthError: ``row_standoff_m`` puts the camera inside the crown.
    """
    reach = _CROWN_REACH * float(scene.crown_radii[1])
    if config.row_standoff_m < reach + 0.1:
        raise SynthError(f'row_standoff_m {config.row_standoff_m:g} m puts the camera inside the tree (its crown '
                         f'reaches {reach:.2f} m from the row centre line); use at least {reach + 0.1:.2f} m')
    length = config.row_length_m
    if length is None:
        K = make_intrinsics(config)
        half_fov_x = np.arctan(0.5 * K.w / K.fl_x)
        # The first view's image edge ray passes the crown (radius R round the trunk) at 0.1 m: the camera at
        # x = -L / 2 looking at the row sees the crown iff L / 2 < (R + standoff * sin(a)) / cos(a), a the half
        # field of view across the image width. Symmetric at the end of the pass.
        radius = _CROWN_REACH * float(scene.crown_radii[0]) + 0.1
        length = 2.0 * (radius + config.row_standoff_m * np.sin(half_fov_x)) / np.cos(half_fov_x)
    return RowDrive(float(length), config.row_standoff_m, config.camera_height_m, config.camera_pitch_deg)


def _smooth_jitter(rng: np.random.Generator, s: np.ndarray, std: float) -> np.ndarray:
    """Smooth noise along the path (s [N] metres): three sinusoids of 0.8-4 m wavelength, ``std`` overall."""
    wavelength = rng.uniform(0.8, 4.0, 3)
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    waves = np.sin(2.0 * np.pi * s[:, None] / wavelength + phase)
    return std * np.sqrt(2.0 / 3.0) * waves.sum(axis=1)


def row_poses(scene: Scene, config: SynthConfig, rng: np.random.Generator) -> np.ndarray:
    """[V, 4, 4] views of a robot driving past the tree on both sides of the row (x axis).

    The first ceil(V / 2) views drive +x on the side y < 0, the rest drive back (-x) on the side y > 0; on both
    passes the camera looks to the robot's left, at the row centre line, pitched ``camera_pitch_deg`` up. Views
    are evenly spaced along each pass (:func:`row_drive`: the tree enters and leaves the view). Height, standoff,
    yaw, pitch and roll jitter smoothly along the path (``row_jitter``, :data:`ROW_JITTER_STD`).

    Raises:
        SynthError: ``row_standoff_m`` puts the camera inside the crown.
    """
    drive = row_drive(scene, config)
    n = config.views
    n_out = (n + 1) // 2
    poses = np.zeros((n, 4, 4))
    for side, first, m in ((-1.0, 0, n_out), (1.0, n_out, n - n_out)):
        if m == 0:
            continue
        frac = np.arange(m) / (m - 1) if m > 1 else np.full(1, 0.5)
        s = frac * drive.length_m                           # distance driven on this pass
        x = -side * (s - 0.5 * drive.length_m)              # side -1 drives +x, side +1 drives -x
        j_h, j_d, j_yaw, j_pitch, j_roll = (_smooth_jitter(rng, s, config.row_jitter * std) for std in ROW_JITTER_STD)
        yaw = np.arctan2(-side, 0.0) + np.radians(j_yaw)    # facing the row centre line
        pitch = np.radians(drive.pitch_deg + j_pitch)
        roll = np.radians(j_roll)
        forward = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1)
        right = np.stack([np.sin(yaw), -np.cos(yaw), np.zeros(m)], axis=1)
        up = np.cross(right, forward)
        c, s_ = np.cos(roll)[:, None], np.sin(roll)[:, None]
        block = poses[first:first + m]
        block[:, :3, 0] = c * right + s_ * up
        block[:, :3, 1] = -s_ * right + c * up
        block[:, :3, 2] = -forward
        block[:, :3, 3] = np.stack([x, side * (drive.standoff_m + j_d), drive.height_m + j_h], axis=1)
        block[:, 3, 3] = 1.0
    return poses


def make_poses(scene: Scene, config: SynthConfig) -> np.ndarray:
    """[V, 4, 4] camera-to-world poses (OpenGL axes) of ``config.trajectory``, deterministic in the seed."""
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0xCA3]))
    if config.trajectory == 'row':
        return row_poses(scene, config, rng)
    return hemisphere_poses(scene, config, rng)
