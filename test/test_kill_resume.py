"""``kill -9`` during collection, each training stage and the export, then a restart on the same output directory.

fruit_counter, ``fruitnerfpp replay --resume`` and ``fruitnerfpp run --resume`` each finish with the count of an
uninterrupted run and the bit-identical trained field (training resumes from the last checkpoint; on the CPU it
is bit-exact). The processes are real and are killed with SIGKILL at exact points (test/fault_injection.py makes
them stop there); a micro training config keeps each run to seconds.

CI kills each program at some of the points (every point is covered by one program); set
``FRUITNERFPP_FAULT_MATRIX=full`` to kill every program at every point (docs/results/robustness.md).
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import torch

from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
from fruitnerfpp_ros.nodes.bag_replay import collect_keyframes
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from test.core.training.stand_in_scene import make_sphere_scene
from test.nodes import bag_factory as bf

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]
FULL = os.environ.get('FRUITNERFPP_FAULT_MATRIX') == 'full'
ALL_POINTS = ['collection:4', 'train:geometry:3', 'train:semantic:3', 'train:instance:3', 'export']
POINTS = {  # CI: every point once; full: every program at every point
    'run': ALL_POINTS[1:] if FULL else ['train:geometry:3', 'export'],
    'replay': ALL_POINTS if FULL else ['collection:4', 'train:semantic:3'],
    'node': ALL_POINTS if FULL else ['collection:4', 'train:instance:3'],
}
MICRO_CONFIG = '''train:
  geometry: {iterations: 6, batch_rays: 128}
  semantic: {iterations: 4, batch_rays: 128}
  instance: {iterations: 4, groups: 2, group_size: 3, pixels_per_fruit: 8}
  render: {occupancy_update_every: 2, chunk_rays: 2048}
  data: {eval_every: 5}
  checkpoint_every: 2
  log_every: 1
  eval_max_views: 1
clustering:
  n_jobs: 1
'''
SETTINGS = settings_from_parameters({})


class Program:
    """A program started through test/fault_injection.py; stdout lines are collected in a thread."""

    def __init__(self, point: str, args: list[str], log: Path) -> None:
        self.point = point
        self._log = open(log, 'a')
        self._log.write(f'\n=== {point}: {" ".join(args)}\n')
        self._log.flush()
        self.proc = subprocess.Popen([sys.executable, '-m', 'test.fault_injection', point, *args], cwd=REPO,
                                     env=dict(os.environ), stdout=subprocess.PIPE, stderr=self._log, text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line)
        self.lines.put('')

    def kill_at_point(self, timeout_s: float = 240.0) -> None:
        """Wait for the program to reach its point, then SIGKILL it."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.5)
            except queue.Empty:
                continue
            if f'KILLPOINT {self.point}' in line:
                self.proc.send_signal(signal.SIGKILL)
                self.proc.wait(30)
                return
            if line == '':
                break
        self.proc.kill()
        raise AssertionError(f'{self.point}: the program ended or timed out first (rc {self.proc.wait(30)}); '
                             f'see {self._log.name}')

    def finish(self, timeout_s: float = 240.0) -> None:
        rc = self.proc.wait(timeout_s)
        assert rc == 0, f'{self.point}: exit code {rc}; see {self._log.name}'


