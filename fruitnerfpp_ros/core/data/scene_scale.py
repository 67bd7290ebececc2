"""Metric scale of a scene from its masks and poses, before any training: where the fruit is, and how big.

Every quantity of the method that has a length (marching step, grid cells, export voxel, cluster sizes) follows
from the fruit diameter, not from the size of a box: a 6 m box and a 2 m box around the same tree must sample its
fruit alike.

How (a visual-hull vote of the fruit masks, vectorised over a voxel grid and all views):

1. Voxel centres over a search box (the region the cameras see) are projected into every view. A voxel *agrees*
   with a view when it projects onto a fruit pixel (the mask dilated by half the voxel's image footprint). A voxel
   that at least ``min_views`` views and ``min_fraction`` of the views that see it agree with, and that at least
   ``min_seen_share`` of the best-seen voxel's views see, is a fruit voxel: a real fruit is on a fruit pixel
   wherever it is not hidden; empty space only by chance (and space seen by a few views only agrees by chance most
   easily). A coarse vote over the whole search box finds the fruit region, finer ones inside it (each over the
   region the previous found, ``refine_votes``) the fruit voxels.
2. Each fruit voxel is on the fruit mask of the views that agree with it; the median distance of a mask's fruit
   voxels from its camera is that mask's depth, and ``depth * equivalent diameter in pixels / focal length`` its
   diameter in metres. Leaves hide parts of fruits, so the masks are smaller than the fruit: a high percentile of
   the per-mask diameters is the estimate.
3. The fruit region is the box of the fruit voxels' 2nd-98th percentiles (stray agreeing voxels do not stretch
   it), grown by one fruit diameter (the percentiles cut the fruit at the crown's edges). Fruit that leaves hide
   from most views would be left out of it: the region also holds voxels that fewer views agree with, when those
   views look at them from directions spread wide enough to place them (``region_fraction``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['ScaleConfig', 'SceneScale', 'SceneVotes', 'FruitVotes', 'dilate_square', 'estimate_scene_scale',
           'fruit_votes', 'fruit_voxel_mask', 'project_points', 'vote_fruit_masks']


@dataclass(frozen=True)
class ScaleConfig:
    """How the fruit size and region are found (or given)."""

    fruit_diameter_m: float | None = None
    """A known fruit diameter (m) to use as it is; None = measured from the masks and poses."""
    diameter_range_m: tuple[float, float] = (0.02, 0.25)
    """The fruit diameters (m) a measurement in metres can give; see ``outside_range``."""
    outside_range: Literal['pose_units', 'clamp'] = 'pose_units'
    """A measured diameter outside ``diameter_range_m``: ``pose_units`` takes the poses to be in other units than
    metres (a COLMAP or nerfstudio reconstruction, a scene modelled in centimetres) and uses the measurement as it
    is: every length of the method follows the fruit size in the poses' units, and the few lengths given in metres
    (``data.box_margin_m``, ``render.near``, ...) are converted with ``default_diameter_m`` as the fruit's size in
    metres (``SceneScale.units_per_metre``). ``clamp`` uses the range's nearer end (the poses are in metres and the
    measurement is off). A 30-apple tree with its poses in units of 20 m / 5 m / 20 cm / 5 cm: ``clamp`` F1 0.18 /
    0.97 / 1.00 / 0.60, ``pose_units`` 1.00 every time (docs/results/robustness.md)."""
    default_diameter_m: float = 0.07
    """Used when nothing can be measured (too few fruit voxels or masks), with a warning in the result."""
    coarse_resolution: int = 64
    """Voxels along the longest side of the search box in the first vote."""
    fine_resolution: int = 96
    """Voxels along the longest side of the fruit region in the second vote."""
    min_views: int = 3
    """A fruit voxel agrees with at least this many views."""
    min_fraction: float = 0.7
    """... and with at least this fraction of the views that see it (fine vote; the coarse vote uses half)."""
    region_fraction: float | None = 0.35
    """The fruit region (the refining votes' boxes, and the scene box cut from it) also holds the voxels that agree
    with at least this fraction of the views that see them when their agreeing views look at them from directions
    spread over ``region_view_angle_deg``; the diameter is measured on the ``min_fraction`` voxels only. Fruit
    inside dense foliage agrees with few of the views that see it (leaves hide it from most): at the true mango
    centres of the suite a median of 40 %, so the ``min_fraction`` voxels held one side of the crown only and 20 %
    of the mangoes lay outside the scene box (docs/results/accuracy_suite.md). None = ``min_fraction`` voxels only."""
    region_view_angle_deg: float = 60.0
    """See ``region_fraction``: the agreeing views' directions must not lie along one line: the largest eigenvalue
    of their mean d d^T is at most cos^2(angle / 2), as for two views this angle apart. Space in front of or behind
    a fruit agrees with the views looking through it, from one side or from both sides of a row, all along one
    line; the fruit itself with views from many directions."""
    min_seen_share: float = 0.25
    """... and is seen by at least this share of the views that see the best-seen voxel."""
    diameter_percentile: float = 75.0
    """Percentile of the per-mask diameters taken as the fruit diameter (masks are cut by leaves)."""
    min_mask_pixels: int = 12
    """Masks with fewer pixels are not measured (their size is mostly quantisation)."""
    refine_votes: int = 2
    """Further fine votes, each over the fruit region the previous one found (finer voxels as the region shrinks).
    The first fine vote spans the coarse vote's candidates, which the views of a row drive stretch along their
    viewing direction: at a 3 m standoff it spanned 13 m, its voxels (14 cm) twice the fruit, and the region and
    the masks' depths came out too large (pear_row_far: region 3.3 m across the row for a 1.2 m crown, diameter
    99 mm for 68 mm; after two more votes 1.2 m (1.3 m grown) and 77 mm; docs/results/accuracy_suite.md)."""
    refine_min_share: float = 0.5
    """A refining vote is kept only when it holds at least this share of the voxels the vote before it held. Over
    a tighter box at the same resolution a vote finds more voxels on the same fruit, not fewer; far fewer means its
    finer cells lost the fruit that the coarser cells' wider mask dilation placed (fruit in dense foliage shows a
    few leaf gaps to each view, so a small cell on it agrees with few of the views that see it): mango_row_80 of
    the holdout suite held 185 voxels at 68 mm, then 7 at 14 mm, and the region shrank to a tenth of the crown.
    The vote before then stands. 0 = every refining vote is kept."""

    def __post_init__(self) -> None:
        lo, hi = self.diameter_range_m
        if not 0 < lo < hi:
            raise ConfigError(f'scale.diameter_range_m must be 0 < min < max, got {self.diameter_range_m}')
        if self.outside_range not in ('pose_units', 'clamp'):
            raise ConfigError(f'scale.outside_range must be pose_units or clamp, not {self.outside_range!r}')
        if self.fruit_diameter_m is not None and not lo <= self.fruit_diameter_m <= hi:
            raise ConfigError(f'scale.fruit_diameter_m {self.fruit_diameter_m} is outside diameter_range_m '
                              f'{self.diameter_range_m}')
        if self.coarse_resolution < 8 or self.fine_resolution < 8 or self.min_views < 1 or self.refine_votes < 0:
            raise ConfigError('scale: resolutions must be >= 8, min_views >= 1 and refine_votes >= 0')
        if self.region_fraction is not None and not 0 < self.region_fraction <= 1:
            raise ConfigError(f'scale.region_fraction must be in (0, 1], got {self.region_fraction}')
        if not 0 <= self.region_view_angle_deg < 180:
            raise ConfigError(f'scale.region_view_angle_deg must be in [0, 180), got {self.region_view_angle_deg}')
        if not 0 < self.min_fraction <= 1 or not 0 <= self.diameter_percentile <= 100 \
                or not 0 <= self.min_seen_share <= 1 or not 0 <= self.refine_min_share <= 1:
            raise ConfigError('scale: min_fraction, min_seen_share and refine_min_share must be in [0, 1] and '
                              'diameter_percentile in [0, 100]')


class SceneScale(NamedTuple):
    """The metric scale of one scene.

    Attributes:
        fruit_diameter_m: the fruit diameter every length of the method follows from.
        source: ``config`` (given), ``masks`` (measured), ``pose_units`` (measured outside ``diameter_range_m``
            and used as it is: the poses are not in metres), ``clamped`` (measured outside it, the range's end used:
            ``ScaleConfig.outside_range: clamp``) or ``default`` (nothing measurable).
        fruit_region: [2, 3] box (m) around the fruit voxels, or None when none was found.
        n_fruit_voxels: fruit voxels of the fine vote.
        n_masks_measured: masks whose diameter entered the estimate.
        units_per_metre: the poses' units in a metre: 1 for poses in metres; for ``pose_units`` the measured
            diameter over ``ScaleConfig.default_diameter_m`` (the lengths the config gives in metres are multiplied
            by it). ``fruit_diameter_m`` and ``fruit_region`` are in the poses' units.
    """

    fruit_diameter_m: float
    source: str
    fruit_region: np.ndarray | None
    n_fruit_voxels: int
    n_masks_measured: int
    units_per_metre: float = 1.0

    def to_json(self) -> dict:
        return {'fruit_diameter_m': round(self.fruit_diameter_m, 5), 'source': self.source,
                'fruit_region': None if self.fruit_region is None else np.round(self.fruit_region, 4).tolist(),
                'n_fruit_voxels': self.n_fruit_voxels, 'n_masks_measured': self.n_masks_measured,
                'units_per_metre': round(self.units_per_metre, 6)}


class FruitVotes(NamedTuple):
    """A visual-hull vote of fruit masks over a voxel grid (:func:`vote_fruit_masks`)."""

    centres: torch.Tensor      # [N, 3] voxel centres, the grid's C order (x slowest)
    seen: torch.Tensor         # [N] views that see each voxel
    agree: torch.Tensor        # [N] views whose (dilated) fruit mask holds it
    voxel: float               # voxel size, m
    moments: torch.Tensor      # [N, 6] sum of d d^T (xx yy zz xy xz yz), d: unit direction to an agreeing camera
    shape: tuple[int, int, int]  # voxels along x, y, z


def _grid(box: np.ndarray, resolution: int, device: torch.device) -> tuple[torch.Tensor, float, tuple[int, int, int]]:
    size = box[1] - box[0]
    voxel = float(size.max()) / resolution
    counts = np.maximum(1, np.ceil(size / voxel)).astype(int)
    axes = [torch.arange(n, device=device, dtype=torch.float32) * voxel + float(box[0][i]) + 0.5 * voxel
            for i, n in enumerate(counts)]
    shape = (int(counts[0]), int(counts[1]), int(counts[2]))
    return torch.stack(torch.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3), voxel, shape


def project_points(centres: torch.Tensor, T_world_camera: torch.Tensor, K: torch.Tensor, width: int, height: int
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(pixel column, row, depth along the optical axis, inside the image and in front) of world points."""
    R, c = T_world_camera[:3, :3], T_world_camera[:3, 3]
    cam = (centres - c) @ R                                  # OpenGL camera axes: the camera looks along -z
    depth = -cam[:, 2]
    safe = torch.where(depth > 1e-6, depth, torch.ones_like(depth))
    u = K[0] * cam[:, 0] / safe + K[2]
    v = -K[1] * cam[:, 1] / safe + K[3]
    inside = (depth > 1e-6) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    return u.long().clamp(0, width - 1), v.long().clamp(0, height - 1), depth, inside


