"""TrainConfig presets, YAML files and the train CLI's config handling."""

from __future__ import annotations

from pathlib import Path

import pytest

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.cli.train import resolve_train_config
from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.training import PRESET_NAMES, TrainConfig
from fruitnerfpp_ros.errors import ConfigError

CONFIG_DIR = Path(__file__).resolve().parents[3] / 'config'


@pytest.mark.parametrize('name', PRESET_NAMES)
def test_yaml_presets_match_python(name: str) -> None:
    assert load_config(TrainConfig, CONFIG_DIR / f'train_{name}.yaml') == TrainConfig.preset(name)


def test_presets_scale_up() -> None:
    tiny, cpu, default, paper = (TrainConfig.preset(n) for n in PRESET_NAMES)
    assert tiny.geometry.iterations < cpu.geometry.iterations < default.geometry.iterations \
        < paper.geometry.iterations
    assert cpu.field == tiny.field and cpu.instance == tiny.instance
    rays = [c.geometry.iterations * c.geometry.batch_rays for c in (tiny, cpu, default, paper)]
    assert rays == sorted(rays) and len(set(rays)) == 4  # each preset trains its geometry on more rays
    # every preset aligns the poses to the images and refines them only where they were found off
    assert all(c.pose_alignment.enabled and c.geometry.pose_lr > 0 for c in (tiny, cpu, default, paper))
    refine_when = [c.geometry.pose_refine_when for c in (tiny, cpu, default, paper)]
    assert refine_when == ['aligned', 'aligned', 'aligned', 'aligned']
    assert default.instance.groups == 4 and default.instance.group_size == 8 and default.instance.pixels_per_fruit == 32
    assert default.instance.temperature == 0.2 and default.field.embedding_dim == 32
    with pytest.raises(ConfigError, match='huge'):
        TrainConfig.preset('huge')


def test_cli_config_overrides_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / 'over.yaml').write_text('geometry:\n  iterations: 7\ninstance:\n  temperature: 0.3\n')
    config = resolve_train_config('tiny', tmp_path / 'over.yaml')
    assert config.geometry.iterations == 7 and config.instance.temperature == 0.3
    assert config.semantic == TrainConfig.preset('tiny').semantic
    (tmp_path / 'bad.yaml').write_text('geometry:\n  iteration: 7\n')
    with pytest.raises(ConfigError, match='bad.yaml.*geometry.iteration'):
        resolve_train_config('tiny', tmp_path / 'bad.yaml')
    for section, key, value in (('geometry', 'coarse_to_fine_fraction', 1.5), ('data', 'outside_box_fraction', 1.0),
                                ('render', 'occupancy_probe_fraction', 0.0)):  # values out of their range
        (tmp_path / f'{key}.yaml').write_text(f'{section}:\n  {key}: {value}\n')
        with pytest.raises(ConfigError, match=key):
            resolve_train_config('tiny', tmp_path / f'{key}.yaml')
    code = main(['train', str(tmp_path / 'missing'), '--out', str(tmp_path / 'run'), '--device', 'cpu'])
    err = capsys.readouterr().err
    assert code == 2 and 'transforms.json' in err and 'Traceback' not in err


def test_every_preset_is_offered_by_the_commands_and_the_node() -> None:
    import typing

    from fruitnerfpp_ros.cli.main import build_parser
    from fruitnerfpp_ros.nodes.params import CounterSettings
    hints = typing.get_type_hints(CounterSettings)
    assert typing.get_args(hints['preset']) == ('auto', *PRESET_NAMES)
    sub = next(a for a in build_parser()._actions if a.dest == 'command').choices
    for command in ('train', 'run', 'replay', 'demo', 'orchard'):
        preset = next(a for a in sub[command]._actions if a.dest == 'preset')
        assert tuple(preset.choices) == ('auto', *PRESET_NAMES), command
    for command in ('train', 'run'):  # a command that trains picks the device's preset by itself (it was 'default' /
        args = build_parser().parse_args([command, 'data', '--out', 'run'])        # 'tiny' whatever the device)
        assert args.preset == 'auto', command
    assert build_parser().parse_args(['demo', '--out', 'd']).preset == 'tiny'  # `make demo` takes minutes


def test_auto_is_the_cpu_preset_on_the_cpu_with_a_note_and_default_on_cuda(capsys) -> None:
    from fruitnerfpp_ros.cli.train import resolve_preset
    from fruitnerfpp_ros.core.preset_names import auto_preset
    assert resolve_preset('auto', 'cpu') == 'cpu'  # the preset the suites judge, not the tests' fast `tiny`
    assert "preset 'auto' on the CPU" in capsys.readouterr().err
    assert resolve_preset('cpu', 'cpu') == 'cpu' and resolve_preset('default', 'cpu') == 'default'
    assert capsys.readouterr().err == ''                   # a named preset is taken as it is, without a word
    assert auto_preset(on_cuda=True) == 'default' and auto_preset(on_cuda=False) == 'cpu'
