"""SegmenterConfig: YAML file, validation, factory errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.segmentation import FallbackSegmenter, SegmenterConfig, build_segmenter
from fruitnerfpp_ros.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]


def test_the_documented_yaml_is_the_defaults() -> None:
    assert load_config(SegmenterConfig, ROOT / 'config/segmentation.yaml') == SegmenterConfig()


@pytest.mark.parametrize('kwargs, message', [
    ({'method': 'mask_rcnn'}, "unknown method 'mask_rcnn'"),
    ({'min_saturation': 1.5}, 'min_saturation must be in'),
    ({'foliage_min_half_width_deg': 40.0}, 'foliage_min_half_width_deg <= foliage_max_half_width_deg'),
    ({'min_area_fraction': 0.2}, 'min_area_fraction < max_area_fraction'),
    ({'min_area_px': 0}, 'min_area_px must be >= 1'),
])
def test_bad_values_are_named(kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        SegmenterConfig(**kwargs)


def test_yaml_typos_are_named(tmp_path: Path) -> None:
    path = tmp_path / 'seg.yaml'
    path.write_text('method: fallback\nmin_saturaton: 0.5\n')
    with pytest.raises(ConfigError, match='min_saturaton'):
        load_config(SegmenterConfig, path)


def test_factory_builds_the_fallback_without_torch() -> None:
    assert isinstance(build_segmenter(SegmenterConfig()), FallbackSegmenter)
    assert SegmenterConfig().min_area_for(96, 96) == 6 and SegmenterConfig().min_area_for(1000, 1000) == 200
    # in a fresh interpreter (this one has torch loaded by other tests): the fallback path never imports it
    code = ('import sys, numpy as np; from fruitnerfpp_ros.core.segmentation import SegmenterConfig, build_segmenter; '
            'build_segmenter(SegmenterConfig())(np.zeros((8, 8, 3), np.uint8)); print("torch" in sys.modules)')
    assert subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True).stdout.strip() \
        == 'False'


def test_load_merges_the_file_with_the_overrides_that_are_set(tmp_path: Path) -> None:
    path = tmp_path / 'seg.yaml'
    path.write_text('method: fallback\nmin_saturation: 0.5\n')
    config = SegmenterConfig.load(path, method='torchscript', checkpoint='', device=None)
    assert (config.method, config.min_saturation) == ('torchscript', 0.5)
    assert config.checkpoint == SegmenterConfig().checkpoint and config.device == SegmenterConfig().device
    assert SegmenterConfig.load(None, method='sam') == SegmenterConfig(method='sam')
