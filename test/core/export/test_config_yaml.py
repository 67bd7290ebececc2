"""config/export.yaml and config/clustering.yaml hold exactly the dataclass defaults and load through config_io."""

from __future__ import annotations

from pathlib import Path

import pytest

from fruitnerfpp_ros.cli.results import load_section
from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.errors import ConfigError

CONFIG = Path(__file__).resolve().parents[3] / 'config'


def test_yaml_files_match_the_defaults() -> None:
    assert load_config(ExportConfig, CONFIG / 'export.yaml') == ExportConfig()
    assert load_config(ClusterConfig, CONFIG / 'clustering.yaml') == ClusterConfig()


def test_sections_of_a_run_config_and_unknown_keys(tmp_path: Path) -> None:
    path = tmp_path / 'run.yaml'
    path.write_text('train: {seed: 3}\nexport: {fruit_threshold: 0.7}\nclustering: {lambda_e: 4.0}\n')
    assert load_section(ExportConfig, path, 'export').fruit_threshold == 0.7
    assert load_section(ClusterConfig, path, 'clustering').lambda_e == 4.0
    path.write_text('clustering: {lambda_f: 4.0}\n')
    with pytest.raises(ConfigError, match='lambda_f'):
        load_section(ClusterConfig, path, 'clustering')
