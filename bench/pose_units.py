#!/usr/bin/env python3
"""A dataset with its poses in other units than metres: a copy of a ``fruitnerfpp synth`` dataset (transforms.json,
images, masks, ``gt_fruits.json``, ``sparse_pc.ply``) with every length multiplied by ``--factor`` (a pose unit of
1 / factor metres), the images and masks unchanged, as a COLMAP or nerfstudio reconstruction of the same scene would
have it. Counting the copy must give the count of the original (docs/results/robustness.md, "Poses in other units
than metres").

Usage::

    fruitnerfpp synth --fruit apple --count 30 --views 48 --resolution 128 --seed 7 --out A
    python bench/pose_units.py A A_20m --factor 0.05      # a pose unit of 20 m
    fruitnerfpp run A_20m --out R --preset tiny --device cpu && fruitnerfpp eval R
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.data.ply_io import read_ply_vertices, write_ply_vertices
from fruitnerfpp_ros.core.data.transforms_format import read_transforms, write_transforms


def scaled_copy(source: Path, out: Path, factor: float) -> None:
    """Copy ``source`` to ``out`` with its poses, ground truth and sparse points multiplied by ``factor``."""
    shutil.copytree(source, out)
    transforms = read_transforms(source)
    scaled = []
    for frame in transforms.frames:
        pose = np.array(frame.T_world_camera, np.float64)
        pose[:3, 3] *= factor
        scaled.append(dataclasses.replace(frame, T_world_camera=pose))
    transforms.frames = scaled
    transforms.extra['frame'] = f'{transforms.extra.get("frame", "world")}, every length x {factor}'
    write_transforms(out, transforms)
    gt_path = source / 'gt_fruits.json'
    if gt_path.is_file():
        gt = json.loads(gt_path.read_text())
        for fruit in gt['fruits']:
            fruit['center'] = [float(v) * factor for v in fruit['center']]
            if 'diameter' in fruit:
                fruit['diameter'] = float(fruit['diameter']) * factor
            if 'radii' in fruit:
                fruit['radii'] = [float(v) * factor for v in fruit['radii']]
        (out / 'gt_fruits.json').write_text(json.dumps(gt, indent=1))
    ply = transforms.ply_file_path
    if ply and (source / ply).is_file():
        vertices = read_ply_vertices(source / ply).copy()
        for axis in ('x', 'y', 'z'):
            vertices[axis] = vertices[axis] * factor
        write_ply_vertices(out / ply, vertices)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('source', type=Path, help='a transforms.json dataset')
    parser.add_argument('out', type=Path, help='the copy to write (must not exist)')
    parser.add_argument('--factor', type=float, required=True, help='every length times this (0.05: units of 20 m)')
    args = parser.parse_args()
    if args.out.exists():
        parser.error(f'{args.out} exists')
    if not args.factor > 0:
        parser.error('--factor must be > 0')
    scaled_copy(args.source, args.out, args.factor)
    print(f'wrote {args.out}: every length x {args.factor}')


if __name__ == '__main__':
    main()