@pytest.fixture(scope='module')
def faults(tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    """A 10-view sphere scene as a bag, its keyframes, the micro config and the uninterrupted reference run."""
    root = tmp_path_factory.mktemp('kill_resume')
    scene = make_sphere_scene(root / 'scene', views=10, size=32, fruits=6)
    messages = bf.dataset_messages(scene)
    bag = bf.write_bag(root / 'bag', messages)
    config = root / 'micro.yaml'
    config.write_text(MICRO_CONFIG)
    keyframes = collect_keyframes(bag, root / 'keyframes', SETTINGS, log=lambda *_: None).store.directory
    reference = root / 'reference'
    Program('none', ['fruitnerfpp_ros.cli.main', 'run', str(keyframes), '--out', str(reference), '--config',
                     str(config), '--device', 'cpu', '--preset', 'tiny'], root / 'reference.log').finish()
    return SimpleNamespace(root=root, messages=messages, bag=bag, config=config, keyframes=keyframes,
                           reference=reference, n_frames=len(read_transforms(keyframes).frames))


def _assert_same_as_reference(faults: SimpleNamespace, run_dir: Path, keyframes_dir: Path) -> None:
    assert [f.stamp_ns for f in read_transforms(keyframes_dir).frames] == \
        [f.stamp_ns for f in read_transforms(faults.keyframes).frames]  # no keyframe lost, none twice
    expected = json.loads((faults.reference / 'counts.json').read_text())
    counted = json.loads((run_dir / 'counts.json').read_text())
    assert (counted['total'], counted['fruits']) == (expected['total'], expected['fruits'])
    fields = [load_checkpoint(d / 'checkpoints' / 'latest.pt')['field'] for d in (faults.reference, run_dir)]
    assert fields[0].keys() == fields[1].keys()
    assert all(torch.equal(fields[0][k], fields[1][k]) for k in fields[0])  # resumed training is bit-exact


def test_fruitnerfpp_run_resumes_after_kill(faults: SimpleNamespace) -> None:
    out = faults.root / 'run_killed'
    args = ['fruitnerfpp_ros.cli.main', 'run', str(faults.keyframes), '--out', str(out), '--config',
            str(faults.config), '--device', 'cpu', '--preset', 'tiny', '--resume']
    for point in POINTS['run']:
        Program(point, args, faults.root / 'run.log').kill_at_point()
        with open(out / 'metrics.jsonl', 'a') as f:  # as if the kill had cut a line (before: JSONDecodeError)
            f.write('{"stage": "geometry", "st')
    assert not (out / 'counts.json').exists()
    Program('none', args, faults.root / 'run.log').finish()
    _assert_same_as_reference(faults, out, faults.keyframes)


def test_fruitnerfpp_replay_resumes_after_kill(faults: SimpleNamespace) -> None:
    out = faults.root / 'replay_killed'
    params = faults.root / 'replay_params.yaml'
    params.write_text(f'/**:\n  ros__parameters:\n    preset: tiny\n    device: cpu\n'
                      f'    config_file: {faults.config}\n')
    args = ['fruitnerfpp_ros.cli.main', 'replay', str(faults.bag), '--out', str(out), '--params', str(params),
            '--resume']
    for point in POINTS['replay']:
        Program(point, args, faults.root / 'replay.log').kill_at_point()
    assert not (out / 'counts.json').exists()
    Program('none', args, faults.root / 'replay.log').finish()
    _assert_same_as_reference(faults, out, out / 'keyframes')


class _Robot:
    """Publishes the scene's frames as live topics (reliable QoS) from this process."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from sensor_msgs.msg import CameraInfo, Image

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node('kill_test_robot', context=self.context)
        self.pubs = {topic: self.node.create_publisher(msg_type, topic, 100) for topic, msg_type in
                     [('/camera/image_raw', Image), ('/camera/camera_info', CameraInfo),
                      ('/camera/pose', PoseStamped), ('/camera/instance_mask', Image)]}
        self.last_diagnostics = 0.0
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      lambda _: setattr(self, 'last_diagnostics', time.monotonic()), 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        threading.Thread(target=self.executor.spin, daemon=True).start()

    def publish_after(self, messages: list[tuple[str, str, int, Any]], newest_kept_ns: int,
                      started: float) -> None:
        """Wait until the node started at ``started`` is up (its /diagnostics: a killed node's subscriptions
        linger in discovery), then publish the frames newer than ``newest_kept_ns``."""
        deadline = time.monotonic() + 60
        while self.last_diagnostics < started or not all(p.get_subscription_count() for p in self.pubs.values()):
            assert time.monotonic() < deadline, 'fruit_counter did not come up'
            time.sleep(0.05)
        time.sleep(0.5)
        for topic, _, stamp, msg in messages:
            if stamp > newest_kept_ns:
                self.pubs[topic].publish(msg)
                time.sleep(0.005)

    def close(self) -> None:
        import rclpy
        self.executor.shutdown(timeout_sec=5.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def test_fruit_counter_resumes_after_kill(faults: SimpleNamespace) -> None:
    out = faults.root / 'node_killed'
    args = ['fruitnerfpp_ros.nodes.fruit_counter', '--ros-args', '-p', f'output_dir:={out}',
            '-p', 'input_reliability:=reliable', '-p', 'preset:=tiny', '-p', 'device:=cpu',
            '-p', f'config_file:={faults.config}', '-p', f'auto_train_after:={faults.n_frames}']
    robot = _Robot()
    try:
        for point in POINTS['node'] + ['none']:
            started = time.monotonic()
            program = Program(point, args, faults.root / 'node.log')
            kept = [f.stamp_ns for f in KeyframeStore(out / 'keyframes').frames] if (out / 'keyframes').exists() \
                else []
            if len(kept) < faults.n_frames:  # the robot drives on: the frames the node has not kept yet
                robot.publish_after(faults.messages, max(kept, default=0), started)
            if point != 'none':
                program.kill_at_point()
                continue
            report = out / 'train_001' / 'fruit_report.json'
            deadline = time.monotonic() + 240
            while not report.is_file() and program.proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.2)
            program.proc.send_signal(signal.SIGINT)
            program.finish(60)
    finally:
        robot.close()
    assert json.loads((out / 'train_001' / 'fruit_report.json').read_text())['keyframes'] == faults.n_frames
    assert not (out / 'train_002').exists()  # the interrupted run was resumed, not started again
    _assert_same_as_reference(faults, out / 'train_001', out / 'keyframes')
