#!/usr/bin/env python3
"""The scale's fruit region and scene box against the truth on the suites' scenes, before any training.

Every scene of the named suites is synthesised (once, into OUT/<scene>), its scale measured as a training run
measures it (``cpu`` preset: camera box, scale vote, scene box) with each variant of ``ScaleConfig``, and per
variant the share of true fruit centres inside the fruit region and inside the scene box, the box's size and the
measured diameter are printed. Seconds per scene: a way to judge a scale rule on every scene without training.

Usage::

    python bench/scale_regions.py --out regions --variant strict=region_fraction:none
    python bench/scale_regions.py --suites quick --variant f50=region_fraction:0.5,region_view_angle_deg:60
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np


def _value(text: str) -> float | None:
    return None if text.lower() == 'none' else float(text)


def _variant(text: str) -> tuple[str, dict[str, float | None]]:
    """``name=key:value,...`` -> (name, ScaleConfig overrides); ``none`` gives None."""
    name, _, body = text.partition('=')
    return name, {k: _value(v) for k, v in (item.split(':', 1) for item in filter(None, body.split(',')))}


def main() -> int:
    from fruitnerfpp_ros.core.benchmark.suites import suite_scenes
    from fruitnerfpp_ros.core.data.dataset import load_dataset
    from fruitnerfpp_ros.core.synthetic import generate_orchard
    from fruitnerfpp_ros.core.training.presets import preset
    from fruitnerfpp_ros.core.training.scene_box import build_scene_box, camera_box
    from fruitnerfpp_ros.core.data.scene_scale import estimate_scene_scale

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--suites', default='quick,cpu', help='comma-separated suite names (default quick,cpu); '
                        'blind:SEED for another blind draw')
    parser.add_argument('--out', type=Path, default=Path('scale_regions'), help='where the scenes are synthesised')
    parser.add_argument('--variant', action='append', default=[], help='name=key:value,... (repeatable)')
    args = parser.parse_args()
    config = preset('cpu')
    variants = {'base': config.scale} | {n: dataclasses.replace(config.scale, **o)
                                         for n, o in map(_variant, args.variant)}
    named = [name.partition(':') for name in args.suites.split(',')]
    for scene in (s for name, _, draw in named for s in suite_scenes(name, draw=int(draw) if draw else None)):
        data = args.out / scene.name
        if not (data / 'transforms.json').is_file():
            generate_orchard(scene.synth_config('cpu'), data)
        dataset = load_dataset(data, eval_every=config.data.eval_every)
        centres = np.array([f['center'] for f in json.loads((data / 'gt_fruits.json').read_text())['fruits']])
        cameras = camera_box(dataset, config)
        line = [scene.name]
        for name, scale_config in variants.items():
            scale = estimate_scene_scale(dataset, cameras, scale_config)
            box = build_scene_box(dataclasses.replace(config, scale=scale_config), cameras, scale,
                                  dataset.T_world_camera[:, :3, 3].double().numpy())
            region = scale.fruit_region
            in_region = 0.0 if region is None else np.all((centres >= region[0]) & (centres <= region[1]), 1).mean()
            in_box = np.all((centres >= box[0]) & (centres <= box[1]), 1).mean()
            size = ' x '.join(f'{v:.2f}' for v in box[1] - box[0])
            line.append(f'{name}: in region {in_region:.2f}, in box {in_box:.2f}, box {size} m, '
                        f'd {scale.fruit_diameter_m * 1000:.1f} mm')
        print(' | '.join(line), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