def dilate_square(image: torch.Tensor, radius: int) -> torch.Tensor:
    """Max over the (2 radius + 1)^2 square around each pixel of ``image`` [N, C, H, W]: the square max pool done as
    a row pass and a column pass (the same values, 2k instead of k^2 comparisons a pixel for a k-wide square)."""
    k = 2 * radius + 1
    rows = F.max_pool2d(image, (1, k), stride=1, padding=(0, radius))
    return F.max_pool2d(rows, (k, 1), stride=1, padding=(radius, 0))


def vote_fruit_masks(dataset: SceneDataset, views: list[int], box: np.ndarray, resolution: int,
                     device: torch.device) -> FruitVotes:
    """How many of ``views`` see, and put on their fruit mask, each voxel of a grid over ``box`` with
    ``resolution`` voxels along its longest side (``dataset``'s poses)."""
    centres, voxel, shape = _grid(box, resolution, device)
    seen = torch.zeros(len(centres), dtype=torch.int32, device=device)
    agree = torch.zeros_like(seen)
    moments = torch.zeros(len(centres), 6, device=device)
    box_centre = torch.as_tensor(0.5 * (box[0] + box[1]), dtype=torch.float32, device=device)
    for view in views:
        T = dataset.T_world_camera[view].to(device)
        K = dataset.intrinsics[view].to(device)
        # dilate the fruit mask by half the voxel's footprint at the box centre's depth (at least one pixel)
        distance = float(torch.linalg.norm(T[:3, 3] - box_centre))
        radius = max(1, int(math.ceil(0.5 * voxel * float(K[0]) / max(distance, 1e-3))))
        fruit = dataset.semantic_masks[view].to(device, torch.float32)[None, None]
        dilated = dilate_square(fruit, radius)[0, 0] > 0
        u, v, _, inside = project_points(centres, T, K, dataset.width, dataset.height)
        if dataset.valid_masks is not None:
            inside &= dataset.valid_masks[view].to(device)[v, u]
        seen += inside
        agrees = torch.nonzero(inside & dilated[v, u]).squeeze(1)       # the few voxels on the fruit mask
        agree[agrees] += 1
        d = F.normalize(T[:3, 3] - centres[agrees], dim=1)
        moments.index_add_(0, agrees, torch.stack([d[:, 0] * d[:, 0], d[:, 1] * d[:, 1], d[:, 2] * d[:, 2],
                                                   d[:, 0] * d[:, 1], d[:, 0] * d[:, 2], d[:, 1] * d[:, 2]], 1))
    return FruitVotes(centres, seen, agree, voxel, moments, shape)


