"""The suites are valid data: every scene builds its SynthConfig, and the cpu suite covers every axis."""

from __future__ import annotations

import pickle

import pytest

from fruitnerfpp_ros.core.benchmark.blind_suite import BLIND_SEED, draw_blind_scenes
from fruitnerfpp_ros.core.benchmark.suites import SUITES, BagOptions, SuiteScene, suite_scenes
from fruitnerfpp_ros.core.synthetic import FRUIT_NAMES, MIXED, build_scene, row_drive
from fruitnerfpp_ros.errors import ConfigError, SynthError

ALL = [(suite.name, scene) for suite in SUITES.values() for scene in suite.scenes]


@pytest.mark.parametrize('suite, scene', ALL, ids=[f'{s}-{c.name}' for s, c in ALL])
def test_every_scene_builds_its_synth_config(suite: str, scene: SuiteScene) -> None:
    config = scene.synth_config('cpu')
    assert config.device == 'cpu' and scene.covers
    assert pickle.loads(pickle.dumps(scene)) == scene  # crosses into the scene process
    if config.trajectory == 'row':
        row_drive(build_scene(config), config)  # the camera stays outside the crown
        assert config.sparse_points == 0  # a robot has no SfM cloud


def test_suites_have_unique_names_and_their_presets() -> None:
    for suite in SUITES.values():
        names = [s.name for s in suite.scenes]
        assert len(names) == len(set(names))
    presets = {name: suite.preset for name, suite in SUITES.items()}
    assert presets == {'quick': 'cpu', 'cpu': 'cpu', 'gpu': 'default', 'holdout': 'cpu', 'blind': 'cpu',
                       'smoke': 'tiny'}


def test_holdout_suite_shares_no_seed_and_adds_axes() -> None:
    held = [s.synth_config() for s in SUITES['holdout'].scenes]
    tuned = [s.synth_config() for name in ('quick', 'cpu') for s in SUITES[name].scenes]
    assert not {c.seed for c in held} & {c.seed for c in tuned}
    assert {(c.fruit, c.trajectory) for c in held} - {(c.fruit, c.trajectory) for c in tuned}
    assert any(c.leaf_scale > 1 for c in held) and any(c.leaf_scale < 1 for c in held)
    assert any(c.cluster_scale > 1 for c in held) and any(c.fov_deg != 50 for c in held)
    assert any(c.trajectory == 'row' and c.camera_pitch_deg < 0 for c in held)
    assert any(s.via_bag and s.synth_config().resolution == (480, 360) for s in SUITES['holdout'].scenes)
    assert any(c.pass_offset_m > 0 and c.pass_offset_deg > 0 for c in held)


def test_blind_suite_is_a_fixed_draw_over_every_axis_on_seeds_no_other_suite_uses() -> None:
    assert draw_blind_scenes() == SUITES['blind'].scenes == draw_blind_scenes(BLIND_SEED)  # the same draw each time
    assert draw_blind_scenes(BLIND_SEED + 1) != draw_blind_scenes()
    others = {s.synth_config().seed for name in SUITES if name != 'blind' for s in SUITES[name].scenes}
    many = draw_blind_scenes(count=200)  # the draw's ranges, over more scenes than the suite holds
    configs = [s.synth_config() for s in many]
    assert not {c.seed for c in configs} & others and len({c.seed for c in configs}) == len(configs)
    assert {c.fruit for c in configs} == {*FRUIT_NAMES, MIXED}
    assert {c.trajectory for c in configs} == {'row', 'hemisphere'}
    assert all(20 <= c.count <= 130 and 48 <= c.views <= 64 and max(c.resolution) <= 320 for c in configs)
    rows = [c for c in configs if c.trajectory == 'row']
    assert all(1.5 <= c.row_standoff_m <= 3 and 0.8 <= c.camera_height_m <= 2 for c in rows)
    assert min(c.camera_pitch_deg for c in rows) < 0 < max(c.camera_pitch_deg for c in rows)
    assert any(any(c.distortion) for c in configs) and any(c.pose_noise_m > 0 for c in configs)
    assert any(c.pass_offset_m > 0 for c in rows) and any(c.mask_missed > 0 for c in configs)
    bags = [s for s in many if s.via_bag]
    assert {s.bag.storage for s in bags} == {'mcap', 'sqlite3'}
    assert {s.bag.pose_source for s in bags} == {'pose', 'tf'}
    assert all(s.synth_config().bag_image_format == 'jpeg' for s in bags)
    assert all(s.covers.startswith(f'{s.synth_config().fruit}, ') for s in many)


