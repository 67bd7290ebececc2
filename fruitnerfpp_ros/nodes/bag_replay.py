"""Offline replay of a recorded rosbag2 (sqlite3 or MCAP): collect keyframes, train, count, write results.mcap.

The bag is read with rosbags (no ROS graph, no DDS) and its messages go through the same
:class:`~fruitnerfpp_ros.nodes.frame_assembler.FrameAssembler` as the live node's topics. Outputs in ``RUN_DIR``::

    keyframes/          the collected transforms.json dataset (retrain with ``fruitnerfpp train``)
    ...                 the training run (config.yaml, checkpoints/, cloud.ply, counts.json...)
    fruit_report.json   the ~/fruit_report payload
    results.mcap        the node's output topics (/fruit_counter/fruit_count, fruit_report, fruit_cloud,
                        fruit_centers, fruit_markers, /diagnostics), readable by rosbags, mcap and Foxglove

Run as ``fruitnerfpp replay BAG --out RUN_DIR`` or ``ros2 run fruitnerfpp_ros bag_replay BAG --out RUN_DIR`` (both
enter through :mod:`fruitnerfpp_ros.cli.replay`; this module never imports the command line).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import threading
import time
from pathlib import Path
from typing import Any, NamedTuple

from fruitnerfpp_ros.core.atomic_io import atomic_write_text, trim_torn_line
from fruitnerfpp_ros.core.bags import BagSource, BagTopic, FileRecovery, open_bag
from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.core.progress import ProgressCallback
from fruitnerfpp_ros.errors import BagError, ConfigError
from fruitnerfpp_ros.nodes.frame_assembler import FrameAssembler
from fruitnerfpp_ros.nodes.log import LogFunction, LogLevel
from fruitnerfpp_ros.nodes.params import CounterSettings, keyframe_config, pipeline_configs
from fruitnerfpp_ros.nodes.results import (DIAGNOSTICS_TOPIC, OUTPUT_TOPICS, RESULTS_NODE_NAME, diagnostics_msg,
                                           result_messages, write_report)
from fruitnerfpp_ros.nodes.status import AssemblerStatus, DiagnosticLevel, NodeState

__all__ = ['ROLE_TYPES', 'ReplayResult', 'collect_keyframes', 'replay_bag', 'write_results_mcap']

#: Accepted message types per role (rosbags spelling).
ROLE_TYPES = {
    'image': ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage'),
    'mask': ('sensor_msgs/msg/Image',),
    'camera_info': ('sensor_msgs/msg/CameraInfo',),
    'pose': ('geometry_msgs/msg/PoseStamped', 'geometry_msgs/msg/PoseWithCovarianceStamped'),
    'odometry': ('nav_msgs/msg/Odometry',),
    'tf': ('tf2_msgs/msg/TFMessage',),
    'tf_static': ('tf2_msgs/msg/TFMessage',),
    'depth': ('sensor_msgs/msg/Image',),
}
RESULTS_NAME = 'results.mcap'
REPORT_NAME = 'fruit_report.json'
#: Written when the collection from the bag is complete: a resumed replay does not read the bag again.
COLLECTION_NAME = 'collection.json'


class ReplayResult(NamedTuple):
    """What a replay produced.

    Attributes:
        run_dir: the run directory.
        keyframes_dir: the collected transforms.json dataset.
        n_keyframes: keyframes collected.
        count: the CountResult (None when training was skipped).
        report_path: fruit_report.json (None when training was skipped).
        results_mcap: results.mcap (None when training was skipped).
        pipeline: the core's PipelineResult (None when training was skipped).
        status: the collection counters (messages per role, errors, sync).
        recoveries: the damaged storage files read up to their last whole message (empty for a sound bag).
    """

    run_dir: Path
    keyframes_dir: Path
    n_keyframes: int
    count: Any
    report_path: Path | None
    results_mcap: Path | None
    pipeline: Any
    status: AssemblerStatus
    recoveries: tuple[FileRecovery, ...] = ()


def _print_log(level: LogLevel, message: str) -> None:
    print(f'[{level}] {message}', file=sys.stdout if level is LogLevel.INFO else sys.stderr, flush=True)


def _topics_table(topics: list[BagTopic]) -> str:
    return ', '.join(f'{t.topic} [{t.msgtype}]' for t in topics) or 'none'


def _roles_in_bag(source: BagSource, assembler: FrameAssembler, settings: CounterSettings,
                  log: LogFunction) -> dict[str, str]:
    """Topic -> role for every role the settings use; checks that the bag has the required ones."""
    bag_path = source.path
    by_topic = {t.topic: t for t in source.topics}
    roles: dict[str, str] = {}
    used = list(assembler.required_roles())
    if settings.pose_source in ('tf', 'odometry'):
        used += [r for r in ('tf', 'tf_static') if r not in used]
    used += assembler.optional_roles()
    for role in used:
        topic = assembler.topic_of(role)
        compressed = f'{topic}/compressed'  # image_transport's name for the JPEG / PNG stream of an image topic
        if role == 'image' and topic not in by_topic and compressed in by_topic:
            log(LogLevel.INFO, f'{bag_path}: no topic {topic} in the bag; reading its compressed stream {compressed}')
            topic = compressed
        if topic not in by_topic:
            if role in assembler.required_roles():
                raise BagError(f'{bag_path}: no topic {topic} ({role}) in the bag; topics in the bag: '
                               f'{_topics_table(source.topics)}. Set the *_topic parameters (--params) to match.')
            if role in assembler.optional_roles():
                log(LogLevel.WARN, f'{bag_path}: no topic {topic} ({role}) in the bag; keyframes without {role}')
            continue
        msgtype = by_topic[topic].msgtype
        if msgtype not in ROLE_TYPES[role]:
            raise BagError(f'{bag_path}: topic {topic} has type {msgtype}, expected '
                           f'{" or ".join(ROLE_TYPES[role])} for {role}')
        roles[topic] = role
    unused = sorted(set(by_topic) - set(roles))
    if unused:
        log(LogLevel.INFO, f'{bag_path}: ignoring topics {", ".join(unused)}')
    return roles


def read_bag_into(assembler: FrameAssembler, bag_path: str | Path, settings: CounterSettings, *,
                  log: LogFunction = _print_log, stop_event: threading.Event | None = None) -> list[FileRecovery]:
    """Feed every relevant message of the bag to ``assembler`` (then flush it).

    A damaged bag (an MCAP without footer, a sqlite3 file with missing pages, a missing or stale metadata.yaml) is
    read up to its last whole message (:func:`~fruitnerfpp_ros.core.bags.open_bag`), with a warning saying how
    much was recovered.

    Returns:
        one record per damaged storage file that was recovered (empty for a sound bag).

    Raises:
        BagError: the bag is missing, holds nothing readable, or lacks a required topic (the message lists the
            topics it has).
    """
    from rosbags.typesys import Stores, get_typestore

    source = open_bag(bag_path)
    try:
        for note in source.notes:
            log(LogLevel.WARN, note)
        for recovery in source.recoveries:
            log(LogLevel.WARN, recovery.describe())
        source.on_recovery = lambda recovery: log(LogLevel.WARN, recovery.describe())
        roles = _roles_in_bag(source, assembler, settings, log)
        typestore = get_typestore(Stores.ROS2_JAZZY)
        store = assembler.store
        try:
            for message in source.messages(set(roles)):
                if stop_event is not None and stop_event.is_set():
                    break
                role = roles[message.topic]
                try:
                    msg = typestore.deserialize_cdr(message.data, message.msgtype)
                except Exception as err:  # noqa: BLE001 - a damaged message is skipped, the next may be fine
                    assembler.received[role] += 1
                    assembler.errors[role] += 1
                    log(LogLevel.WARN, f'{message.topic}: undecodable message skipped ({type(err).__name__}: {err})')
                    continue
                assembler.on_message(role, msg)
        except BagError as err:
            raise BagError(f'{err}; {len(store)} keyframe(s) collected before the damage stay in '
                           f'{store.directory}') from err
        assembler.flush()
        store.flush()
    finally:
        source.close()
    return list(source.recoveries)


def collect_keyframes(bag_path: str | Path, keyframes_dir: str | Path, settings: CounterSettings, *,
                      log: LogFunction = _print_log, stop_event: threading.Event | None = None,
                      resume: bool = False) -> FrameAssembler:
    """Read every relevant message of the bag through a :class:`FrameAssembler` into ``keyframes_dir``.

    Args:
        resume: keep the keyframes already in ``keyframes_dir`` and add only those newer than its newest (a
            replay that was killed while collecting continues where it stopped, with the same keyframes).

    Returns:
        the assembler (its ``store`` holds the keyframes, ``status()`` the counters).

    Raises:
        BagError: see :func:`read_bag_into`.
    """
    if not Path(bag_path).exists():
        raise BagError(f'{bag_path}: no such bag (a rosbag2 directory or an .mcap / .db3 file)')
    store = KeyframeStore(keyframes_dir, keyframe_config(settings), resume_after_newest=resume,
                          mask_source=settings.mask_source)
    assembler = FrameAssembler(settings, store, log)
    read_bag_into(assembler, bag_path, settings, log=log, stop_event=stop_event)
    return assembler


def write_results_mcap(path: str | Path, messages: list[tuple[str, str, Any]], stamp_ns: int) -> Path:
    """Write rclpy messages as a single MCAP file (rosbag2 flavour: CDR + ros2msg schemas; result topics are
    offered transient-local, as the node publishes them).

    Args:
        path: the .mcap file to create (replaced atomically if it exists).
        messages: (topic, rosbags type name, rclpy message) in write order.
        stamp_ns: log time of every message.
    """
    from rclpy.serialization import serialize_message
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    forever = QosTime(2147483647, 4294967295)
    latched = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, forever, forever,
                  QosLiveliness.AUTOMATIC, forever, False)

    path = Path(path)
    tmp_dir = path.with_name(f'.{path.name}.tmp{time.time_ns()}')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    try:
        with Writer(tmp_dir, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            connections: dict[str, Any] = {}
            for topic, msgtype, msg in messages:
                if topic not in connections:
                    qos = [] if topic == DIAGNOSTICS_TOPIC else [latched]  # `ros2 bag play` re-latches results
                    connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore,
                                                               offered_qos_profiles=qos)
                writer.write(connections[topic], int(stamp_ns), serialize_message(msg))
        written = next(tmp_dir.glob('*.mcap'))
        written.replace(path)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    return path


def _finished_collection(run_dir: Path, bag_path: Path) -> dict[str, Any] | None:
    """The collection record of a replay that finished collecting from ``bag_path`` (None: not finished).

    Raises:
        ConfigError: the run directory was collected from another bag.
    """
    path = run_dir / COLLECTION_NAME
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
        bag = record['bag']
    except (ValueError, KeyError, TypeError):
        return None
    if Path(bag).resolve() != bag_path.resolve():
        raise ConfigError(f'{run_dir} holds the keyframes of {bag}, not {bag_path}; choose a new --out')
    return record


_Collected = tuple[KeyframeStore, AssemblerStatus, tuple[FileRecovery, ...]]


def _collect(bag_path: Path, run_dir: Path, settings: CounterSettings, log: LogFunction,
             stop_event: threading.Event | None, resume: bool) -> _Collected:
    """Collect the keyframes (or, resuming, keep those of a finished or interrupted collection)."""
    keyframes_dir = run_dir / 'keyframes'
    finished = _finished_collection(run_dir, bag_path) if resume else None
    if finished is not None:
        store = KeyframeStore(keyframes_dir, keyframe_config(settings))
        log(LogLevel.INFO, f'{keyframes_dir}: the collection from {bag_path} is complete ({len(store)} '
            'keyframes); the bag is not read again')
        return store, AssemblerStatus(**{**finished['status'], 'keyframes': len(store)}), tuple(
            FileRecovery(*r) for r in finished.get('recoveries', []))
    if keyframes_dir.exists() and not resume:  # a replay collects afresh; earlier keyframes are kept aside
        previous = keyframes_dir.with_name(f'keyframes_previous_{time.time_ns()}')
        keyframes_dir.rename(previous)
        log(LogLevel.INFO, f'{keyframes_dir} existed: moved to {previous}')
    (run_dir / COLLECTION_NAME).unlink(missing_ok=True)
    store = KeyframeStore(keyframes_dir, keyframe_config(settings), resume_after_newest=resume,
                          mask_source=settings.mask_source)
    if resume and len(store):
        log(LogLevel.INFO, f'{keyframes_dir}: resuming the collection after its {len(store)} keyframe(s)')
    assembler = FrameAssembler(settings, store, log)
    recoveries = tuple(read_bag_into(assembler, bag_path, settings, log=log, stop_event=stop_event))
    status = assembler.status()
    if stop_event is None or not stop_event.is_set():
        atomic_write_text(run_dir / COLLECTION_NAME, json.dumps(
            {'bag': str(bag_path), 'keyframes': len(store), 'status': dataclasses.asdict(status),
             'recoveries': [list(r) for r in recoveries]}, indent=1))
    return store, status, recoveries


def replay_bag(bag_path: str | Path, run_dir: str | Path, settings: CounterSettings = CounterSettings(), *,
               train: bool = True, progress: ProgressCallback | None = None, log: LogFunction = _print_log,
               stop_event: threading.Event | None = None, show_progress: bool = False,
               skip_training: bool = False, resume: bool = False) -> ReplayResult:
    """Collect keyframes from a bag, then train, count and write the outputs into ``run_dir``.

    Args:
        bag_path: rosbag2 directory (sqlite3 or MCAP) or a single .mcap / .db3 file.
        run_dir: output directory (created).
        settings: topics, pose source, keyframe selection, preset, device (see ``config/fruit_counter.yaml``).
        train: False stops after collecting keyframes.
        skip_training: reuse the model already trained in ``run_dir`` (re-export and recount only).
        resume: continue a replay into ``run_dir`` that was killed or stopped: the keyframes collected are kept
            (a finished collection is not read again, an interrupted one continues after its newest keyframe) and
            training continues from its last checkpoint; the count equals an uninterrupted replay's.

    Raises:
        BagError: unreadable bag, missing topics, or no keyframe collected.
        ConfigError: ``run_dir`` already holds a training run (and neither ``resume`` nor ``skip_training``), or
            resuming a run directory collected from another bag.
        FruitNerfError: training / export / clustering failures (from the core).
    """
    run_dir, bag_path = Path(run_dir), Path(bag_path)
    if train and not skip_training and not resume and (run_dir / 'checkpoints').exists():
        raise ConfigError(f'{run_dir} already holds a training run; continue it with --resume, choose a new --out, '
                          'or pass --skip-training to re-export and recount it')
    if not bag_path.exists():
        raise BagError(f'{bag_path}: no such bag (a rosbag2 directory or an .mcap / .db3 file)')
    run_dir.mkdir(parents=True, exist_ok=True)
    keyframes_dir = run_dir / 'keyframes'
    store, status, recoveries = _collect(bag_path, run_dir, settings, log, stop_event, resume)
    n_keyframes = len(store)
    log(LogLevel.INFO, f'{bag_path}: {n_keyframes} keyframe(s) from {status.received.get("image", 0)} image(s) '
        f'in {keyframes_dir}')
    if n_keyframes == 0:
        raise BagError(f'{bag_path}: no keyframe could be made; received {dict(status.received)}, errors '
                       f'{dict(status.errors)}, unmatched stamps {dict(status.sync_unmatched)}')
    if not train:
        return ReplayResult(run_dir, keyframes_dir, n_keyframes, None, None, None, None, status, recoveries)
    if n_keyframes < settings.min_keyframes:
        raise BagError(f'{bag_path}: only {n_keyframes} keyframe(s), fewer than min_keyframes='
                       f'{settings.min_keyframes}')
    from fruitnerfpp_ros.core.clustering.workers import partition_pool
    from fruitnerfpp_ros.core.pipeline import run_pipeline
    from fruitnerfpp_ros.core.device import use_cpu_threads
    if resume:  # a kill or a full disk may have cut the last metrics line, which resuming reads again
        trim_torn_line(run_dir / 'metrics.jsonl')
    configs = pipeline_configs(settings)
    for note in configs.notes:
        log(LogLevel.INFO, note)
    use_cpu_threads(configs.train.cpu_threads, settings.device)  # the replay owns its process
    with partition_pool(configs.cluster.n_jobs) as pool:  # the replay owns the clustering workers
        result = run_pipeline(keyframes_dir, run_dir, train_config=configs.train,
                              export_config=configs.export, cluster_config=configs.cluster,
                              device=settings.device, progress=progress, stop_event=stop_event,
                              show_progress=show_progress, skip_training=skip_training, executor=pool,
                              resume=resume and not skip_training)
    if result.stopped:
        raise BagError(f'{bag_path}: replay stopped before the count; the keyframes stay in {keyframes_dir}; '
                       'continue with --resume')
    stamp_ns = max(f.stamp_ns or 0 for f in store.frames)
    run_id = f'{run_dir.resolve().name}'
    extra = {'keyframes': n_keyframes, 'source': str(bag_path), 'preset': configs.preset}
    messages = result_messages(result.count, result.cloud, settings.world_frame, stamp_ns, run_id, extra)
    report_path = write_report(run_dir / REPORT_NAME, messages['fruit_report'].data)
    diagnostics = diagnostics_msg(f'{RESULTS_NODE_NAME}: pipeline', RESULTS_NODE_NAME, DiagnosticLevel.OK,
                                  f'{NodeState.DONE}: {result.count.count} fruits',
                                  {'state': NodeState.DONE, 'keyframes': n_keyframes, 'fruits': result.count.count},
                                  stamp_ns)
    topics = [(f'/{RESULTS_NODE_NAME}/{t.name}', t.msg_type, messages[t.name]) for t in OUTPUT_TOPICS]
    topics.append((DIAGNOSTICS_TOPIC, 'diagnostic_msgs/msg/DiagnosticArray', diagnostics))
    results_mcap = write_results_mcap(run_dir / RESULTS_NAME, topics, stamp_ns)
    return ReplayResult(run_dir, keyframes_dir, n_keyframes, result.count, report_path, results_mcap, result, status,
                        recoveries)
