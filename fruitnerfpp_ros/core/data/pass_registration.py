"""Register a row drive's return pass onto its first pass on the fruit both see, before training.

A robot drives one side of a row, turns, and drives back on the other. Wheel odometry has drifted by then, so the
two passes' poses disagree by a rigid offset of centimetres and a degree or so (``synth --pass-offset``). The
feature alignment (:mod:`.pose_alignment`) cannot see it: no feature is seen from both sides. From about 4-5 cm
the fruit seen from both sides is counted twice (apple_row_60: F1 0.923 at no drift, 0.687 at 5 cm / 1 deg;
docs/results/pose_refinement.md). The fruit masks of both sides do see the same fruit, so their visual hulls must
meet:

1. The training views split into two passes by heading: a row drive's views look across the row, one pass one
   way, the other the opposite way. Views that look in many directions (a hemisphere) have no passes, and nothing
   is done.
2. Per pass, a visual-hull vote of its fruit masks over a voxel grid of ``voxel_diameters`` fruit diameters (the
   vote of :mod:`.scene_scale`): a voxel is fruit for a pass when enough of its views put it on a fruit mask.
3. Moving a pass's cameras by a rigid transform moves its fruit voxels by the same transform, so every offset of
   the later pass (along the row, across it, vertical, and a yaw about the fruit's centre) is scored at once by
   the voxels both passes call fruit after moving the later pass's voxels (no view is projected again).
4. The best offset is applied only when it beats no offset by ``min_gain`` and by ``min_gain_share`` of the fruit
   voxels: on exact poses the best offset gains 0-3 % by chance (the masks' noise; the suites' rows and five more),
   on a drift of 5 cm it doubles the score (docs/results/pose_refinement.md, session 36).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.scene_scale import ScaleConfig, fruit_voxel_mask, vote_fruit_masks
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['PassRegistrationConfig', 'PassRegistration', 'split_passes', 'register_passes']


#: A view looks across the ground when its viewing direction projected on the ground is at least this long (it is
#: within about 73 deg of level).
_LEVEL = 0.3


@dataclass(frozen=True)
class PassRegistrationConfig:
    """Registration of a row drive's return pass onto its first pass (see the module docstring)."""

    enabled: bool = True
    """Look for two passes and register them; off keeps the poses as they are."""
    heading_spread_deg: float = 60.0
    """Views whose heading (the optical axis on the ground plane) is within this of the row's across-row axis
    belong to a pass; at least ``pass_share`` of the views must, or there are no passes (a hemisphere)."""
    pass_share: float = 0.9
    """See ``heading_spread_deg``."""
    min_pass_views: int = 4
    """Each pass needs at least this many training views."""
    voxel_diameters: float = 0.33
    """Voxel size of the vote, in fruit diameters."""
    max_voxels: int = 4_000_000
    """The vote's voxel grows when the scene box would hold more voxels than this."""
    max_shift_m: tuple[float, float, float] = (0.25, 0.08, 0.08)
    """Offsets searched along the row, across it and vertically (m, either way)."""
    max_yaw_deg: float = 3.0
    """Yaw offsets searched about the vertical through the fruit's centre (deg, either way)."""
    yaw_step_deg: float = 0.5
    """Yaw step of the search's fine pass (the coarse pass steps twice this and one voxel; the fine pass half a
    voxel, around the coarse pass's best)."""
    min_gain: float = 1.15
    """The best offset is applied when its score is at least this times the score of no offset ..."""
    min_gain_share: float = 0.05
    """... and exceeds it by at least this share of the smaller pass's fruit voxels: where the two sides' masks
    hold different fruit (dense foliage hides each fruit from one side), no offset makes them meet, and a score
    of 18 voxels against 1 is chance (mango_row_80)."""
    min_pass_voxels: int = 50
    """Each pass needs this many fruit voxels to register on."""

    def __post_init__(self) -> None:
        if not 0 < self.heading_spread_deg < 90 or not 0 < self.pass_share <= 1:
            raise ConfigError('pass_registration: heading_spread_deg must be in (0, 90) and pass_share in (0, 1]')
        if self.voxel_diameters <= 0 or self.max_voxels < 1000 or self.yaw_step_deg <= 0:
            raise ConfigError('pass_registration: voxel_diameters and yaw_step_deg must be > 0, max_voxels >= 1000')
        if len(self.max_shift_m) != 3 or min(self.max_shift_m) < 0 or self.max_yaw_deg < 0:
            raise ConfigError(f'pass_registration: max_shift_m must be three values >= 0 and max_yaw_deg >= 0, got '
                              f'{self.max_shift_m}, {self.max_yaw_deg}')
        if self.min_gain < 1 or self.min_gain_share < 0 or self.min_pass_views < 1 or self.min_pass_voxels < 1:
            raise ConfigError('pass_registration: min_gain must be >= 1, min_gain_share >= 0, min_pass_views and '
                              'min_pass_voxels >= 1')


