"""The accuracy suites (issue #11) as data: one :class:`SuiteScene` record per synthetic scene with ground truth.

Edit the scenes here; the runner (:mod:`.runner`) and the report (:mod:`.report`) never name one. Each scene is a
set of :class:`~fruitnerfpp_ros.core.synthetic.SynthConfig` fields (checked only when the scene runs, so a broken
scene fails alone and is reported), whether it goes through a rosbag2 and the bag replay like a robot recording,
and a note on the axes of variation it covers.

- ``quick``: 4 scenes, sized for about 10 minutes on a 2-core CPU with the ``cpu`` preset and ``--jobs 2``.
- ``cpu``: 13 scenes over every axis the generator varies (fruit type, count, trajectory, camera and lens, look,
  odometry noise, bag transport), each within about 5 minutes of ``cpu``-preset training on one core; seeds
  differ from the ``quick`` suite's (scenes nothing was tuned on).
- ``gpu``: the paper's Table II scenes: six fruit types at the paper's counts, 300 views of 512 px, hemisphere,
  ``default`` preset.
- ``holdout``: 7 scenes on axes and seeds the ``cpu`` suite does not hold (fruit types on other trajectories, a
  wide lens looking down, dense and sparse foliage, fruit in clusters, the issue's 480x360 robot recording, a
  return pass drifted as wheel odometry drifts). No
  default is chosen on them: they confirm a change the other suites chose, and show whether it carries over.
- ``blind``: 8 scenes drawn at random over every axis at once (:mod:`.blind_suite`): confirms, never chooses.
- ``smoke``: two micro scenes (dataset and bag path) that check the harness itself, ``tiny`` preset.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping

from fruitnerfpp_ros.core.benchmark.blind_suite import draw_blind_scenes
from fruitnerfpp_ros.core.benchmark.scene_types import BagOptions, Suite, SuiteScene
from fruitnerfpp_ros.core.benchmark.scene_types import row_fields as _row
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['BagOptions', 'SuiteScene', 'Suite', 'SUITES', 'SUITE_NAMES', 'suite_scenes']


_QUICK = (
    SuiteScene('apple_hemi_20', dict(fruit='apple', count=20, views=48, resolution=(96, 96), trajectory='hemisphere',
                                     seed=0),
               'the CI scene: apple, hemisphere, 96 px'),
    SuiteScene('apple_row_60', _row(fruit='apple', count=60, views=48, resolution=(240, 180), seed=1),
               'robot-like row drive on both sides, 4:3 camera, no sparse cloud'),
    SuiteScene('plum_hemi_40', dict(fruit='plum', count=40, views=48, resolution=(128, 128), seed=2),
               'small fruit (plum), hemisphere'),
    SuiteScene('mango_hemi_40', dict(fruit='mango', count=40, views=48, resolution=(128, 128), seed=3),
               'elongated, occluded fruit (mango), hemisphere'),
)

_CPU = (
    SuiteScene('pear_hemi_20', dict(fruit='pear', count=20, views=48, resolution=(96, 96), seed=101),
               'pear (pear-shaped), fewest fruits (20), hemisphere'),
    SuiteScene('apple_hemi_40', dict(fruit='apple', count=40, views=48, resolution=(128, 128), seed=102),
               'apple, hemisphere, new seed'),
    SuiteScene('lemon_hemi_60', dict(fruit='lemon', count=60, views=48, resolution=(160, 160), seed=103,
                                     appearance_variation=0.6),
               'lemon (elongated), varied look'),
    SuiteScene('mango_hemi_100', dict(fruit='mango', count=100, views=64, resolution=(192, 192), seed=104,
                                      appearance_variation=0.5),
               'mango (occluded, yellow-green), 100 fruits, varied look'),
    SuiteScene('apple_hemi_200', dict(fruit='apple', count=200, views=64, resolution=(256, 256), seed=105,
                                      appearance_variation=0.3),
               'dense tree (200 apples), 256 px'),
    SuiteScene('plum_row_120', _row(fruit='plum', count=120, views=64, resolution=(240, 180), seed=106,
                                    appearance_variation=0.5),
               'small fruit on a row drive, standoff 2 m, camera 1.2 m, pitch 5 deg, varied look'),
    SuiteScene('pear_row_far', _row(fruit='pear', count=80, views=64, resolution=(320, 240), seed=107,
                                    row_standoff_m=3.0, camera_height_m=2.0, camera_pitch_deg=0.0),
               'row, far standoff 3 m, high mast 2 m, level camera, 320x240'),
    SuiteScene('peach_row_near', _row(fruit='peach', count=50, views=56, resolution=(240, 180), seed=108,
                                      row_standoff_m=1.5, camera_height_m=0.8, camera_pitch_deg=10.0,
                                      appearance_variation=0.4),
               'peach, row, near standoff 1.5 m, low camera 0.8 m, pitch 10 deg, varied look'),
    SuiteScene('mixed_row_150', _row(fruit='mixed', count=150, views=64, resolution=(240, 180), seed=109,
                                     appearance_variation=0.7),
               'all six fruit types on one tree, row, strongly varied look'),
    SuiteScene('apple_row_lens', _row(fruit='apple', count=80, views=64, resolution=(320, 240), seed=110,
                                      fy_scale=1.02, principal_offset_px=(6.0, -4.0),
                                      distortion=(-0.12, 0.03, 0.001, -0.001, 0.0)),
               'real camera: 4:3, fy = 1.02 fx, principal point off centre, plumb_bob distortion'),
    SuiteScene('apple_row_pose_noise', _row(fruit='apple', count=60, views=64, resolution=(240, 180), seed=111,
                                            pose_noise_m=0.02, pose_noise_deg=1.0),
               'odometry error: 2 cm / 1 deg pose noise, row'),
    SuiteScene('apple_bag_odom', _row(fruit='apple', count=60, views=56, resolution=(240, 180), seed=112,
                                      bag_image_format='jpeg', world_frame='odom', appearance_variation=0.3),
               'robot recording: rosbag2 (MCAP), JPEG CompressedImage, odom frame, poses from /tf',
               via_bag=True, bag=BagOptions(storage='mcap', pose_source='tf')),
    SuiteScene('peach_bag_map', _row(fruit='peach', count=60, views=56, resolution=(240, 180), seed=113,
                                     bag_image_format='jpeg', world_frame='map',
                                     distortion=(-0.08, 0.01, 0.0, 0.0, 0.0), appearance_variation=0.5),
               'robot recording: rosbag2 (sqlite3), JPEG CompressedImage, map frame, PoseStamped, '
               'plumb_bob CameraInfo',
               via_bag=True, bag=BagOptions(storage='sqlite3', pose_source='pose')),
)

_HOLDOUT = (
    SuiteScene('apple_bag_480', _row(fruit='apple', count=60, views=48, resolution=(480, 360), seed=201,
                                     row_standoff_m=2.5, bag_image_format='jpeg', world_frame='odom'),
               "the issue's robot recording: 480x360 JPEG, both sides at 2.5 m, odom frame, poses from /tf",
               via_bag=True, bag=BagOptions(storage='mcap', pose_source='tf')),
    SuiteScene('mango_row_80', _row(fruit='mango', count=80, views=64, resolution=(240, 180), seed=202,
                                    leaf_scale=1.3),
               'mango on a row drive, foliage 1.3x denser'),
    SuiteScene('lemon_row_wide', _row(fruit='lemon', count=70, views=56, resolution=(320, 240), seed=203,
                                      fov_deg=70.0, row_standoff_m=1.8, camera_pitch_deg=-5.0),
               'lemon, row, wide lens (70 deg), camera looking 5 deg down'),
    SuiteScene('peach_hemi_120', dict(fruit='peach', count=120, views=64, resolution=(192, 192), seed=204,
                                      cluster_scale=2.0),
               'peach, hemisphere, twice the fruit hanging in touching clusters'),
    SuiteScene('plum_hemi_80', dict(fruit='plum', count=80, views=56, resolution=(192, 144), seed=205,
                                    leaf_scale=0.6),
               'plum, hemisphere through a 4:3 camera, sparse foliage'),
    SuiteScene('mixed_hemi_90', dict(fruit='mixed', count=90, views=56, resolution=(160, 160), seed=206,
                                     appearance_variation=0.5),
               'all six fruit types on one tree, hemisphere, varied look'),
    SuiteScene('apple_row_drift', _row(fruit='apple', count=60, views=56, resolution=(240, 180), seed=207,
                                       pass_offset_m=0.06, pass_offset_deg=1.0),
               "odometry's drift on the return pass: the far side's poses 6 cm along the row and 1 deg off"),
)

#: The paper's fruit counts (Table II).
_PAPER_COUNTS = (('apple', 283), ('plum', 745), ('lemon', 326), ('pear', 250), ('peach', 152), ('mango', 1150))

_GPU = tuple(
    SuiteScene(f'{fruit}_paper_{count}', dict(fruit=fruit, count=count, views=300, resolution=(512, 512),
                                              trajectory='hemisphere', seed=0),
               f"the paper's {fruit} scene: {count} fruits, 300 views of 512 px, hemisphere")
    for fruit, count in _PAPER_COUNTS)

_SMOKE = (
    SuiteScene('apple_micro', dict(fruit='apple', count=10, views=16, resolution=(64, 64), seed=7),
               'harness check: the dataset path'),
    SuiteScene('apple_micro_bag', dict(fruit='apple', count=10, views=16, resolution=(64, 64), seed=8,
                                       bag_image_format='jpeg', world_frame='odom'),
               'harness check: the bag path (JPEG, odom frame, poses from /tf)',
               via_bag=True, bag=BagOptions(pose_source='tf')),
)

#: Every suite by name.
SUITES: Mapping[str, Suite] = MappingProxyType({
    'quick': Suite('quick', 'cpu', _QUICK, 'sized for about 10 min on a 2-core CPU with --jobs 2'),
    'cpu': Suite('cpu', 'cpu', _CPU, 'every axis of the generator, each scene within ~5 min of cpu-preset training '
                 'on one core'),
    'gpu': Suite('gpu', 'default', _GPU, "the paper's Table II scenes on a GPU (default preset)"),
    'holdout': Suite('holdout', 'cpu', _HOLDOUT, 'scenes no default was chosen on (other axes and seeds): run to '
                     'confirm a change, never to choose one'),
    'blind': Suite('blind', 'cpu', draw_blind_scenes(), 'scenes drawn at random over every axis at once (a fixed '
                   'seed): run to confirm a change, never to choose one'),
    'smoke': Suite('smoke', 'tiny', _SMOKE, 'two micro scenes that check the harness, not the accuracy (with '
                   '--config bench/accuracy_smoke.yaml: a minute or two)'),
})
SUITE_NAMES = tuple(SUITES)


def suite_scenes(suite: str, names: str | list[str] | tuple[str, ...] | None = None, *,
                 draw: int | None = None) -> tuple[SuiteScene, ...]:
    """The scenes of ``suite``, or only those named (``'a,b'`` or a list), in suite order. ``draw``: the ``blind``
    suite's scenes drawn from this seed instead of the suite's (:func:`.blind_suite.draw_blind_scenes`).

    Raises:
        ConfigError: an unknown suite or scene name (the message lists the known ones), or ``draw`` for a suite
            other than ``blind``.
    """
    if suite not in SUITES:
        raise ConfigError(f'unknown suite {suite!r}; expected one of {", ".join(SUITE_NAMES)}')
    if draw is not None and suite != 'blind':
        raise ConfigError(f'a draw seed is for the blind suite only, not {suite!r}')
    scenes = SUITES[suite].scenes if draw is None else draw_blind_scenes(draw)
    if names is None:
        return scenes
    wanted = [n.strip() for n in (names.split(',') if isinstance(names, str) else names) if n.strip()]
    known = {s.name for s in scenes}
    unknown = [n for n in wanted if n not in known]
    if unknown or not wanted:
        raise ConfigError(f'unknown scene(s) {", ".join(unknown) or "(none named)"} in suite {suite}; its scenes: '
                          f'{", ".join(s.name for s in scenes)}')
    return tuple(s for s in scenes if s.name in wanted)
