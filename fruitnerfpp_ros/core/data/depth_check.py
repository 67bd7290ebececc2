"""Do the views' depth images agree with each other? A check run before training, so garbage depth never trains.

Each checked view's depth pixels (a regular subsample) are lifted to world points and projected into its
neighbouring views (nearest camera centres, facing the same way). In a neighbour with a depth at that pixel, the
point either **agrees** (its depth there matches the neighbour's within the sensor's uncertainty plus a pixel's
footprint), **contradicts** (it lies clearly in front of what the neighbour sees: the neighbour looks through it)
or is **occluded** (behind the neighbour's surface: no evidence either way). A view's agreement is
agree / (agree + contradict). Real depth agrees except at depth edges and along noise (0.8-1.0 on the synthetic
scenes, stereo noise included); random or misaligned depth contradicts about as often as it lies behind (near 0).
The worst view below the threshold is dropped, the others are scored again without it as a neighbour, and so on
(a broken view's surfaces also contradict its good neighbours' points). A view with too few decided points (no
overlapping neighbour with depth left) is kept: there is nothing against it. When more than half of the views
are dropped, the sensor itself is broken and no view's depth is used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

__all__ = ['DepthViewCheck', 'check_depth_views']

#: Pixels of a neighbour's image a point may land from the surface it belongs to (nearest-pixel lookup, edges).
_FOOTPRINT_PX = 2.0
#: Fewest decided (agreeing or contradicting) points for a view's agreement to count.
_MIN_DECIDED = 20


@dataclass(frozen=True)
class DepthViewCheck:
    """The outcome of :func:`check_depth_views`.

    Attributes:
        views: [C] the view indices checked (those with depth).
        agreement: [C] fraction of each view's decided points that agree with the neighbours (NaN: too few decided).
        decided: [C] decided points per view.
        used: [C] bool, the view's depth is used for training.
        min_agreement: the threshold applied.
    """

    views: np.ndarray
    agreement: np.ndarray
    decided: np.ndarray
    used: np.ndarray
    min_agreement: float

    @property
    def rejected_views(self) -> list[int]:
        """Views whose depth disagrees with their neighbours' (trained without depth)."""
        return [int(v) for v in self.views[~self.used]]

    def summary(self) -> str:
        """One line for the log."""
        measured = self.agreement[np.isfinite(self.agreement)]
        median = f'{float(np.median(measured)):.2f}' if len(measured) else 'n/a'
        text = (f'depth of {int(self.used.sum())}/{len(self.views)} views agrees with the neighbouring views '
                f'(median agreement {median}, threshold {self.min_agreement:.2f})')
        if len(self.views) and not self.used.any():
            text += '; the depth disagrees between most views (a broken, misaligned or mis-scaled sensor): ' \
                    'trained without depth'
        elif not self.used.all():
            shown = ', '.join(map(str, self.rejected_views[:12])) + (' ...' if len(self.rejected_views) > 12 else '')
            text += f'; trained without the depth of views {shown}'
        return text

    def to_json(self) -> dict:
        return {'views': self.views.tolist(), 'agreement': [None if not np.isfinite(a) else round(float(a), 4)
                                                            for a in self.agreement],
                'decided': self.decided.tolist(), 'used': self.used.tolist(), 'min_agreement': self.min_agreement,
                'summary': self.summary()}


def _neighbours(T_world_camera: torch.Tensor, views: torch.Tensor, count: int) -> list[torch.Tensor]:
    """For each of ``views``, up to ``count`` other views (indices into ``views``) with the nearest camera centres
    among those facing within 90 degrees of it."""
    centres = T_world_camera[views, :3, 3]
    forward = -T_world_camera[views, :3, 2]  # OpenGL cameras look along -z
    distance = torch.cdist(centres, centres)
    distance = distance + torch.where((forward @ forward.T) > 0.0, 0.0, float('inf'))
    distance.fill_diagonal_(float('inf'))
    nearest, index = torch.topk(distance, k=min(count, len(views) - 1), largest=False)
    return [row[torch.isfinite(d)] for d, row in zip(nearest, index)]


