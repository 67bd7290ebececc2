"""Configuration of the instance-mask segmenters (fallback, TorchScript model, Segment Anything)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['SegmenterConfig', 'SEGMENTER_METHODS']

#: Segmenter methods, in the order the CLI and the node list them.
SEGMENTER_METHODS: tuple[str, ...] = ('fallback', 'torchscript', 'sam')


@dataclass(frozen=True)
class SegmenterConfig:
    """Which segmenter turns an RGB image into per-image fruit instance ids, and its thresholds.

    ``fallback`` is the built-in, fruit-agnostic colour segmenter (no model, no torch); ``torchscript`` and ``sam``
    load a model from the local file ``checkpoint`` (nothing is ever downloaded).
    """

    method: Literal['fallback', 'torchscript', 'sam'] = 'fallback'
    """``fallback`` (built-in colour segmenter), ``torchscript`` (a TorchScript instance-segmentation model, see
    ``torchscript.py`` for its input/output contract) or ``sam`` (Segment Anything automatic mask generator; needs
    the ``segment_anything`` package)."""

    checkpoint: str = ''
    """Local model file for ``torchscript`` (a ``torch.jit.save`` file) and ``sam`` (a SAM ``.pth``); unused by
    ``fallback``."""

    device: str = 'auto'
    """Torch device of the model: auto (CUDA when present), cpu, cuda or cuda:N; unused by ``fallback``."""

    # ---------------------------------------------------------------- fallback: which pixels are fruit-coloured
    min_saturation: float = 0.64
    """HSV saturation ``(max - min) / max`` a fruit pixel needs, in [0, 1]. Sky, bark, soil and grey surfaces stay
    below it (synthetic: sky 0.16-0.49, soil 0.43, bark 0.53; fruits 0.69 (pear) to 0.93 (apple))."""

    min_value: float = 0.08
    """HSV value ``max(R, G, B) / 255`` a fruit pixel needs: the hue of darker pixels is 8-bit noise."""

    foliage_hue_sigmas: float = 3.0
    """Half-width of the excluded foliage hue band, in robust standard deviations of the dominant hue mode of the
    saturated pixels (the foliage). The spread is measured on the mode's far side from the fruit candidates."""

    foliage_min_half_width_deg: float = 12.0
    """Smallest half-width of the foliage hue band, degrees."""

    foliage_max_half_width_deg: float = 35.0
    """Largest half-width of the foliage hue band, degrees (a wide mode must not swallow yellow-green fruit)."""

    # ---------------------------------------------------------------- fallback: from pixels to instances
    opening_radius_fraction: float = 0.0
    """Radius of the morphological opening that removes stems, twigs and noise, as a fraction of the image's
    shorter side (at least 1 px when > 0; 0 = no opening)."""

    min_area_fraction: float = 2e-4
    """Instances smaller than this fraction of the image's pixels are dropped (also applies to ``torchscript`` and
    ``sam`` masks)."""

    min_area_px: int = 6
    """Floor of the minimum instance area, pixels."""

    min_fill_ratio: float = 0.2
    """Smallest ``area / bounding-box area`` of a fallback instance: thin diagonal branches are dropped."""

    max_elongation: float = 15.0
    """Instances whose area exceeds this many discs of their largest inscribed radius (twigs, stems, leaf edges:
    long and thin) are dropped; 0 = off."""

    split_depth_fraction: float = 0.35
    """Touching fruits are split (distance transform + watershed) when the neck between them is narrower than
    their blob's largest inscribed radius by at least this fraction of it (h-maxima depth); 0 = never split."""

    # ---------------------------------------------------------------- learned models (torchscript, sam)
    score_threshold: float = 0.5
    """Masks whose score (model confidence; SAM: predicted IoU) is below this are dropped, in [0, 1]."""

    mask_threshold: float = 0.5
    """A pixel belongs to a mask when its probability is at least this (logits are passed through a sigmoid)."""

    max_area_fraction: float = 0.05
    """``sam``: masks larger than this fraction of the image (foliage, ground, sky) are not fruit."""

    min_solidity: float = 0.85
    """``sam``: smallest ``area / convex-hull area`` of a fruit mask (fruits are compact, branches and leaf
    clusters are not)."""

    sam_model_type: Literal['vit_h', 'vit_l', 'vit_b'] = 'vit_b'
    """``sam``: the image-encoder size of the checkpoint (``vit_b`` for ``sam_vit_b_01ec64.pth``)."""

    sam_points_per_side: int = 32
    """``sam``: grid of point prompts per image side of the automatic mask generator."""

    def __post_init__(self) -> None:
        if self.method not in SEGMENTER_METHODS:
            raise ConfigError(f"SegmenterConfig: unknown method {self.method!r}; expected one of "
                              f"{', '.join(SEGMENTER_METHODS)}")
        unit = {'min_saturation': self.min_saturation, 'min_value': self.min_value,
                'score_threshold': self.score_threshold, 'mask_threshold': self.mask_threshold,
                'min_fill_ratio': self.min_fill_ratio, 'min_solidity': self.min_solidity,
                'split_depth_fraction': self.split_depth_fraction}
        for name, value in unit.items():
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f'SegmenterConfig: {name} must be in [0, 1], got {value}')
        if not self.foliage_hue_sigmas > 0:
            raise ConfigError('SegmenterConfig: foliage_hue_sigmas must be > 0')
        if not 0.0 <= self.foliage_min_half_width_deg <= self.foliage_max_half_width_deg <= 180.0:
            raise ConfigError('SegmenterConfig: need 0 <= foliage_min_half_width_deg <= foliage_max_half_width_deg '
                              '<= 180')
        if not 0.0 <= self.opening_radius_fraction < 0.5:
            raise ConfigError('SegmenterConfig: opening_radius_fraction must be in [0, 0.5)')
        if not 0.0 <= self.min_area_fraction < self.max_area_fraction <= 1.0:
            raise ConfigError('SegmenterConfig: need 0 <= min_area_fraction < max_area_fraction <= 1')
        if self.max_elongation < 0:
            raise ConfigError('SegmenterConfig: max_elongation must be >= 0')
        if self.min_area_px < 1:
            raise ConfigError('SegmenterConfig: min_area_px must be >= 1')
        if self.sam_points_per_side < 1:
            raise ConfigError('SegmenterConfig: sam_points_per_side must be >= 1')

    @classmethod
    def load(cls, path: str | Path | None = None, **overrides: Any) -> 'SegmenterConfig':
        """The config of the YAML ``path`` (defaults when None or empty), with the ``overrides`` that are set
        (None and '' leave the file's value): what the ``segment`` command and the node both do.

        Raises:
            ConfigError: an unreadable file or a bad value (the message names the file).
        """
        base = load_config(cls, path) if path else cls()
        return dataclasses.replace(base, **{k: v for k, v in overrides.items() if v not in (None, '')})

    def min_area_for(self, height: int, width: int) -> int:
        """Minimum instance area in pixels for an image of ``height`` x ``width``."""
        return max(self.min_area_px, int(round(self.min_area_fraction * height * width)))