def largest_eigenvalue_sym3(m: torch.Tensor) -> torch.Tensor:
    """Largest eigenvalue of each symmetric 3x3 matrix given as [N, 6] (xx yy zz xy xz yz), in closed form.

    The trigonometric solution of the characteristic cubic (Smith 1961), computed in float64 and returned in the
    input's dtype. Elementwise, so it runs alike on every device: the batched ``torch.linalg.eigvalsh`` failed on
    CUDA (cusolver internal error) over the fine vote's voxels of a 300-view 512 px scene.
    """
    a = m.double()
    xx, yy, zz, xy, xz, yz = a.unbind(1)
    q = (xx + yy + zz) / 3.0
    off = xy * xy + xz * xz + yz * yz
    p = torch.sqrt(((xx - q) ** 2 + (yy - q) ** 2 + (zz - q) ** 2 + 2.0 * off) / 6.0)
    safe = torch.where(p > 1e-12, p, torch.ones_like(p))
    bx, by, bz = (xx - q) / safe, (yy - q) / safe, (zz - q) / safe
    cxy, cxz, cyz = xy / safe, xz / safe, yz / safe
    det = bx * (by * bz - cyz * cyz) - cxy * (cxy * bz - cyz * cxz) + cxz * (cxy * cyz - by * cxz)
    phi = torch.acos((0.5 * det).clamp(-1.0, 1.0)) / 3.0
    largest = torch.where(p > 1e-12, q + 2.0 * p * torch.cos(phi), q)  # p = 0: a multiple of the identity
    return largest.to(m.dtype)


