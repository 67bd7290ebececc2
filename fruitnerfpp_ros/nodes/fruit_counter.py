"""The ``fruit_counter`` node: collects keyframes from live topics, trains in the background, publishes the count.

Threading (nvblox-style): subscription callbacks only append to bounded per-input deques (oldest dropped and
counted); a tick timer drains them through the shared :class:`FrameAssembler` (keyframes written to disk as they
arrive); training runs :func:`fruitnerfpp_ros.core.pipeline.run_pipeline` in a background thread with a stop event,
so the executor keeps spinning, reporting and collecting (keyframes that arrive during training are kept for the
next ``~/train``). Runs are managed by :class:`~fruitnerfpp_ros.nodes.training_runs.TrainingRuns`.

Restarted on the same ``output_dir`` (after ``kill -9`` or a power loss) the node keeps every keyframe collected,
publishes the last finished count again and resumes a training run that was interrupted from its last checkpoint.

Interface (see docs/ros_interface.md): inputs ``image_topic`` / ``camera_info_topic`` / ``mask_topic`` (or a
segmenter, ``mask_source``) / pose (``pose_topic``, ``odometry_topic`` or /tf + /tf_static) / optional
``depth_topic``; services ``~/train``,
``~/reset``, ``~/save`` (std_srvs/Trigger); latched outputs ``~/fruit_count``, ``~/fruit_report``, ``~/fruit_cloud``,
``~/fruit_centers``, ``~/fruit_markers``; ``/diagnostics``. With ``row_mode`` (:mod:`.row_counter`) the row is
counted segment by segment while it is driven: ``~/tree_counts``, ``~/tree_markers`` and a running ``~/fruit_count``.
"""

from __future__ import annotations

import heapq
import itertools
import os
import sys
import threading
import time
from collections import deque
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import yaml

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.nodes.frame_assembler import FrameAssembler
from fruitnerfpp_ros.nodes.log import LogLevel, ThrottledLog
from fruitnerfpp_ros.nodes.mask_source import mask_source_from_settings
from fruitnerfpp_ros.nodes.params import declare_parameters, keyframe_config, settings_mapping
from fruitnerfpp_ros.nodes.row_params import declare_row_parameters
from fruitnerfpp_ros.nodes.results import DIAGNOSTICS_TOPIC, OUTPUT_TOPICS, diagnostics_msg, write_report
from fruitnerfpp_ros.nodes.node_main import spin_node
from fruitnerfpp_ros.nodes.status import NodeState, NodeStatus, RunStatus
from fruitnerfpp_ros.nodes.training_runs import TrainingRuns

__all__ = ['FruitCounterNode', 'main', 'default_output_dir', 'LATCHED_QOS']

#: Results: late subscribers get the last message (RViz, Foxglove, farm software joining later).
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
_TF_STATIC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
_TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
#: The tick brings keyframes/transforms.json up to date at least this often (the journal holds every keyframe).
_INDEX_FLUSH_S = 2.0


def default_output_dir() -> Path:
    """``$ROS_HOME/fruitnerfpp/run_<UTC time>`` (``ROS_HOME`` defaults to ``~/.ros``)."""
    ros_home = Path(os.environ.get('ROS_HOME') or Path.home() / '.ros')
    return ros_home / 'fruitnerfpp' / datetime.now(timezone.utc).strftime('run_%Y%m%dT%H%M%SZ')


