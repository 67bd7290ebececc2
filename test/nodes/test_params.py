"""Declared parameters and their one mapping onto the core configs."""

from __future__ import annotations

from pathlib import Path

import pytest

from fruitnerfpp_ros.errors import ConfigError
from fruitnerfpp_ros.nodes.params import (PARAMETERS, keyframe_config, load_parameter_file, pipeline_configs,
                                          settings_from_parameters)


def test_every_parameter_is_documented_and_typed() -> None:
    assert len({p.name for p in PARAMETERS}) == len(PARAMETERS)
    for p in PARAMETERS:
        assert len(p.description) > 15 and type(p.default) in (bool, int, float, str)


def test_bad_values_name_the_parameter() -> None:
    with pytest.raises(ConfigError, match='pose_source'):
        settings_from_parameters({'pose_source': 'gps'})
    with pytest.raises(ConfigError, match='unknown .*image_tpoic'):
        settings_from_parameters({'image_tpoic': '/x'})
    with pytest.raises(ConfigError, match='camera_extrinsic'):
        settings_from_parameters({'camera_extrinsic': '1 2 3'})
    with pytest.raises(ConfigError, match='max_keyframes'):
        keyframe_config(settings_from_parameters({'max_keyframes': 0}))


def test_params_file_forms(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters:\n    sync_slop_s: 1\n'
                    'fruit_counter:\n  ros__parameters:\n    preset: tiny\nother_node:\n  ros__parameters:\n    x: 1\n')
    values = load_parameter_file(path)
    assert values == {'sync_slop_s': 1, 'preset': 'tiny'}
    assert settings_from_parameters(values).sync_slop_s == 1.0
    with pytest.raises(ConfigError, match='not found'):
        load_parameter_file(tmp_path / 'missing.yaml')


def test_pipeline_configs_auto_preset_and_overrides(tmp_path: Path) -> None:
    from fruitnerfpp_ros.core.training import TrainConfig
    configs = pipeline_configs(settings_from_parameters({'device': 'cpu'}))
    assert configs.preset == 'cpu' and "'cpu' preset" in configs.notes[0]
    assert configs.train == TrainConfig.preset('cpu')
    override = tmp_path / 'c.yaml'
    override.write_text('train:\n  geometry:\n    iterations: 7\n')
    configs = pipeline_configs(settings_from_parameters({'preset': 'tiny', 'config_file': str(override)}))
    assert configs.train.geometry.iterations == 7 and configs.notes == ()
    override.write_text('train:\n  geometry:\n    iterashuns: 7\n')
    with pytest.raises(ConfigError, match='iterashuns'):
        pipeline_configs(settings_from_parameters({'config_file': str(override)}))


def test_the_documented_parameter_tables_are_the_declared_ones() -> None:
    from fruitnerfpp_ros.nodes.params import parameter_table
    root = Path(__file__).resolve().parents[2]
    for doc in ('README.md', 'docs/ros_interface.md'):
        assert parameter_table() in (root / doc).read_text(), f'{doc}: regenerate with nodes.params.parameter_table()'


def test_a_node_trains_on_one_thread_when_the_preset_says_auto(monkeypatch: pytest.MonkeyPatch) -> None:
    """The `cpu` preset's auto threads take the machine's cores in the CLI; a node shares them with the robot's
    other processes and keeps one (a count given in the config file is kept)."""
    import dataclasses

    import torch

    from fruitnerfpp_ros.nodes.params import use_node_cpu_threads
    monkeypatch.setattr('os.sched_getaffinity', lambda pid: {0, 1, 2, 3}, raising=False)
    monkeypatch.delenv('OMP_NUM_THREADS', raising=False)
    configs = pipeline_configs(settings_from_parameters({'preset': 'cpu', 'device': 'cpu'}))
    assert configs.train.cpu_threads == 0
    before = torch.get_num_threads()
    try:
        use_node_cpu_threads(configs, 'cpu')
        assert torch.get_num_threads() == 1
        use_node_cpu_threads(configs._replace(train=dataclasses.replace(configs.train, cpu_threads=3)), 'cpu')
        assert torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)