def fruit_voxel_mask(votes: FruitVotes, min_views: int, min_fraction: float, min_seen_share: float,
                     min_angle_deg: float = 0.0) -> torch.Tensor:
    """[N] bool: the voxels at least ``min_views`` views and ``min_fraction`` of those that see them agree with,
    seen by ``min_seen_share`` of the best-seen voxel's views (and, with ``min_angle_deg``, from directions spread
    at least that wide)."""
    seen = votes.seen.float()
    out = ((votes.agree >= min_views) & (votes.agree.float() >= min_fraction * seen.clamp_min(1.0))
           & (seen >= min_seen_share * float(seen.max())))
    if min_angle_deg > 0 and bool(out.any()):
        m = votes.moments[out] / votes.agree[out].float().clamp_min(1.0)[:, None]
        largest = largest_eigenvalue_sym3(m)                 # 1: every agreeing view on one line through the voxel
        out[out.clone()] = largest <= math.cos(math.radians(0.5 * min_angle_deg)) ** 2
    return out


def _region(points: torch.Tensor, pad: float) -> np.ndarray:
    """Box of the 2nd-98th percentiles of ``points`` grown by ``pad`` (stray agreeing voxels do not stretch it)."""
    p = points.double().cpu().numpy()
    lo, hi = np.percentile(p, 2.0, axis=0), np.percentile(p, 98.0, axis=0)
    return np.stack([lo - pad, hi + pad])


