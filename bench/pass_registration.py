#!/usr/bin/env python3
"""The pass registration's gate on the suites' scenes, before any training: how much the best offset of a row
drive's return pass beats no offset, on exact poses and with a drift added.

Every scene of the named suites is synthesised (once, into OUT/<scene>; with ``--pass-offset`` a drifted twin into
OUT/<scene>_drift), its poses started as a training run starts them (``core/training/pose_start.py``: the pose
alignment, the scene measurement, the registration; preset ``--preset``), and the registration's figures printed
as a markdown table: passes, fruit voxels per pass, the score of no offset and of the best one, their ratio
(``gain``), the gain as a share of the smaller pass's fruit voxels, the offset, and whether it was applied. Noise-
free scenes show the chance floor the gate (``min_gain``, ``min_gain_share``) must stay above.

Usage::

    python bench/pass_registration.py --out passes                                   # quick, cpu, holdout
    python bench/pass_registration.py --suites quick --pass-offset 0.05 1.0 --out passes
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path


def main() -> int:
    import torch

    from fruitnerfpp_ros.core.benchmark.suites import suite_scenes
    from fruitnerfpp_ros.core.data.dataset import load_dataset
    from fruitnerfpp_ros.core.synthetic import generate_orchard
    from fruitnerfpp_ros.core.training.pose_start import start_poses
    from fruitnerfpp_ros.core.training.presets import preset

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--suites', default='quick,cpu,holdout', help='comma-separated suite names')
    parser.add_argument('--out', type=Path, default=Path('pass_registration'), help='where scenes are synthesised')
    parser.add_argument('--preset', default='cpu', help='training preset whose settings start the poses')
    parser.add_argument('--pass-offset', type=float, nargs=2, metavar=('METRES', 'DEGREES'),
                        help='also run each row scene with its return pass drifted this much')
    args = parser.parse_args()
    config = preset(args.preset)
    print('| scene | passes (views) | fruit voxels | score none / best | gain | share | offset (m) / yaw (deg) '
          '| applied | s |')
    print('|---|---|---|---:|---:|---:|---|---|---:|')
    for scene in (s for name in args.suites.split(',') for s in suite_scenes(name)):
        synth = scene.synth_config('cpu')
        twins = [(scene.name, synth)]
        if args.pass_offset and synth.trajectory == 'row':
            twins.append((f'{scene.name}_drift', dataclasses.replace(
                synth, pass_offset_m=args.pass_offset[0], pass_offset_deg=args.pass_offset[1])))
        for name, synth_config in twins:
            data = args.out / name
            if not (data / 'transforms.json').is_file():
                generate_orchard(synth_config, data)
            dataset = load_dataset(data, eval_every=config.data.eval_every)
            started = time.perf_counter()
            report = start_poses(dataset, config, torch.device('cpu')).registration.report
            seconds = time.perf_counter() - started
            if 'score_zero' not in report:
                print(f"| {name} | {report.get('views', '-')} | {report.get('fruit_voxels', '-')} | | | | | "
                      f"no: {report['reason']} | {seconds:.0f} |")
                continue
            share = (report['score_best'] - report['score_zero']) / max(1, min(report['fruit_voxels']))
            print(f"| {name} | {report['views']} | {report['fruit_voxels']} | {report['score_zero']} / "
                  f"{report['score_best']} | {report['gain']:.3f} | {share:.3f} | {report['offset_m']} / "
                  f"{report['yaw_deg']} | {'yes' if report['applied'] else 'no'} | {seconds:.0f} |", flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
