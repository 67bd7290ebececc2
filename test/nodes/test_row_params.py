"""The row parameters: declared once, documented, the shipped params file, their mapping onto OrchardConfig."""

from __future__ import annotations

from pathlib import Path

import pytest

from fruitnerfpp_ros.errors import ConfigError
from fruitnerfpp_ros.nodes.params import PARAMETERS, load_parameter_file
from fruitnerfpp_ros.nodes.row_params import (ROW_PARAMETERS, orchard_config, row_parameter_table,
                                              row_settings_from_parameters, split_parameters)

ROOT = Path(__file__).resolve().parents[2]


def test_row_parameters_are_documented_and_apart_from_the_counters() -> None:
    assert not {p.name for p in ROW_PARAMETERS} & {p.name for p in PARAMETERS}
    assert all(len(p.description) > 15 for p in ROW_PARAMETERS)
    assert row_parameter_table() in (ROOT / 'docs/ros_interface.md').read_text(), \
        'docs/ros_interface.md: regenerate with nodes.row_params.row_parameter_table()'


def test_shipped_params_file_and_mapping(tmp_path: Path) -> None:
    values = load_parameter_file(ROOT / 'config/orchard_row.yaml')
    counter, row = split_parameters({**values, 'preset': 'tiny'})
    assert counter == {'preset': 'tiny'} and list(row) == [p.name for p in ROW_PARAMETERS]
    settings = row_settings_from_parameters(row)
    assert settings.row_mode and settings.gnss_topic == '/gnss/fix'
    config = orchard_config(settings)
    assert config.geo.antenna_in_camera_m == (0.0, -0.5, 0.0) and config.segments.length_m is None
    (tmp_path / 'o.yaml').write_text('orchard:\n  merge:\n    match_diameters: 0.7\n  segments:\n    margin_m: 0.9\n')
    config = orchard_config(row_settings_from_parameters({'orchard_config_file': str(tmp_path / 'o.yaml'),
                                                          'segment_length_m': 2, 'datum': '49 11 300 30',
                                                          'tree_spacing_m': 1.5}))
    assert config.merge.match_diameters == 0.7 and config.segments.length_m == 2.0
    assert config.segments.margin_m == 0.9            # the parameter at its default leaves the file's value
    assert config.geo.datum == (49.0, 11.0, 300.0, 30.0) and config.trees.spacing_m == 1.5
    with pytest.raises(ConfigError, match='gnss_antenna_offset'):
        row_settings_from_parameters({'gnss_antenna_offset': '1 2'})
    with pytest.raises(ConfigError, match='row_flush_after_s'):
        row_settings_from_parameters({'row_flush_after_s': 0.0})