def test_another_blind_draw_has_scenes_names_and_seeds_of_its_own() -> None:
    suite = SUITES['blind'].scenes
    other = suite_scenes('blind', draw=7)
    assert other == draw_blind_scenes(7) and len(other) == len(suite)
    assert all(s.name.endswith(f'_d7_{i}') for i, s in enumerate(other))
    assert all(s.name.endswith(f'_b{i}') for i, s in enumerate(suite))
    taken = {s.synth_config().seed for name in SUITES for s in SUITES[name].scenes}
    seeds = {s.synth_config().seed for s in other}
    assert len(seeds) == len(other) and not seeds & taken
    assert not seeds & {s.synth_config().seed for s in draw_blind_scenes(8)}   # the next draw's are its own too
    assert [s.name for s in suite_scenes('blind', other[2].name, draw=7)] == [other[2].name]
    with pytest.raises(ConfigError, match='blind suite only'):
        suite_scenes('quick', draw=7)
    with pytest.raises(ConfigError, match='unknown scene'):
        suite_scenes('blind', suite[0].name, draw=7)


def test_quick_suite_is_the_four_scenes() -> None:
    configs = [s.synth_config() for s in SUITES['quick'].scenes]
    ci = configs[0]
    assert (ci.fruit, ci.count, ci.views, ci.resolution, ci.trajectory, ci.seed) == \
        ('apple', 20, 48, (96, 96), 'hemisphere', 0)
    row = configs[1]
    assert (row.fruit, row.count, row.views, row.resolution, row.trajectory, row.sparse_points) == \
        ('apple', 60, 48, (240, 180), 'row', 0)
    assert [(c.fruit, c.count, c.resolution, c.trajectory) for c in configs[2:]] == \
        [('plum', 40, (128, 128), 'hemisphere'), ('mango', 40, (128, 128), 'hemisphere')]


def test_cpu_suite_covers_every_axis() -> None:
    scenes = SUITES['cpu'].scenes
    configs = {s.name: s.synth_config() for s in scenes}
    assert len(scenes) >= 12
    assert {c.fruit for c in configs.values()} == {*FRUIT_NAMES, MIXED}
    counts = [c.count for c in configs.values()]
    assert min(counts) <= 20 and max(counts) >= 180
    assert {c.trajectory for c in configs.values()} == {'hemisphere', 'row'}
    rows = [c for c in configs.values() if c.trajectory == 'row']
    assert {c.row_standoff_m for c in rows} >= {1.5, 3.0} and all(1.5 <= c.row_standoff_m <= 3 for c in rows)
    assert all(0.8 <= c.camera_height_m <= 2 and 0 <= c.camera_pitch_deg <= 10 for c in rows)
    assert any(c.width * 3 == c.height * 4 and c.fy_scale != 1 and c.principal_offset_px != (0.0, 0.0)
               and any(c.distortion) for c in configs.values())
    bags = [s for s in scenes if s.via_bag]
    assert len(bags) == 2
    assert {configs[s.name].world_frame for s in bags} == {'odom', 'map'}
    assert all(configs[s.name].bag_image_format == 'jpeg' for s in bags)
    assert any(c.pose_noise_m == 0.02 and c.pose_noise_deg == 1.0 for c in configs.values())
    assert sum(c.appearance_variation > 0 for c in configs.values()) >= 3
    assert all(48 <= c.views <= 64 and 96 <= max(c.resolution) <= 320 for c in configs.values())
    seeds = [c.seed for c in configs.values()]
    quick_seeds = {s.synth_config().seed for s in SUITES['quick'].scenes}
    assert len(set(seeds)) == len(seeds) and not set(seeds) & quick_seeds


def test_gpu_suite_is_the_papers_table() -> None:
    configs = [s.synth_config() for s in SUITES['gpu'].scenes]
    assert {(c.fruit, c.count) for c in configs} == {('apple', 283), ('plum', 745), ('lemon', 326), ('pear', 250),
                                                     ('peach', 152), ('mango', 1150)}
    assert all(c.views == 300 and c.resolution == (512, 512) and c.trajectory == 'hemisphere' for c in configs)


def test_suite_scenes_selects_by_name_in_suite_order() -> None:
    chosen = suite_scenes('quick', 'mango_hemi_40, apple_hemi_20')
    assert [s.name for s in chosen] == ['apple_hemi_20', 'mango_hemi_40']
    assert suite_scenes('quick') == SUITES['quick'].scenes
    with pytest.raises(ConfigError, match="unknown suite 'fast'; expected one of quick, cpu, gpu, holdout, blind, "
                                          "smoke"):
        suite_scenes('fast')
    with pytest.raises(ConfigError, match='unknown scene.* nope in suite quick; its scenes: apple_hemi_20'):
        suite_scenes('quick', 'apple_hemi_20,nope')


def test_bad_definitions() -> None:
    with pytest.raises(ConfigError, match='scene name'):
        SuiteScene('a b', {}, 'x')
    with pytest.raises(ConfigError, match='storage'):
        BagOptions(storage='rosbag1')  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="scene odd: .*unexpected keyword argument 'colour'"):
        SuiteScene('odd', {'colour': 'red'}, 'x').synth_config()
    with pytest.raises(SynthError, match='unknown fruit type'):
        SuiteScene('banana', {'fruit': 'banana'}, 'x').synth_config()
