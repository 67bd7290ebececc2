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


def test_every_reader_of_a_pipeline_file_rejects_a_misspelt_section(tmp_path: Path) -> None:
    from fruitnerfpp_ros.cli.train import resolve_train_config
    from fruitnerfpp_ros.nodes.params import pipeline_configs, settings_from_parameters
    path = tmp_path / 'run.yaml'
    path.write_text('trian: {seed: 3}\nexport: {fruit_threshold: 0.7}\n')
    readers = [lambda: resolve_train_config('tiny', path, section='train'),
               lambda: load_section(ExportConfig, path, 'export'),
               lambda: load_section(ClusterConfig, path, 'clustering'),
               lambda: pipeline_configs(settings_from_parameters({'preset': 'tiny', 'config_file': str(path)}))]
    for read in readers:
        with pytest.raises(ConfigError, match=r'run.yaml: unknown section\(s\) trian; expected only train, export'):
            read()
    path.write_text('export: 0.7\n')
    with pytest.raises(ConfigError, match='section export must be a mapping'):
        load_section(ExportConfig, path, 'export')


def test_behind_foliage_settings_are_checked(tmp_path: Path) -> None:
    path = tmp_path / 'run.yaml'
    path.write_text('export: {behind_foliage: some}\n')
    with pytest.raises(ConfigError, match=r"behind_foliage: 'some' is not one of \['none', 'unsurfaced', 'all'\]"):
        load_section(ExportConfig, path, 'export')
    with pytest.raises(ConfigError, match="behind_foliage must be none, unsurfaced or all, not 'some'"):
        ExportConfig(behind_foliage='some')
    with pytest.raises(ConfigError, match='behind_min_alpha'):
        ExportConfig(behind_min_alpha=0.0)
    path.write_text('export: {behind_foliage: none}\n')
    assert load_section(ExportConfig, path, 'export').behind_foliage == 'none'
