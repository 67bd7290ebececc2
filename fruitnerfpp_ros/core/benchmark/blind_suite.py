"""The ``blind`` suite: scenes drawn at random over every axis the generator varies, all axes at once.

The tuned suites (``quick``, ``cpu``) vary one or two axes a scene and ``holdout`` a few more; a scene someone else
generates varies all of them at once: an odd lens *and* noisy masks *and* a JPEG bag on a far row. This suite draws
such scenes from a fixed seed (:data:`BLIND_SEED`) with :class:`random.Random` (stable across Python versions), so
the draw is the same on every machine and nobody picked it. Ranges are a robot's (a row's standoff 1.5-3 m, a
camera 0.8-2 m high, pitch -5..10 deg), a little wider than the tuned suites' where a real camera is (field of
view 42-65 deg, JPEG quality 70-95), and sized for the 2-core CPU machine (20-130 fruits, at most 320 x 240, 48-64
views). Like ``holdout`` it confirms a default, it never chooses one.

    fruitnerfpp bench accuracy --suite blind --out b --jobs 2 --device cpu
    fruitnerfpp bench accuracy --suite blind --draw 7 --out b7 --jobs 2 --device cpu   # another draw of eight

``--draw SEED`` draws another eight from another seed (scene seeds of their own, names ``..._d<SEED>_<i>``): a
change confirmed on the suite can be checked again on scenes that nobody has looked at yet.
"""

from __future__ import annotations

import math
import random
from typing import Any

from fruitnerfpp_ros.core.benchmark.scene_types import BagOptions, SuiteScene, row_fields
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['BLIND_SEED', 'BLIND_SCENES', 'draw_blind_scenes']

#: The draw's seed (the date the suite was drawn); change it only to draw a new blind suite, never to pick scenes.
BLIND_SEED = 20261207
#: Scenes in the suite (about 50 min on the 2-core machine, two at once).
BLIND_SCENES = 8
_FRUITS = ('apple', 'plum', 'lemon', 'pear', 'peach', 'mango', 'mixed')
_RESOLUTIONS = ((160, 120), (200, 150), (240, 180), (320, 240), (192, 192), (256, 192))
_FIRST_SEED = 401  # scene seeds 401...: no tuned suite uses them
_OTHER_DRAWS_FIRST_SEED = 10_000  # another draw's scenes: 10_000 + 10 * (seed % 100_000) + index


def _scene_seeds(seed: int, count: int) -> tuple[int, ...]:
    """The generator seeds of a draw's scenes: 401... for the suite's draw, others from 10_000 on (never a tuned
    suite's)."""
    first = _FIRST_SEED if seed == BLIND_SEED else _OTHER_DRAWS_FIRST_SEED + 10 * (seed % 100_000)
    return tuple(first + index for index in range(count))


def _draw_one(rng: random.Random, index: int, scene_seed: int, suffix: str) -> SuiteScene:
    """One scene: every axis drawn, the optional ones (lens, odometry error, drift, mask errors, bag) by chance."""
    fruit = rng.choice(_FRUITS)
    row = rng.random() < 0.6
    count = round(math.exp(rng.uniform(math.log(20), math.log(130))))
    synth: dict[str, Any] = dict(
        fruit=fruit, count=count, views=rng.choice((48, 56, 64)), resolution=rng.choice(_RESOLUTIONS),
        fov_deg=round(rng.uniform(42.0, 65.0), 1), leaf_scale=round(rng.uniform(0.6, 1.3), 2),
        cluster_scale=round(rng.uniform(0.5, 2.0), 2), appearance_variation=round(rng.uniform(0.0, 0.8), 2),
        seed=scene_seed)
    axes = [fruit, f'{count} fruits', 'row' if row else 'hemisphere']
    if row:
        synth.update(row_fields(row_standoff_m=round(rng.uniform(1.5, 3.0), 2),
                                camera_height_m=round(rng.uniform(0.8, 2.0), 2),
                                camera_pitch_deg=round(rng.uniform(-5, 10), 1)))
        axes.append(f"standoff {synth['row_standoff_m']} m, camera {synth['camera_height_m']} m, "
                    f"pitch {synth['camera_pitch_deg']} deg")
    if rng.random() < 0.4:
        synth.update(fy_scale=round(rng.uniform(0.98, 1.03), 3),
                     principal_offset_px=(round(rng.uniform(-8, 8), 1), round(rng.uniform(-8, 8), 1)),
                     distortion=(round(rng.uniform(-0.15, -0.02), 3), round(rng.uniform(0.0, 0.03), 3), 0.0, 0.0, 0.0))
        axes.append('real lens')
    if rng.random() < 0.3:
        synth.update(pose_noise_m=round(rng.uniform(0.005, 0.02), 3), pose_noise_deg=round(rng.uniform(0.3, 1.0), 2))
        axes.append(f"pose noise {synth['pose_noise_m']} m / {synth['pose_noise_deg']} deg")
    if row and rng.random() < 0.2:
        synth.update(pass_offset_m=round(rng.uniform(0.02, 0.06), 3), pass_offset_deg=round(rng.uniform(0.3, 1.0), 2))
        axes.append(f"return pass drifted {synth['pass_offset_m']} m / {synth['pass_offset_deg']} deg")
    if rng.random() < 0.4:
        synth.update(mask_missed=round(rng.uniform(0.05, 0.2), 2), mask_false=round(rng.uniform(0.02, 0.1), 2),
                     mask_boundary_px=rng.choice((0, 1)))
        axes.append(f"masks missed {synth['mask_missed']}, false {synth['mask_false']}, "
                    f"boundary {synth['mask_boundary_px']} px")
    via_bag = rng.random() < 0.35
    bag = BagOptions()
    if via_bag:
        synth.update(bag_image_format='jpeg', bag_jpeg_quality=rng.randint(70, 95),
                     world_frame=rng.choice(('odom', 'map')))
        bag = BagOptions(storage=rng.choice(('mcap', 'sqlite3')), pose_source=rng.choice(('pose', 'tf')))
        axes.append(f"bag ({bag.storage}, JPEG {synth['bag_jpeg_quality']}, {synth['world_frame']}, "
                    f'poses from {bag.pose_source})')
    name = f"{fruit}_{'row' if row else 'hemi'}_{count}_{suffix}"
    return SuiteScene(name, synth, ', '.join(axes), via_bag=via_bag, bag=bag)


def draw_blind_scenes(seed: int = BLIND_SEED, count: int = BLIND_SCENES) -> tuple[SuiteScene, ...]:
    """``count`` scenes drawn from ``seed``: the same scenes for the same arguments on every machine. The suite's
    draw (:data:`BLIND_SEED`) names its scenes ``..._b<i>``, another draw ``..._d<seed>_<i>``."""
    if count > 10 and seed != BLIND_SEED:
        raise ConfigError('another draw holds at most 10 scenes (its scene seeds would meet the next draw\'s)')
    rng = random.Random(seed)
    suffix = 'b{}' if seed == BLIND_SEED else f'd{seed}_{{}}'
    return tuple(_draw_one(rng, index, scene_seed, suffix.format(index))
                 for index, scene_seed in enumerate(_scene_seeds(seed, count)))