def _mask_diameters(dataset: SceneDataset, views: list[int], fruit: torch.Tensor, min_pixels: int) -> np.ndarray:
    """Metric diameter of every instance mask holding fruit voxels: its median voxel depth times its equivalent
    diameter in pixels over the focal length."""
    out = []
    for view in views:
        T = dataset.T_world_camera[view].to(fruit.device)
        K = dataset.intrinsics[view].to(fruit.device)
        u, v, depth, inside = project_points(fruit, T, K, dataset.width, dataset.height)
        ids = dataset.instance_masks[view].to(fruit.device).long()
        hit = ids[v, u] * inside.long()
        if not bool((hit > 0).any()):
            continue
        labels, inverse = torch.unique(hit[hit > 0], return_inverse=True)
        depths = depth[hit > 0]
        order = torch.argsort(inverse * 1e6 + depths.double())  # per mask, voxels by depth
        counts = torch.bincount(inverse, minlength=len(labels))
        starts = torch.cumsum(counts, 0) - counts
        median_depth = depths[order][starts + counts // 2]
        area = torch.bincount(ids.reshape(-1), minlength=int(labels.max()) + 1)[labels].double()
        focal = math.sqrt(float(K[0]) * float(K[1]))
        diameter = 2.0 * torch.sqrt(area / math.pi) * median_depth.double() / focal
        out.append(diameter[area >= min_pixels].cpu().numpy())
    return np.concatenate(out) if out else np.zeros(0)


class SceneVotes(NamedTuple):
    """The finest vote of :func:`fruit_votes` and which of its voxels are fruit."""

    votes: FruitVotes
    fruit: torch.Tensor   # [N] bool, the fruit voxels (``min_fraction``): the diameter is measured on them
    held: torch.Tensor    # [N] bool, the fruit voxels and those placed by views spread wide (``region_fraction``)


def fruit_votes(dataset: SceneDataset, search_box: np.ndarray, config: ScaleConfig = ScaleConfig(), *,
                device: torch.device | str = 'cpu') -> SceneVotes | None:
    """The coarse vote over ``search_box``, then the fine and refining votes over the fruit region (the module
    doc), of ``dataset``'s training views; None when the coarse vote finds fewer than 4 candidate voxels."""
    device = torch.device(device)
    views = [int(v) for v in dataset.train_indices]
    coarse = vote_fruit_masks(dataset, views, np.asarray(search_box, np.float64), config.coarse_resolution, device)
    candidates = fruit_voxel_mask(coarse, config.min_views, 0.5 * config.min_fraction, config.min_seen_share)
    if int(candidates.sum()) < 4:
        return None

    def fruit_voxels(votes: FruitVotes) -> torch.Tensor:
        return fruit_voxel_mask(votes, config.min_views, config.min_fraction, config.min_seen_share)

    def held_voxels(votes: FruitVotes) -> torch.Tensor:
        """The voxels the region holds: the fruit voxels, and those placed by views spread wide enough."""
        if config.region_fraction is None:
            return fruit_voxels(votes)
        return fruit_voxels(votes) | fruit_voxel_mask(votes, config.min_views, config.region_fraction,
                                                      config.min_seen_share, config.region_view_angle_deg)

    fine = vote_fruit_masks(dataset, views, _region(coarse.centres[candidates], coarse.voxel),
                            config.fine_resolution, device)
    held = held_voxels(fine)
    for _ in range(config.refine_votes):
        if int(held.sum()) < 4:
            break
        finer = vote_fruit_masks(dataset, views, _region(fine.centres[held], fine.voxel), config.fine_resolution,
                                 device)
        finer_held = held_voxels(finer)
        if int(finer_held.sum()) < max(4.0, config.refine_min_share * int(held.sum())):
            break  # the finer cells lost the fruit (see refine_min_share): the vote before stands
        shrunk = finer.voxel < 0.9 * fine.voxel
        fine, held = finer, finer_held
        if not shrunk:  # the region no longer shrinks: another vote would repeat this one
            break
    return SceneVotes(fine, fruit_voxels(fine), held)


def estimate_scene_scale(dataset: SceneDataset, search_box: np.ndarray, config: ScaleConfig = ScaleConfig(), *,
                         device: torch.device | str = 'cpu') -> SceneScale:
    """The fruit diameter and fruit region of ``dataset`` (its training views), searched within ``search_box``.

    Args:
        dataset: the loaded dataset (semantic and instance masks, poses, intrinsics).
        search_box: [2, 3] region to search (m), e.g. where the cameras' views overlap.
        config: thresholds, or a given diameter.
        device: where the vote runs (a GPU makes 300 views of a fine grid take a second).
    """
    device = torch.device(device)
    views = [int(v) for v in dataset.train_indices]
    votes = fruit_votes(dataset, search_box, config, device=device)
    region, n_fruit, diameters = None, 0, np.zeros(0)
    if votes is not None:
        n_fruit = int(votes.fruit.sum())
        if int(votes.held.sum()) >= 4 and n_fruit >= 4:
            region = _region(votes.votes.centres[votes.held], votes.votes.voxel)
            diameters = _mask_diameters(dataset, views, votes.votes.centres[votes.fruit], config.min_mask_pixels)
    lo, hi = config.diameter_range_m
    units_per_metre = 1.0
    if config.fruit_diameter_m is not None:
        diameter, source = float(config.fruit_diameter_m), 'config'
    elif len(diameters) < 3:
        diameter, source = float(config.default_diameter_m), 'default'
    else:
        diameter = float(np.percentile(diameters, config.diameter_percentile))
        if lo <= diameter <= hi:
            source = 'masks'
        elif config.outside_range == 'clamp':
            diameter, source = float(np.clip(diameter, lo, hi)), 'clamped'
        else:
            source, units_per_metre = 'pose_units', diameter / config.default_diameter_m
    if region is not None:  # its percentiles cut the fruit at the crown's edges: the region holds them whole
        region = region + np.array([[-diameter], [diameter]])
    return SceneScale(diameter, source, region, n_fruit, 0 if source == 'config' else len(diameters),
                      units_per_metre)
