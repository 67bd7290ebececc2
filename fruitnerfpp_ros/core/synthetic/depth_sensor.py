"""A depth camera aligned to the colour camera: what a stereo RGB-D sensor (RealSense, ZED, OAK-D) returns.

``stereo`` (the default of ``--depth``) degrades the rendered depth z (along the optical axis) as stereo matching
does:

- **range noise** growing with range squared: sigma(z) = k z^2 / (f b), for a disparity noise of k pixels, the
  sensor's focal length f (its own pixels) and baseline b (``depth_disparity_noise_px``, ``depth_focal_px``,
  ``depth_baseline_m``; 0.08 px, 640 px, 5 cm: 1 cm at 2 m, 2.3 cm at 3 m);
- **holes at depth edges**: the farther pixel of every neighbouring pair whose depths differ by more than
  ``EDGE_JUMP`` of their range (the background strip one camera of the pair cannot see, and flying pixels);
- **holes on thin leaves**: ``LEAF_DROPOUT`` of the leaf pixels return nothing (too thin and too similar to match);
- **a maximum range** (``depth_max_range_m``) and no return from the sky.

``exact`` keeps the rendered depth (within range); ``random`` is garbage depth (uniform within the sensor's range
wherever it would return), to show that training notices and ignores it. No return is 0.
"""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.synthetic.config import DEPTH_MODELS
from fruitnerfpp_ros.core.synthetic.rasterizer import SURFACE_LEAF
from fruitnerfpp_ros.errors import SynthError

__all__ = ['DEPTH_MODELS', 'EDGE_JUMP', 'LEAF_DROPOUT', 'MIN_RANGE_M', 'stereo_sigma_m', 'sensed_depth']

#: Relative depth jump between neighbouring pixels that a stereo matcher cannot bridge (an occlusion edge).
EDGE_JUMP = 0.05
#: Share of leaf pixels without a return.
LEAF_DROPOUT = 0.5
#: Closest range the sensor measures, metres.
MIN_RANGE_M = 0.2


def stereo_sigma_m(depth_m: np.ndarray, *, disparity_noise_px: float, focal_px: float,
                   baseline_m: float) -> np.ndarray:
    """Standard deviation (m) of a stereo camera's depth at ``depth_m``: k z^2 / (f b)."""
    depth = np.asarray(depth_m, dtype=np.float64)
    return disparity_noise_px * depth * depth / (focal_px * baseline_m)


def _edge_holes(depth: np.ndarray) -> np.ndarray:
    """[H, W] bool: the farther pixel of each horizontal or vertical neighbour pair with a depth jump (sky = far)."""
    far = np.where(np.isfinite(depth), depth, np.inf)
    holes = np.zeros(depth.shape, bool)
    for axis in (0, 1):
        a = far[:-1] if axis == 0 else far[:, :-1]
        b = far[1:] if axis == 0 else far[:, 1:]
        with np.errstate(invalid='ignore'):
            jump = np.abs(a - b) > EDGE_JUMP * np.minimum(a, b)
        first = jump & (a > b)
        second = jump & (b > a)
        if axis == 0:
            holes[:-1] |= first
            holes[1:] |= second
        else:
            holes[:, :-1] |= first
            holes[:, 1:] |= second
    return holes


def sensed_depth(depth: np.ndarray, surface: np.ndarray, model: str, rng: np.random.Generator, *,
                 max_range_m: float, disparity_noise_px: float, focal_px: float, baseline_m: float) -> np.ndarray:
    """The depth image a sensor of ``model`` returns for a rendered view.

    Args:
        depth: [H, W] rendered depth along the optical axis, metres (inf = sky).
        surface: [H, W] what each pixel shows (``rasterizer.SURFACE_*``).
        model: ``exact``, ``stereo`` or ``random`` (see the module doc).
        rng: the sensor's own random stream.
        max_range_m: farthest return, metres.
        disparity_noise_px, focal_px, baseline_m: the stereo noise model.

    Returns:
        [H, W] float32 metres, 0 = no return.
    """
    z = np.asarray(depth, dtype=np.float64)
    returns = np.isfinite(z) & (z >= MIN_RANGE_M) & (z <= max_range_m)
    if model == 'exact':
        return np.where(returns, z, 0.0).astype(np.float32)
    if model == 'random':
        return np.where(returns, rng.uniform(MIN_RANGE_M, max_range_m, z.shape), 0.0).astype(np.float32)
    if model != 'stereo':
        raise SynthError(f'unknown depth model {model!r}; expected one of {", ".join(DEPTH_MODELS[1:])}')
    returns &= ~_edge_holes(z)
    returns &= ~((surface == SURFACE_LEAF) & (rng.random(z.shape) < LEAF_DROPOUT))
    sigma = stereo_sigma_m(np.where(returns, z, 0.0), disparity_noise_px=disparity_noise_px, focal_px=focal_px,
                           baseline_m=baseline_m)
    noisy = z + sigma * rng.standard_normal(z.shape)
    returns &= (noisy >= MIN_RANGE_M) & (noisy <= max_range_m)
    return np.where(returns, noisy, 0.0).astype(np.float32)
