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
    ({'row_standoff_m': 0.1}, r'row_standoff_m must be a number within 0.3..50, got 0.1'),
    ({'camera_pitch_deg': 80.0}, 'camera_pitch_deg must be a number within -60..60'),
    ({'fy_scale': 0.0}, 'fy_scale must be a number within 0.5..2'),
    ({'principal_offset_px': (1.0,)}, 'principal_offset_px must be 2 finite numbers'),
    ({'principal_offset_px': (70.0, 0.0)}, 'principal_offset_px must keep the principal point inside the 128x128'),
    ({'distortion': (0.1, 0.0, 0.0)}, 'distortion must be 4 or 5 finite numbers'),
    ({'distortion': (0.1, float('nan'), 0.0, 0.0)}, 'distortion must be 4 or 5 finite numbers'),
    ({'distortion': (20.0, 0.0, 0.0, 0.0)}, 'distortion coefficients must be within -10..10'),
    ({'appearance_variation': 1.5}, 'appearance_variation must be a number within 0..1'),
    ({'bag_image_format': 'png'}, "unknown bag_image_format 'png'; expected one of raw, jpeg"),
    ({'bag_jpeg_quality': 0}, 'bag_jpeg_quality must be an integer within 1..100'),
    ({'world_frame': '/map'}, "world_frame must be a ROS frame name like map or odom"),
    ({'world_frame': 'my map'}, "world_frame must be a ROS frame name"),
])
def test_bad_config_raises(kwargs: dict, message: str) -> None:
    with pytest.raises(SynthError, match=message):
        SynthConfig(**kwargs)


def test_four_distortion_coefficients_mean_k3_zero() -> None:
    assert SynthConfig(distortion=(-0.1, 0.01, 0.0, 0.001)).distortion == (-0.1, 0.01, 0.0, 0.001, 0.0)


def test_impossible_camera_or_drive_raises_before_writing(tmp_path: Path) -> None:
    # k1 = -0.4 alone folds over inside a 50-degree image: no distorted pixel maps back to a unique ray there.
    folding = SynthConfig(count=3, views=1, resolution=(32, 24), distortion=(-0.4, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(SynthError, match=r'distortion \[-0.4, 0.0, 0.0, 0.0, 0.0\] cannot be inverted over the 32x24'):
        generate_orchard(folding, tmp_path / 'ds', bag=tmp_path / 'bag')
    assert not (tmp_path / 'bag').exists() and not list((tmp_path / 'ds' / 'images').iterdir())
    inside = SynthConfig(count=300, views=2, resolution=(32, 24), trajectory='row', row_standoff_m=1.0)
    with pytest.raises(SynthError, match=r'row_standoff_m 1 m puts the camera inside the tree .* use at least 1\.'):
        generate_orchard(inside, tmp_path / 'ds2')


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
    (['--resolution', '12y'], "--resolution: expected a size like 128, 160x120 or 160 120, got '12y'"),
    (['--resolution', '16', '12', '8'], "--resolution: expected a size like 128, 160x120 or 160 120, got '16 12 8'"),
    (['--distortion', '0.1', 'x', '0', '0'], "--distortion: expected a number, got 'x'"),
    (['--distortion', '0.1', '0', '0'], 'distortion must be 4 or 5 finite numbers'),
    (['--world-frame', 'a b'], 'world_frame must be a ROS frame name'),
    (['--bag-image-format', 'png'], "unknown bag_image_format 'png'"),
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


def test_cli_warns_when_no_view_shows_a_fruit(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A small tree (8 apples: its crown hangs at about half a metre) under a camera 2 m high pitched up 10 deg."""
    common = ['synth', '--quiet', '--fruit', 'apple', '--count', '8', '--views', '12', '--resolution', '48',
              '--seed', '5', '--trajectory', 'row', '--row-standoff', '2.4']
    assert main([*common, '--camera-height', '2.0', '--camera-pitch', '10', '--out', str(tmp_path / 'past')]) == 0
    captured = capsys.readouterr()
    assert '(0 visible)' in captured.out and 'warning: no view shows any of the fruits' in captured.err
    assert main([*common, '--camera-height', '0.8', '--camera-pitch', '0', '--out', str(tmp_path / 'level')]) == 0
    captured = capsys.readouterr()
    assert '(0 visible)' not in captured.out and 'warning' not in captured.err
