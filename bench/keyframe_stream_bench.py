#!/usr/bin/env python3
"""A long drive through the collector: N keyframes (default 10,000) of small images through the FrameAssembler.

Measures the time per keyframe in each quarter of the drive (flat = O(1) per keyframe), the process's peak
memory, the journal and transforms.json sizes, a snapshot (what ~/train freezes) and re-opening the directory
(what a restarted node does). Before the journal, transforms.json was rewritten after every keyframe: 1,000
keyframes took 24 s and 10,000 about 40 minutes.

Usage::

    python bench/keyframe_stream_bench.py              # 10,000 keyframes (~1 min on 2 cores)
    python bench/keyframe_stream_bench.py -n 2000
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped

from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.nodes.conversions import (camera_info_msg_from_intrinsics, image_msg_from_array,
                                               pose_msg_from_transform, time_msg_from_ns)
from fruitnerfpp_ros.nodes.frame_assembler import FrameAssembler
from fruitnerfpp_ros.nodes.params import keyframe_config, settings_from_parameters


def run(n: int) -> None:
    h, w = 24, 32
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    mask = np.zeros((h, w), np.uint16)
    mask[4:10, 6:12], mask[12:18, 16:22] = 1, 2
    start_ns, period_ns = 1_700_000_000_000_000_000, 100_000_000
    info = camera_info_msg_from_intrinsics(CameraIntrinsics(30.0, 30.0, 16.0, 12.0, w, h), 'camera_optical', 0)
    image, instance = image_msg_from_array(rgb, 'rgb8', 'camera_optical', 0), image_msg_from_array(mask, 'mono16',
                                                                                                   'camera_optical', 0)
    pose = PoseStamped()
    with tempfile.TemporaryDirectory() as tmp:
        settings = settings_from_parameters({'max_keyframes': n + 1, 'min_translation_m': 0.05})
        store = KeyframeStore(Path(tmp) / 'keyframes', keyframe_config(settings))
        assembler = FrameAssembler(settings, store, lambda *_: None)
        quarters, t0 = [], time.perf_counter()
        for k in range(n):
            stamp = time_msg_from_ns(start_ns + k * period_ns)
            T = np.eye(4)
            T[0, 3] = 0.1 * k
            pose.pose = pose_msg_from_transform(T)
            for msg in (info, image, instance, pose):
                msg.header.stamp = stamp
            for role, msg in (('camera_info', info), ('image', image), ('mask', instance), ('pose', pose)):
                assembler.on_message(role, msg)
            if (k + 1) % (n // 4) == 0:
                quarters.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
        store.flush()
        per_kf = [1e3 * q / (n // 4) for q in quarters]
        directory = store.directory
        started = time.perf_counter()
        snapshot = store.snapshot(Path(tmp) / 'snapshot')
        snapshot_s = time.perf_counter() - started
        started = time.perf_counter()
        reopened = len(KeyframeStore(directory))
        reopen_s = time.perf_counter() - started
        peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f'| keyframes | {len(store)} (errors {assembler.status().errors or "none"}) |')
        print(f'| ms per keyframe, quarters 1-4 | {" / ".join(f"{v:.2f}" for v in per_kf)} |')
        print(f'| total | {sum(quarters):.1f} s |')
        print(f'| frames.jsonl / transforms.json | {(directory / "frames.jsonl").stat().st_size / 1e6:.1f} MB / '
              f'{(directory / "transforms.json").stat().st_size / 1e6:.1f} MB |')
        print(f'| snapshot (~/train) | {snapshot.n_keyframes} keyframes in {snapshot_s:.2f} s |')
        print(f'| re-open (restart) | {reopened} keyframes in {reopen_s:.2f} s |')
        print(f'| peak RSS of the process | {peak_mib:.0f} MiB |')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('-n', type=int, default=10_000, help='keyframes (default 10,000)')
    run(parser.parse_args().n)
    return 0


if __name__ == '__main__':
    sys.exit(main())
