#!/usr/bin/env python3
"""Load benchmark of the live fruit_counter: 1280x720 images + instance masks + poses at 30 Hz for minutes.

Starts ``fruit_counter`` as its own process (its output directory in a temporary folder), publishes a moving
camera from this process (sensor-data QoS, as a camera driver does) and measures, once a second:

- the node's resident memory (``VmRSS`` / peak ``VmHWM`` from /proc): bounded, keyframes live on disk;
- ``/diagnostics``: input rates, messages received, queue drops, keyframes, state;
- the answer time of ``~/save`` (asked every 0.5 s): the executor never stalls.

Halfway through it calls ``~/train`` with a micro training config: keyframes keep arriving while the run trains.
Prints a Markdown summary (docs/results/robustness.md holds the 10-minute run).

Usage::

    python bench/load_bench.py                    # 60 s (quick)
    python bench/load_bench.py --duration 600     # the 10-minute run
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

MICRO_CONFIG = '''train:
  geometry: {iterations: 30, batch_rays: 256}
  semantic: {iterations: 20, batch_rays: 256}
  instance: {iterations: 20, groups: 2, group_size: 3, pixels_per_fruit: 8}
  data: {eval_every: 0}
  checkpoint_every: 10
  log_every: 5
clustering:
  n_jobs: 1
'''


def _frames(width: int, height: int, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` textured RGB images (gradients + noise, PNG-compressible like a real scene) with 3-6 fruit disks."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:height, 0:width]
    out = []
    for k in range(n):
        base = np.stack([(xx * (k + 1)) % 256, (yy * 2) % 256, ((xx + yy) // 3 + 40 * k) % 256], -1)
        rgb = (base + rng.integers(0, 24, base.shape)).clip(0, 255).astype(np.uint8)
        mask = np.zeros((height, width), np.uint16)
        for fruit in range(1, rng.integers(4, 7)):
            cx, cy, r = rng.integers(60, width - 60), rng.integers(60, height - 60), rng.integers(15, 40)
            disk = (xx - cx) ** 2 + (yy - cy) ** 2 < r ** 2
            mask[disk] = fruit
            rgb[disk] = (200, 30 + 10 * fruit, 20)
        out.append((rgb, mask))
    return out


class Bench:
    """The publisher, the diagnostics listener and the service prober (one rclpy node in this process)."""

    def __init__(self, args: argparse.Namespace) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from rclpy.executors import MultiThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import CameraInfo, Image
        from std_srvs.srv import Trigger

        from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
        from fruitnerfpp_ros.nodes.conversions import camera_info_msg_from_intrinsics, image_msg_from_array

        self.args = args
        rclpy.init()
        self.node = rclpy.create_node('load_bench')
        qos = qos_profile_sensor_data
        self.pubs = {'image': self.node.create_publisher(Image, '/camera/image_raw', qos),
                     'mask': self.node.create_publisher(Image, '/camera/instance_mask', qos),
                     'pose': self.node.create_publisher(PoseStamped, '/camera/pose', qos),
                     'camera_info': self.node.create_publisher(CameraInfo, '/camera/camera_info', qos)}
        w, h = args.width, args.height
        intrinsics = CameraIntrinsics(0.8 * w, 0.8 * w, w / 2, h / 2, w, h)
        self.messages = [(image_msg_from_array(rgb, 'rgb8', 'camera_optical', 0),
                          image_msg_from_array(mask, 'mono16', 'camera_optical', 0))
                         for rgb, mask in _frames(w, h, 6)]
        self.info = camera_info_msg_from_intrinsics(intrinsics, 'camera_optical', 0)
        self.pose = PoseStamped()
        self.pose.header.frame_id = 'map'
        self.pose.pose.orientation.w = 1.0
        self.published = 0
        self.diagnostics: list[tuple[float, dict[str, str], str]] = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.save = self.node.create_client(Trigger, '/fruit_counter/save')
        self.train = self.node.create_client(Trigger, '/fruit_counter/train')
        self.executor = MultiThreadedExecutor(num_threads=2)
        self.executor.add_node(self.node)
        self._spin = threading.Thread(target=self.executor.spin, daemon=True)
        self._spin.start()

    def close(self) -> None:
        import rclpy
        self.executor.shutdown(timeout_sec=5.0)
        self.node.destroy_node()
        rclpy.try_shutdown()
        self._spin.join(5.0)

    def _on_diagnostics(self, msg: Any) -> None:
        status = msg.status[0]
        self.diagnostics.append((time.monotonic(), {kv.key: kv.value for kv in status.values}, status.message))

    def call(self, client: Any, timeout_s: float = 10.0) -> tuple[Any, float]:
        from std_srvs.srv import Trigger
        started = time.monotonic()
        future = client.call_async(Trigger.Request())
        while not future.done() and time.monotonic() - started < timeout_s:
            time.sleep(0.002)
        return future.result(), time.monotonic() - started

    def publish(self, k: int) -> None:
        """Frame ``k``: the camera moves 1 cm per frame along x."""
        stamp = self.node.get_clock().now().to_msg()
        image, mask = self.messages[k % len(self.messages)]
        for msg in (image, mask, self.info, self.pose):
            msg.header.stamp = stamp
        self.pose.pose.position.x = 0.01 * k
        self.pubs['camera_info'].publish(self.info)
        self.pubs['pose'].publish(self.pose)
        self.pubs['image'].publish(image)
        self.pubs['mask'].publish(mask)
        self.published += 1


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _rss_kib(pid: int) -> tuple[int, int]:
    fields = dict(line.split(':', 1) for line in Path(f'/proc/{pid}/status').read_text().splitlines() if ':' in line)
    return int(fields['VmRSS'].split()[0]), int(fields['VmHWM'].split()[0])


def run(args: argparse.Namespace) -> int:
    work = Path(tempfile.mkdtemp(prefix='load_bench_'))
    config = work / 'micro.yaml'
    config.write_text(MICRO_CONFIG)
    node = subprocess.Popen([sys.executable, '-m', 'fruitnerfpp_ros.nodes.fruit_counter', '--ros-args',
                             '-p', f'output_dir:={work / "run"}', '-p', f'config_file:={config}', '-p', 'preset:=tiny',
                             '-p', 'device:=cpu', '-p', f'min_translation_m:={args.keyframe_every_m}',
                             '-p', 'max_keyframes:=100000', '-p', 'min_keyframes:=3'],
                            env=dict(os.environ), stdout=subprocess.DEVNULL, stderr=open(work / 'node.log', 'w'))
    bench = Bench(args)
    try:
        while not bench.diagnostics:
            time.sleep(0.1)
            if node.poll() is not None:
                raise SystemExit(f'fruit_counter ended: see {work / "node.log"}')
        start = time.monotonic()
        period = 1.0 / args.rate
        rss: list[tuple[float, int, int]] = []
        latencies: list[tuple[float, float]] = []
        train_answer, train_at, keyframes_at_train = '', None, 0
        next_probe = next_sample = start
        k = 0
        while time.monotonic() - start < args.duration:
            now = time.monotonic()
            target = start + k * period
            if now < target:
                time.sleep(min(target - now, 0.005))
                continue
            bench.publish(k)
            k += 1
            if now >= next_sample:
                rss.append((now - start, *_rss_kib(node.pid)))
                next_sample += 1.0
            if now >= next_probe:
                threading.Thread(target=lambda at=now - start: latencies.append((at, bench.call(bench.save)[1])),
                                 daemon=True).start()
                next_probe += 0.5
            if train_at is None and now - start >= args.duration * args.train_at:
                answer, _ = bench.call(bench.train)
                train_at, train_answer = now - start, answer.message
                keyframes_at_train = int(bench.diagnostics[-1][1].get('keyframes', 0))
        time.sleep(2.0)
        cpu = {'node': _cpu_s(node.pid), 'publisher': _cpu_s(os.getpid())}
        _report(args, bench, rss, latencies, train_at, train_answer, keyframes_at_train, time.monotonic() - start,
                start, work)
        elapsed = time.monotonic() - start
        print(f'CPU use: node {100 * cpu["node"] / elapsed:.0f}%, publisher {100 * cpu["publisher"] / elapsed:.0f}% '
              f'of one core; load average {os.getloadavg()[0]:.1f} (other processes on the machine included)')
    finally:
        node.terminate()
        node.wait(30)
        bench.close()
    return 0


def _state_at(states: list[tuple[float, str, int]], t: float) -> str:
    before = [state for ts, state, _ in states if ts <= t]
    return before[-1] if before else 'starting'


def _phases(rss: list[tuple[float, int, int]], states: list[tuple[float, str]]) -> dict[str, float]:
    """Largest RSS (MiB) while collecting before ~/train, while the run trained, and after it ended."""
    def state_at(t: float) -> str:
        before = [s for ts, s in states if ts <= t]
        return before[-1] if before else 'collecting'
    phases: dict[str, list[int]] = {'before training': [], 'during training': [], 'after training': []}
    trained = False
    for t, kib, _ in rss:
        state = state_at(t)
        if state in ('training', 'exporting', 'counting'):
            trained = True
            phases['during training'].append(kib)
        else:
            phases['after training' if trained else 'before training'].append(kib)
    return {name: max(v) / 1024 for name, v in phases.items() if v}


def _report(args: argparse.Namespace, bench: Bench, rss: list[tuple[float, int, int]],
            latencies: list[tuple[float, float]],
            train_at: float | None, train_answer: str, keyframes_at_train: int, elapsed: float, start: float,
            work: Path) -> None:
    last = bench.diagnostics[-1][1]
    rates = {key.split('/', 1)[1]: [float(d[1][key]) for d in bench.diagnostics if key in d[1] and d[0] > start + 2]
             for key in last if key.startswith('rate_hz/')}
    states = [(t - start, d.get('state', ''), int(d.get('keyframes', 0))) for t, d, _ in bench.diagnostics]
    during = [kf for _, state, kf in states if state in ('training', 'exporting', 'counting')]
    lat = np.array([seconds for _, seconds in latencies] or [float('nan')])
    slow = [f'{at:.0f} s ({seconds:.2f} s, {_state_at(states, at)})' for at, seconds in latencies if seconds > 0.5]
    received_images = int(last.get('received//camera/image_raw', 0))
    skipped = ', '.join(f'{k} {v}' for k, v in last.items() if k.startswith(('skipped/', 'rejected/')))
    print(f'# fruit_counter load: {args.width}x{args.height} rgb8 + mono16 masks + poses at {args.rate:g} Hz, '
          f'{elapsed:.0f} s, {os.cpu_count()} CPUs\n')
    print('| quantity | value |\n|---|---|')
    print(f'| frames published | {bench.published} ({bench.published / elapsed:.1f} Hz) |')
    for topic, values in sorted(rates.items()):
        print(f'| {topic} | received {last.get(f"received/{topic}", "?")}, rate {np.mean(values):.1f} Hz mean, '
              f'{np.min(values):.1f}-{np.max(values):.1f}; queue drops {last.get(f"dropped_queue/{topic}", "0")} |')
    print(f'| images lost before the node (DDS best effort) | {bench.published - received_images} |')
    print(f'| skipped | {skipped or "none"}, sync_unmatched {last.get("sync_unmatched")} |')
    print(f'| keyframes on disk | {last.get("keyframes")} |')
    phases = ', '.join(f'{name} {mib:.0f} MiB' for name, mib in _phases(rss, [(t, s) for t, s, _ in states]).items())
    print(f'| node RSS (max per phase) | {phases}; end {rss[-1][1] / 1024:.0f} MiB; peak (VmHWM) '
          f'{rss[-1][2] / 1024:.0f} MiB |')
    print(f'| ~/save answer time | median {np.median(lat) * 1e3:.0f} ms, p99 {np.percentile(lat, 99) * 1e3:.0f} ms, '
          f'max {lat.max() * 1e3:.0f} ms over {len(latencies)} calls; over 0.5 s at: {", ".join(slow) or "none"} |')
    if train_at is not None:
        print(f'| ~/train at {train_at:.0f} s | {train_answer} |')
        grown = max(during, default=keyframes_at_train) - keyframes_at_train
        print(f'| keyframes collected while the run trained | {grown} (final state {last.get("state")}, '
              f'{last.get("fruit_count") or "no"} fruits counted) |')
    print(f'\nnode log and run: {work}')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=60.0, help='seconds of publishing (default 60)')
    parser.add_argument('--rate', type=float, default=30.0, help='frames per second (default 30)')
    parser.add_argument('--width', type=int, default=1280)
    parser.add_argument('--height', type=int, default=720)
    parser.add_argument('--keyframe-every-m', type=float, default=0.3,
                        help='min_translation_m: the camera moves 1 cm per frame (default 0.3: one keyframe a second)')
    parser.add_argument('--train-at', type=float, default=0.15, help='call ~/train at this fraction of the run')
    return run(parser.parse_args())


if __name__ == '__main__':
    sys.exit(main())