class FruitCounterNode(Node):
    """Counts fruit from posed images and instance masks (see the module docstring)."""

    def __init__(self, node_name: str = 'fruit_counter', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings = declare_parameters(self)
        self.row_settings = declare_row_parameters(self)
        s = self.settings
        # a segmenter loads its model first: a bad checkpoint stops the node (spin_node prints the error) before
        # any run folder exists
        mask_source = mask_source_from_settings(s)
        self.run_dir = Path(s.output_dir).expanduser() if s.output_dir else default_output_dir()
        self.run_dir.mkdir(parents=True, exist_ok=True)
        row_values = settings_mapping(self.row_settings) if self.row_settings.row_mode else {}
        (self.run_dir / 'params.yaml').write_text(yaml.safe_dump(
            {'/**': {'ros__parameters': {**settings_mapping(s), **row_values}}}, sort_keys=False))
        self.store = KeyframeStore(self.run_dir / 'keyframes', keyframe_config(s), mask_source=s.mask_source)
        self.assembler = FrameAssembler(s, self.store, self._log, mask_source=mask_source)
        self._warn_throttled = ThrottledLog(self._log, period_s=30.0)

        # Inputs: callbacks enqueue only.
        self._seq = itertools.count()
        self._queues: dict[str, deque[tuple[int, Any]]] = {}
        self._queue_lock = threading.Lock()
        self.dropped: dict[str, int] = {}
        self._received: dict[str, int] = {}
        self._last_rx: dict[str, float] = {}
        self._started = self._rate_since = self._index_flushed = time.monotonic()
        self._write_errors_reported = 0
        self._rate_window: dict[str, int] = {}
        sensor_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=s.queue_size,
                                reliability=ReliabilityPolicy.BEST_EFFORT if s.input_reliability == 'best_effort'
                                else ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        inputs = ReentrantCallbackGroup()
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image
        self._subscribe('image', CompressedImage if s.compressed_image else Image, s.image_topic, sensor_qos, inputs)
        self._subscribe('camera_info', CameraInfo, s.camera_info_topic, sensor_qos, inputs)
        if self.assembler.mask_source.topic is not None:
            self._subscribe('mask', Image, self.assembler.mask_source.topic, sensor_qos, inputs)
        if s.depth_topic:
            self._subscribe('depth', Image, s.depth_topic, sensor_qos, inputs)
        if s.pose_source == 'pose':
            from geometry_msgs.msg import PoseStamped
            self._subscribe('pose', PoseStamped, s.pose_topic, sensor_qos, inputs)
        elif s.pose_source == 'odometry':
            from nav_msgs.msg import Odometry
            self._subscribe('odometry', Odometry, s.odometry_topic, sensor_qos, inputs)
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            needs_tf = s.pose_source == 'tf' or (s.pose_source == 'odometry' and not s.camera_extrinsic)
            self._log(LogLevel.ERROR if needs_tf else LogLevel.INFO,
                      'tf2_msgs is not installed in this Python environment (it is not on PyPI): /tf and /tf_static '
                      'are not subscribed' + ("; pose_source needs them: use pose_source 'pose', or 'odometry' "
                                              'with camera_extrinsic, or run inside a ROS 2 installation'
                                              if needs_tf else ''))
        else:
            self._subscribe('tf', TFMessage, '/tf', _TF_QOS, inputs)
            self._subscribe('tf_static', TFMessage, '/tf_static', _TF_STATIC_QOS, inputs)

        # Outputs.
        import importlib
        self._result_pubs = {}
        for topic in OUTPUT_TOPICS:
            package, _, name = topic.msg_type.split('/')
            msg_class = getattr(importlib.import_module(f'{package}.msg'), name)
            self._result_pubs[topic.name] = self.create_publisher(msg_class, f'~/{topic.name}', LATCHED_QOS)
        from diagnostic_msgs.msg import DiagnosticArray
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self.row = self._start_row_mode(inputs) if self.row_settings.row_mode else None

        # Work: tick (processing) and services / diagnostics in separate groups, so neither blocks the other.
        from std_srvs.srv import Trigger
        control = MutuallyExclusiveCallbackGroup()
        self.create_service(Trigger, '~/train', self._on_train, callback_group=control)
        self.create_service(Trigger, '~/reset', self._on_reset, callback_group=control)
        self.create_service(Trigger, '~/save', self._on_save, callback_group=control)
        self.create_timer(0.02, self._tick, callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(s.diagnostics_period_s, self._publish_diagnostics, callback_group=control)

        # Training runs (a background thread; resumed here when a kill interrupted one).
        self.runs = TrainingRuns(self.run_dir, self.store, self._log, self._publish_results)
        self._auto_started = False
        self._restore_runs()
        trigger = f'auto-train after {s.auto_train_after}' if s.auto_train_after else 'train on ~/train'
        masks = {'topic': f'masks from {s.mask_topic}',
                 'semantic_topic': f'fruit masks from {s.mask_topic} split into blobs'}.get(
            s.mask_source, f'masks from the {s.mask_source} segmenter')
        self.get_logger().info(f'collecting keyframes into {self.store.directory} (pose source {s.pose_source}, '
                               f'{masks}, {trigger})')

    # ------------------------------------------------------------------ logging
    def _log(self, level: LogLevel, message: str) -> None:
        # One call site per severity: rclpy refuses a severity change at one call site.
        if level is LogLevel.ERROR:
            self.get_logger().error(message)
        elif level is LogLevel.WARN:
            self.get_logger().warning(message)
        else:
            self.get_logger().info(message)

    # ------------------------------------------------------------------ inputs
    def _subscribe(self, role: str, msg_type: Any, topic: str, qos: QoSProfile, group: Any) -> None:
        self._queues[role] = deque()
        self.dropped[role] = 0
        self._received[role] = 0
        self._rate_window[role] = 0
        limit = self.settings.queue_size if role not in ('tf', 'tf_static') else max(self.settings.queue_size, 200)

        def enqueue(msg: Any) -> None:
            with self._queue_lock:
                queue = self._queues[role]
                if len(queue) >= limit:
                    queue.popleft()
                    self.dropped[role] += 1
                queue.append((next(self._seq), msg))
                self._received[role] += 1
                self._rate_window[role] += 1
                self._last_rx[role] = time.monotonic()
        self.create_subscription(msg_type, topic, enqueue, qos, callback_group=group)

    def _tick(self) -> None:
        with self._queue_lock:
            batches = [[(seq, role, msg) for seq, msg in queue] for role, queue in self._queues.items()]
            for queue in self._queues.values():
                queue.clear()
        for _, role, msg in heapq.merge(*batches, key=lambda e: e[0]):
            try:
                self.assembler.on_message(role, msg)
            except Exception as err:  # noqa: BLE001 - nothing a message does may stop the node
                self._log(LogLevel.ERROR, f'{self.assembler.topic_of(role)}: message dropped: '
                          f'{type(err).__name__}: {err}')
        now = time.monotonic()
        if now - self._index_flushed > _INDEX_FLUSH_S:  # the tick writes keyframes, so it never waits here
            self._index_flushed = now
            self.store.flush()
        s = self.settings
        if self.row is not None:
            self.row.tick()
            return
        if s.auto_train_after and not self._auto_started and len(self.store) >= s.auto_train_after:
            self._auto_started = True
            ok, message = self.start_training()
            self._log(LogLevel.INFO if ok else LogLevel.WARN,
                      f'auto-train after {s.auto_train_after} keyframes: {message}')

    # ------------------------------------------------------------------ training
    @property
    def training(self) -> bool:
        """A training run's thread is alive (also while it stops)."""
        return self.runs.running

    @property
    def run_status(self) -> RunStatus:
        """State of the training runs: state, phase, progress, last error, last count and report."""
        return self.runs.status

    def start_training(self) -> tuple[bool, str]:
        """Start a training run on the keyframes collected so far; returns (started, message)."""
        return self.runs.start(self.settings)

    def stop_training(self, timeout_s: float = 10.0) -> None:
        """Ask a running training to stop (it checkpoints) and wait up to ``timeout_s`` for it."""
        self.runs.stop(timeout_s)

    def _publish_results(self, messages: dict[str, Any]) -> None:
        for name, msg in messages.items():
            self._result_pubs[name].publish(msg)

    def _restore_runs(self) -> None:
        """After a restart: publish the last finished count again and resume a run a kill interrupted."""
        last = self.runs.last_finished_report()
        if last is not None:
            from std_msgs.msg import String, UInt32
            count, report = last
            self._publish_results({'fruit_count': UInt32(data=count), 'fruit_report': String(data=report)})
            self.runs.update(state=NodeState.DONE, progress=1.0, last_count=count, last_report=report)
        resumed = self.runs.resume_interrupted(self.settings)
        if resumed is not None:
            self._log(LogLevel.WARN, resumed)
        self._auto_started = self.runs.index > 0  # auto-train happens once per output directory

    # ------------------------------------------------------------------ services
    def _on_train(self, request: Any, response: Any) -> Any:
        response.success, response.message = self.row.flush() if self.row is not None else self.start_training()
        return response

    def _start_row_mode(self, group: Any) -> Any:
        """Row mode: the row publishers, the GNSS subscription and the row counter (its worker thread)."""
        import importlib

        from fruitnerfpp_ros.core.orchard.gnss import GnssFix
        from fruitnerfpp_ros.nodes.row_counter import RowCounter
        from fruitnerfpp_ros.nodes.row_results import ROW_OUTPUT_TOPICS
        for topic in ROW_OUTPUT_TOPICS:
            package, _, name = topic.msg_type.split('/')
            msg_class = getattr(importlib.import_module(f'{package}.msg'), name)
            self._result_pubs[topic.name] = self.create_publisher(msg_class, f'~/{topic.name}', LATCHED_QOS)
        row = RowCounter(self.run_dir, self.store, self.settings, self.row_settings, self._log, self._publish_results)
        if self.row_settings.gnss_topic:
            from sensor_msgs.msg import NavSatFix

            def on_fix(msg: Any) -> None:
                stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                known = int(msg.position_covariance_type) > 0
                row.on_fix(GnssFix(stamp, msg.latitude, msg.longitude, msg.altitude,
                                   tuple(msg.position_covariance) if known else None, int(msg.status.status)))
            self.create_subscription(NavSatFix, self.row_settings.gnss_topic, on_fix, 50, callback_group=group)
        self.get_logger().info(f'row mode: segments trained as the robot passes them ({row.dir})')
        return row

    def _on_reset(self, request: Any, response: Any) -> Any:
        """Answers at once: a running training is told to stop (and never resumed), the keyframes move aside."""
        stopped = self.runs.abandon()
        try:
            moved = self.store.reset()
        except OSError as err:
            response.success, response.message = False, f'reset failed: cannot move the keyframes aside: {err}'
            return response
        self.assembler.reset()
        self._auto_started = False
        self.runs.update(state=NodeState.COLLECTING, phase=None, progress=0.0, last_error='')
        response.success = True
        response.message = (f'reset; previous keyframes kept in {moved}' if moved else 'reset; nothing collected yet') \
            + (f'; training run {stopped} stopped (it is not resumed)' if stopped else '')
        return response

    def _on_save(self, request: Any, response: Any) -> Any:
        """Answers without waiting for the disk: keyframes are stored as they arrive, the tick rewrites
        transforms.json within ``_INDEX_FLUSH_S`` (waiting for a keyframe being encoded took > 1 s under load)."""
        saved = [f'keyframes: {self.store.directory} ({len(self.store)})']
        report = self.run_status.last_report
        if report is not None:
            saved.append(f'report: {write_report(self.run_dir / "fruit_report.json", report)}')
        response.success, response.message = True, '; '.join(saved)
        return response

    # ------------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        try:
            self._publish_diagnostics_now()
        except Exception as err:  # noqa: BLE001 - an exception in a timer would stop the executor
            self._warn_throttled(LogLevel.ERROR, 'diagnostics', f'/diagnostics not published: '
                                 f'{type(err).__name__}: {err}')

    def _publish_diagnostics_now(self) -> None:
        s = self.settings
        now = time.monotonic()
        with self._queue_lock:
            elapsed = max(now - self._rate_since, 1e-3)  # the timer may fire late under load
            rates = {role: n / elapsed for role, n in self._rate_window.items()}
            self._rate_window = dict.fromkeys(self._rate_window, 0)
            self._rate_since = now
            last_rx = dict(self._last_rx)
            dropped = {self.assembler.topic_of(role): n for role, n in self.dropped.items()}
            received = {self.assembler.topic_of(role): n for role, n in self._received.items()}
        run = self.run_status
        # Inputs are expected while collecting; once a drive is done and training runs, silence is normal.
        watched = self.assembler.required_roles() + self.assembler.optional_roles()  # a silent depth topic too
        silent = [role for role in watched if role in self._queues
                  and now - last_rx.get(role, self._started) > s.silent_input_warning_s] \
            if run.state is NodeState.COLLECTING and not self.training else []
        for role in silent:
            self._warn_throttled(LogLevel.WARN, f'silent:{role}', f'no message on {self.assembler.topic_of(role)} '
                                 f'for {now - last_rx.get(role, self._started):.0f} s')
        frames = self.assembler.status()
        write_error = self.store.last_write_error if frames.write_errors > self._write_errors_reported else ''
        self._write_errors_reported = frames.write_errors
        status = NodeStatus.from_parts(run, frames, dropped_queue=sum(dropped.values()), run_dir=self.run_dir,
                                       rates_hz={self.assembler.topic_of(r): v for r, v in rates.items()},
                                       silent_topics=tuple(self.assembler.topic_of(r) for r in silent),
                                       dropped_per_topic=dropped, write_error=write_error,
                                       received_per_topic=received)
        values = {**status.values(), **(self.row.diagnostics() if self.row is not None else {})}
        self._diagnostics_pub.publish(diagnostics_msg(f'{self.get_name()}: pipeline', self.get_name(), status.level,
                                                      status.message(), values, self.get_clock().now().nanoseconds))


def main(args: list[str] | None = None) -> int:
    """Run the node (``ros2 run fruitnerfpp_ros fruit_counter [--ros-args ...]``)."""
    return spin_node('fruit_counter', FruitCounterNode, lambda: MultiThreadedExecutor(num_threads=3), args,
                     on_shutdown=_shutdown)


def _shutdown(node: FruitCounterNode) -> None:
    node.stop_training(timeout_s=5.0)  # the run checkpoints; a restart resumes it
    if node.row is not None:
        node.row.stop(timeout_s=5.0)
    node.store.flush()


if __name__ == '__main__':
    sys.exit(main())
