"""The scene box and metric scale of a dataset measured on each device given, with wall time and peak CUDA memory.

Usage: python bench/gpu/scale_check.py DATASET [--devices cuda,cpu] [--preset default]
(the 2026-12-04 `gpu` suite failed here on CUDA: the batched eigvalsh of the view-spread test, now in closed form).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.scene_box import measure_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('dataset')
    parser.add_argument('--devices', default='cuda,cpu')
    parser.add_argument('--preset', default='default')
    args = parser.parse_args()
    config = TrainConfig.preset(args.preset)
    dataset = load_dataset(args.dataset, eval_every=config.data.eval_every)
    boxes = {}
    for name in args.devices.split(','):
        device = torch.device(name)
        if device.type == 'cuda':
            torch.cuda.reset_peak_memory_stats(device)
        start = time.perf_counter()
        box, scale = measure_scene(dataset, config, device)
        seconds = time.perf_counter() - start
        peak = torch.cuda.max_memory_allocated(device) / 2**20 if device.type == 'cuda' else None
        boxes[name] = box
        print(json.dumps({'device': name, 'seconds': round(seconds, 2), 'cuda_peak_mib': peak,
                          'box': np.round(box, 3).tolist(), **scale.to_json()}))
    if len(boxes) > 1:
        values = list(boxes.values())
        print('largest box difference between devices (m):',
              max(float(np.abs(v - values[0]).max()) for v in values[1:]))


if __name__ == '__main__':
    main()
