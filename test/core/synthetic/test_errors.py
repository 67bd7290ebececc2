"""Bad input gets a SynthError with a clear message; the CLI prints one line and exits with 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.errors import SynthError


@pytest.mark.parametrize('kwargs, message', [
    ({'fruit': 'banana'}, "unknown fruit type 'banana'; expected one of apple, plum"),
    ({'views': 0}, 'views must be a positive integer, got 0'),
    ({'count': 0}, 'count must be an integer between 1 and 20000'),
    ({'resolution': (4, 96)}, 'resolution must be'),
    ({'trajectory': 'spiral'}, "unknown trajectory 'spiral'"),
])
def test_bad_config_raises(kwargs: dict, message: str) -> None:
    with pytest.raises(SynthError, match=message):
        SynthConfig(**kwargs)


def test_unwritable_out_dir_raises(tmp_path: Path) -> None:
    blocker = tmp_path / 'file.txt'
    blocker.write_text('x')
    config = SynthConfig(count=2, views=1, resolution=(16, 16))
    with pytest.raises(SynthError, match='exists and is not a directory'):
        generate_orchard(config, blocker)
    with pytest.raises(SynthError, match='cannot write to output directory .*file.txt/sub'):
        generate_orchard(config, blocker / 'sub')


@pytest.mark.parametrize('argv, message', [
    (['--fruit', 'banana'], "unknown fruit type 'banana'"),
    (['--views', '0'], 'views must be a positive integer'),
    (['--views', 'many'], "--views: expected an integer, got 'many'"),
    (['--resolution', '12y'], "--resolution: expected a size like 128 or 160x120, got '12y'"),
    (['--out-is-a-file'], 'exists and is not a directory'),
])
def test_cli_bad_input_prints_one_line_and_exits_2(argv: list[str], message: str, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / 'file.txt'
    blocker.write_text('x')
    if argv == ['--out-is-a-file']:
        argv = ['--out', str(blocker)]
    else:
        argv = [*argv, '--out', str(tmp_path / 'out')]
    assert main(['synth', '--quiet', *argv]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('fruitnerfpp synth: error: ') and message in err
    assert 'Traceback' not in err