def check_depth_views(depths: torch.Tensor, T_world_camera: torch.Tensor, intrinsics: torch.Tensor,
                      sigma_m: Callable[[torch.Tensor], torch.Tensor], *, min_agreement: float = 0.5,
                      neighbours: int = 4, points_per_view: int = 2048) -> DepthViewCheck:
    """Cross-check the depth images of the views that have one.

    Args:
        depths: [V, H, W] depth along the optical axis, metres, 0 = no return.
        T_world_camera: [V, 4, 4] camera-to-world poses, OpenGL axes.
        intrinsics: [V, 4] fl_x, fl_y, cx, cy (top-left image corner at 0, 0).
        sigma_m: depth (m) -> its standard deviation (m), the sensor model.
        min_agreement: views agreeing less are not used.
        neighbours: views each view is checked against.
        points_per_view: depth pixels lifted per view (a regular subsample of its valid ones).
    """
    depths, poses, K = depths.float().cpu(), T_world_camera.float().cpu(), intrinsics.float().cpu()
    views = torch.nonzero((depths > 0).flatten(1).any(1)).squeeze(1)
    n, (height, width) = len(views), depths.shape[1:]
    votes = np.zeros((n, n, 2), np.int64)  # [view, neighbour] -> (agreeing, contradicting) lookups
    if n >= 2:
        for row, (view, nearest) in enumerate(zip(views.tolist(), _neighbours(poses, views, neighbours))):
            if len(nearest):
                votes[row, nearest.numpy()] = _view_votes(view, views[nearest], depths, poses, K, sigma_m,
                                                          points_per_view, height, width)
    # Peel off the worst view while one disagrees: a broken view also makes its good neighbours look bad (their
    # points land in front of its wrong surfaces), until it no longer counts as a neighbour.
    rejected = np.zeros(n, bool)
    while True:
        agreement, decided = _scores(votes, rejected)
        bad = np.flatnonzero(~rejected & (agreement < min_agreement))
        if not len(bad):
            break
        rejected[bad[np.argmin(agreement[bad])]] = True
    if rejected.sum() > n / 2:  # most views disagree: the sensor itself is broken, none of its depth is used
        rejected[:] = True
    return DepthViewCheck(views.numpy(), agreement, decided, ~rejected, float(min_agreement))


def _scores(votes: np.ndarray, rejected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(agreement [n] (NaN: fewer than ``_MIN_DECIDED`` decided lookups), decided lookups [n]) of each view against
    the neighbours not ``rejected``."""
    counted = votes[:, ~rejected].sum(axis=1)
    decided = counted.sum(axis=1)
    with np.errstate(invalid='ignore', divide='ignore'):
        agreement = np.where(decided >= _MIN_DECIDED, counted[:, 0] / decided, np.nan)
    return agreement, decided


def _view_votes(view: int, others: torch.Tensor, depths: torch.Tensor, poses: torch.Tensor, K: torch.Tensor,
                sigma_m: Callable[[torch.Tensor], torch.Tensor], count: int, height: int, width: int
                ) -> np.ndarray:
    """[M, 2] (agreeing, contradicting) lookups of ``view``'s depth points in each of the ``others`` views' depth
    images."""
    flat = torch.nonzero(depths[view].reshape(-1) > 0).squeeze(1)
    flat = flat[torch.linspace(0, len(flat) - 1, min(count, len(flat))).long()]
    row, col = (flat // width).float(), (flat % width).float()
    z = depths[view].reshape(-1)[flat]
    fx, fy, cx, cy = K[view]
    cam = torch.stack([(col + 0.5 - cx) / fx * z, -(row + 0.5 - cy) / fy * z, -z], dim=-1)
    world = cam @ poses[view, :3, :3].T + poses[view, :3, 3]
    # Into every neighbour at once: [M, P, 3] camera coordinates.
    R, t = poses[others, :3, :3], poses[others, :3, 3]
    local = torch.einsum('mji,mpj->mpi', R, world[None] - t[:, None])
    z_other = -local[..., 2]
    k = K[others][:, None]
    u = k[..., 0] * local[..., 0] / z_other.clamp_min(1e-6) + k[..., 2]
    v = -k[..., 1] * local[..., 1] / z_other.clamp_min(1e-6) + k[..., 3]
    inside = (z_other > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    ui, vi = u.clamp(0, width - 1).long(), v.clamp(0, height - 1).long()
    seen = depths[others[:, None].expand_as(ui), vi, ui]
    has = inside & (seen > 0)
    tolerance = 3.0 * torch.sqrt(sigma_m(z_other) ** 2 + sigma_m(seen) ** 2) + _FOOTPRINT_PX * z_other / k[..., 0]
    agree = has & ((z_other - seen).abs() <= tolerance)
    contradict = has & (z_other < seen - tolerance)
    return torch.stack([agree.sum(1), contradict.sum(1)], dim=1).numpy()