@dataclass(frozen=True)
class PassRegistration:
    """The outcome.

    Attributes:
        moved_views: the later pass's views (dataset indices: its training views, and when applied its held-out
            views too, so that they are rendered where the training views are), empty when there are no passes.
        transform: [4, 4] world transform to apply to those views' camera-to-world poses (identity when not
            applied).
        report: figures for the run directory (passes, scores, the offset, applied or why not).
    """

    moved_views: np.ndarray
    transform: np.ndarray
    report: dict

    @property
    def applied(self) -> bool:
        return bool(self.report.get('applied'))


def split_passes(T_world_camera: np.ndarray, views: np.ndarray, config: PassRegistrationConfig
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | str:
    """The two passes of a row drive: (first pass's views, later pass's views, up, across-row axis), or why there
    are none.

    Args:
        T_world_camera: [V, 4, 4] camera-to-world poses, OpenGL camera axes (the camera looks along -z, y up).
        views: the views to split (dataset indices).
    """
    T = np.asarray(T_world_camera, np.float64)[views]
    up = T[:, :3, 1].mean(0)
    if np.linalg.norm(up) < 0.5:
        return 'the cameras share no up direction'
    up /= np.linalg.norm(up)
    heading, length = _headings(T, up)
    level = length > _LEVEL
    if level.sum() < 2 * config.min_pass_views:
        return 'too few views look across the ground'
    heading = heading[level] / length[level, None]
    across = np.linalg.eigh(heading.T @ heading)[1][:, -1]
    along = heading @ across
    if np.mean(np.abs(along) >= math.cos(math.radians(config.heading_spread_deg))) < config.pass_share:
        return 'the views look in many directions (no passes)'
    side = np.zeros(len(views), dtype=int)
    side[level] = np.sign(along).astype(int)
    first, later = views[side < 0], views[side > 0]
    if min(len(first), len(later)) < config.min_pass_views:
        return f'one pass only ({len(first)} and {len(later)} views each way)'
    if later.min() < first.min():  # the later pass is the one recorded second
        first, later, across = later, first, -across
    return first, later, up, across


def _yaw_rotations(up: np.ndarray, yaws_deg: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(np.radians(yaws_deg)[:, None] * up[None]).as_matrix()


def _score(occupied: torch.Tensor, origin: torch.Tensor, voxel: float, points: torch.Tensor, pivot: torch.Tensor,
           rotations: torch.Tensor, shifts: torch.Tensor, chunk_points: int = 4_000_000) -> torch.Tensor:
    """Per (rotation, shift) pair the number of ``points`` [N, 3] that land on ``occupied`` voxels once turned by
    the rotation about ``pivot`` and shifted; [R, S]."""
    dims = torch.tensor(occupied.shape, device=points.device)
    flat = occupied.reshape(-1)
    turned = torch.einsum('rij,nj->rni', rotations, points - pivot) + pivot - origin        # [R, N, 3]
    out = torch.zeros(len(rotations), len(shifts), dtype=torch.long, device=points.device)
    step = max(1, chunk_points // max(1, len(points)))
    for r in range(len(rotations)):
        for s0 in range(0, len(shifts), step):
            moved = torch.floor((turned[r][None] + shifts[s0:s0 + step, None]) / voxel).long()  # [S, N, 3]
            inside = ((moved >= 0) & (moved < dims)).all(-1)
            index = (moved[..., 0] * dims[1] + moved[..., 1]) * dims[2] + moved[..., 2]
            out[r, s0:s0 + step] = (flat[index.clamp(0, len(flat) - 1)] & inside).sum(1)
    return out


def register_passes(dataset: SceneDataset, box: np.ndarray, fruit_diameter_m: float, config: PassRegistrationConfig,
                    scale: ScaleConfig = ScaleConfig(), *, device: torch.device | str = 'cpu') -> PassRegistration:
    """The rigid offset of the later pass's poses that makes both passes' fruit meet (see the module docstring).

    Args:
        dataset: the loaded dataset (masks, intrinsics, the poses to start from: the pose alignment's, when it
            ran); its training views are registered.
        box: [2, 3] the scene box (m) to vote over.
        fruit_diameter_m: the scene's fruit diameter (the vote's voxel follows from it).
        config: the search and its gate.
        scale: the fruit-voxel thresholds of the scene measurement (``min_views``, ``min_fraction``,
            ``min_seen_share``).
        device: where the vote and the search run.
    """
    device = torch.device(device)
    views = np.asarray(dataset.train_indices, dtype=np.int64)

    def kept(reason: str, moved: np.ndarray | None = None, **figures) -> PassRegistration:
        moved = np.zeros(0, np.int64) if moved is None else moved
        return PassRegistration(moved, np.eye(4), {'applied': False, 'reason': reason, **figures})

    passes = split_passes(dataset.T_world_camera.double().numpy(), views, config)
    if isinstance(passes, str):
        return kept(passes)
    first, later, up, across = passes
    box = np.asarray(box, np.float64)
    volume = float(np.prod(box[1] - box[0]))
    voxel = max(config.voxel_diameters * fruit_diameter_m, (volume / config.max_voxels) ** (1 / 3))
    resolution = max(8, int(math.ceil(float((box[1] - box[0]).max()) / voxel)))
    votes = [vote_fruit_masks(dataset, [int(v) for v in side], box, resolution, device) for side in (first, later)]
    fruit = [fruit_voxel_mask(v, scale.min_views, scale.min_fraction, scale.min_seen_share) for v in votes]
    counts = [int(f.sum()) for f in fruit]
    figures = {'views': [len(first), len(later)], 'fruit_voxels': counts, 'voxel_m': round(votes[0].voxel, 4)}
    if min(counts) < config.min_pass_voxels:
        return kept('too few fruit voxels in a pass', later, **figures)
    voxel = votes[0].voxel
    occupied = fruit[0].reshape(votes[0].shape)
    origin = torch.as_tensor(box[0], dtype=torch.float32, device=device)
    points = votes[1].centres[fruit[1]]
    pivot = torch.cat([votes[0].centres[fruit[0]], points]).mean(0)
    along = np.cross(across, up)
    axes = np.stack([along, across, up])                                                # [3, 3] rows
    limits = np.asarray(config.max_shift_m, np.float64)

    def search(yaws: np.ndarray, shifts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Scores [R * S] of every yaw (deg) and shift [S, 3] (along, across, up; m) kept in the search range."""
        yaws = yaws[np.abs(yaws) <= config.max_yaw_deg + 1e-9]
        shifts = shifts[np.all(np.abs(shifts) <= limits + 1e-9, axis=1)]
        scores = _score(occupied, origin, voxel, points, pivot,
                        torch.as_tensor(_yaw_rotations(up, yaws), dtype=torch.float32, device=device),
                        torch.as_tensor(shifts @ axes, dtype=torch.float32, device=device)).cpu().numpy()
        return scores.ravel(), np.repeat(yaws, len(shifts)), np.tile(shifts, (len(yaws), 1))

    def product(*axes_values: np.ndarray) -> np.ndarray:
        return np.stack(np.meshgrid(*axes_values, indexing='ij'), -1).reshape(-1, len(axes_values))

    # coarse: one voxel and two yaw steps apart; fine: half a voxel and one yaw step around the coarse best
    coarse_yaw = 2.0 * config.yaw_step_deg
    coarse = search(np.arange(-math.floor(config.max_yaw_deg / coarse_yaw + 1e-9),
                              math.floor(config.max_yaw_deg / coarse_yaw + 1e-9) + 1) * coarse_yaw,
                    product(*(np.arange(-n, n + 1) * voxel for n in np.floor(limits / voxel + 1e-9))))
    zero = int(coarse[0][(coarse[1] == 0) & np.all(coarse[2] == 0, axis=1)][0])
    top = int(np.argmax(coarse[0]))
    half = np.array([-0.5, 0.0, 0.5])
    fine = search(coarse[1][top] + half * coarse_yaw, coarse[2][top] + product(half, half, half) * voxel)
    scores, yaws, shifts = (np.concatenate(pair) for pair in zip(coarse, fine))
    # the best score; among equal ones the smallest offset (in search-range units)
    size = (np.abs(shifts) / np.maximum(limits, 1e-9)).sum(1) + np.abs(yaws) / max(config.max_yaw_deg, 1e-9)
    i = int(np.lexsort((size, -scores))[0])
    best = int(scores[i])
    figures.update(score_zero=zero, score_best=best, gain=round(best / max(zero, 1), 3),
                   offset_m=np.round(shifts[i], 4).tolist(), yaw_deg=float(yaws[i]),
                   pivot=np.round(pivot.double().cpu().numpy(), 4).tolist())
    if best < config.min_gain * max(zero, 1) or best - zero < config.min_gain_share * min(counts):
        return kept(f'no offset beats none by {config.min_gain}x and {config.min_gain_share} of the fruit voxels',
                    later, **figures)
    transform = np.eye(4)
    transform[:3, :3] = _yaw_rotations(up, yaws[i:i + 1])[0]
    p = pivot.double().cpu().numpy()
    transform[:3, 3] = p - transform[:3, :3] @ p + shifts[i] @ axes
    held_out = np.asarray(dataset.eval_indices, dtype=np.int64)
    moved = np.union1d(later, held_out[_looking_across(dataset.T_world_camera.double().numpy()[held_out], up,
                                                       across)])
    return PassRegistration(moved, transform, {'applied': True, **figures})


def _headings(T_world_camera: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The views' viewing directions projected on the ground [V, 3] (OpenGL axes: the camera looks along -z) and
    their lengths [V] (1 for a level camera, 0 looking straight up or down)."""
    forward = -np.asarray(T_world_camera, np.float64).reshape(-1, 4, 4)[:, :3, 2]
    heading = forward - (forward @ up)[:, None] * up
    return heading, np.linalg.norm(heading, axis=1)


def _looking_across(T_world_camera: np.ndarray, up: np.ndarray, across: np.ndarray) -> np.ndarray:
    """[V] bool: the views that look across the ground along ``across`` (a pass's side, as :func:`split_passes`
    tells the passes apart)."""
    heading, length = _headings(T_world_camera, up)
    return (length > _LEVEL) & (heading @ across > 0)
