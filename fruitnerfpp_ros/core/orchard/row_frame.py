"""The row's own coordinates: ``s`` along the row, ``l`` across it, from the drive; what stretch a camera sees.

A robot drives along a tree row (one pass out, usually one back on the other side). The row axis is the driving
direction: the mean direction of the chords of the drive about ``baseline_m`` long (a chord and its reverse vote
alike; chords far off the first estimate, such as the turn between the passes, are dropped and the mean taken
again), so that a robot's sway from keyframe to keyframe does not tilt it; ``s`` grows in the direction of the
first pass. The row's centre line lies midway between the two passes when the cameras look at it from both sides,
else ``standoff_m`` ahead of the cameras (:class:`RowFrame`). A camera sees the stretch of the row between where
the left and right edges of its image cross the canopy (the centre line +- ``crown_half_depth_m``):
:func:`viewed_intervals`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fruitnerfpp_ros.errors import OrchardError

__all__ = ['RowFrame', 'estimate_row_frame', 'viewed_intervals', 'camera_forward']


@dataclass(frozen=True)
class RowFrame:
    """Row coordinates in the world's horizontal plane.

    Attributes:
        origin: [2] world xy of s = 0 on the row's centre line, metres.
        axis: [2] unit direction of growing s (the first pass's driving direction).
    """

    origin: np.ndarray
    axis: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        """[2] unit direction of growing l (left of the axis)."""
        return np.array([-self.axis[1], self.axis[0]])

    def along(self, points: np.ndarray) -> np.ndarray:
        """[N] s (m) of world points [N, 2 or 3]."""
        return (np.asarray(points, np.float64).reshape(len(points), -1)[:, :2] - self.origin) @ self.axis

    def across(self, points: np.ndarray) -> np.ndarray:
        """[N] l (m, signed distance from the centre line) of world points [N, 2 or 3]."""
        return (np.asarray(points, np.float64).reshape(len(points), -1)[:, :2] - self.origin) @ self.normal

    def world_xy(self, s: np.ndarray, l_m: np.ndarray | float = 0.0) -> np.ndarray:
        """[N, 2] world xy of row coordinates."""
        s = np.asarray(s, np.float64).reshape(-1)
        return self.origin + s[:, None] * self.axis + np.broadcast_to(l_m, s.shape)[:, None] * self.normal

    def to_json(self) -> dict[str, Any]:
        return {'origin': [round(float(v), 6) for v in self.origin], 'axis': [round(float(v), 9) for v in self.axis]}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> 'RowFrame':
        axis = np.asarray(data['axis'], np.float64)
        return cls(np.asarray(data['origin'], np.float64), axis / np.linalg.norm(axis))


def camera_forward(T_world_camera: np.ndarray) -> np.ndarray:
    """[N, 3] viewing directions of OpenGL camera-to-world poses [N, 4, 4] (-z)."""
    return -np.asarray(T_world_camera, np.float64)[:, :3, 2]


def _drive_axis(xy: np.ndarray, baseline_m: float) -> np.ndarray:
    """[2] unit driving direction of positions [N, 2] in drive order (its sign arbitrary; see the module)."""
    path = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    if path[-1] < 1e-3:
        raise OrchardError('the cameras do not move horizontally: no row axis')
    baseline = min(baseline_m, 0.5 * path[-1])
    end = np.searchsorted(path, path + baseline)
    ok = end < len(xy)
    chord = xy[end[ok]] - xy[np.flatnonzero(ok)]
    angle = np.arctan2(chord[:, 1], chord[:, 0])
    keep = np.ones(len(angle), bool)
    for _ in range(2):  # the mean of doubled angles, then again without the chords 30 degrees or more off it
        doubled = np.arctan2(np.sin(2 * angle[keep]).mean(), np.cos(2 * angle[keep]).mean())
        off = np.abs(np.angle(np.exp(1j * (2 * angle - doubled))))
        if (off < np.radians(60.0)).sum() < 2:
            break
        keep = off < np.radians(60.0)
    return np.array([np.cos(0.5 * doubled), np.sin(0.5 * doubled)])


def estimate_row_frame(T_world_camera: np.ndarray, *, standoff_m: float | None = None,
                       default_standoff_m: float = 2.0, baseline_m: float = 1.0) -> RowFrame:
    """The row frame of a drive, from its camera poses (in drive order).

    Args:
        T_world_camera: [N, 4, 4] camera-to-world poses (OpenGL), in the order they were taken.
        standoff_m: distance from the cameras to the row's centre line; None = measured when the cameras look at
            the row from both sides (midway between the passes), else ``default_standoff_m``.
        default_standoff_m: see ``standoff_m``.
        baseline_m: length of the chords of the drive whose mean direction is the row axis.

    Raises:
        OrchardError: fewer than 2 poses or no horizontal extent (a robot standing still).
    """
    T = np.asarray(T_world_camera, np.float64)
    if len(T) < 2:
        raise OrchardError(f'{len(T)} camera pose(s): a row needs a drive of at least 2')
    xy = T[:, :2, 3]
    centred = xy - xy.mean(axis=0)
    axis = _drive_axis(xy, baseline_m)
    progress = centred @ axis
    head = max(2, len(T) // 4)
    if progress[head - 1] < progress[0]:  # s grows in the first pass's direction
        axis = -axis
    normal = np.array([-axis[1], axis[0]])
    forward = camera_forward(T)[:, :2]
    look = np.sign(forward @ normal)            # +1: the camera looks towards +l
    lateral = centred @ normal
    if standoff_m is None and (look > 0).any() and (look < 0).any():
        centre = 0.5 * (np.median(lateral[look > 0]) + np.median(lateral[look < 0]))
    else:
        d = default_standoff_m if standoff_m is None else standoff_m
        centre = float(np.median(lateral + look * d))
    s0 = float(np.min(centred @ axis))
    origin = xy.mean(axis=0) + centre * normal + s0 * axis
    return RowFrame(origin, axis)


def viewed_intervals(frame: RowFrame, T_world_camera: np.ndarray, fl_x: np.ndarray, width: np.ndarray, *,
                     crown_half_depth_m: float = 0.6, max_range_m: float = 8.0) -> np.ndarray:
    """[N, 2] (s_min, s_max) of the row each camera sees: where its image's left and right edge rays, in the
    horizontal plane, cross the near and far sides of the canopy (centre line -+ ``crown_half_depth_m``); a ray
    that never gets there counts up to ``max_range_m``.

    Args:
        frame: the row frame.
        T_world_camera: [N, 4, 4] camera-to-world (OpenGL axes).
        fl_x: [N] horizontal focal lengths (px); width: [N] image widths (px).
        crown_half_depth_m: half the canopy's depth across the row.
        max_range_m: farthest distance a camera is taken to see.
    """
    T = np.asarray(T_world_camera, np.float64)
    half = 0.5 * np.asarray(width, np.float64) / np.asarray(fl_x, np.float64)
    forward, right = -T[:, :3, 2], T[:, :3, 0]
    s_cam, l_cam = frame.along(T[:, :3, 3]), frame.across(T[:, :3, 3])
    ends = []
    for sign in (-1.0, 1.0):
        ray = forward + sign * half[:, None] * right
        d_s, d_l = ray[:, :2] @ frame.axis, ray[:, :2] @ frame.normal
        norm = np.hypot(d_s, d_l) + 1e-12
        for target in (-crown_half_depth_m, crown_half_depth_m):
            t = np.where(np.abs(d_l) > 1e-9, (target - l_cam) / np.where(np.abs(d_l) > 1e-9, d_l, 1.0), np.inf)
            t = np.where(t > 0, np.minimum(t, max_range_m / norm), max_range_m / norm)
            ends.append(s_cam + t * d_s)
    ends_arr = np.stack(ends, axis=1)
    return np.stack([ends_arr.min(axis=1), ends_arr.max(axis=1)], axis=1)
