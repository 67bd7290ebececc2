"""Turns image / mask / pose / camera_info / TF messages into keyframes: the one path of live node and bag replay.

The live node's worker and the bag reader both call :meth:`FrameAssembler.on_message` with a role
(``image``, ``mask``, ``pose``, ``odometry``, ``camera_info``, ``tf``, ``tf_static``, ``depth``) and a message (rclpy
or rosbags-decoded). Image, mask and pose are matched by stamp (:class:`ApproximateTimeSynchronizer`); a matched
frame waits (up to ``pending_timeout_s`` of stamp time) for camera_info and TF, is converted and undistorted,
and offered to the :class:`KeyframeStore`, which writes it to disk when kept. With a ``depth_topic``, the depth
image of the same stamp (within ``sync_slop_s``, as the mask) joins the frame (:class:`DepthMatcher`): checked
against the image's size and frame, undistorted like the masks; a frame whose depth does not come (a silent topic,
a lost image) or is refused is kept without depth.

Bad input never raises out of :meth:`on_message`: it is logged (throttled per kind) and counted in
:attr:`FrameAssembler.errors`; frames already collected stay on disk. A keyframe the store cannot write (a full
disk) is an error log and ``errors['write']``; the node keeps collecting. Stamps that jump back in time by more
than ``pending_timeout_s`` (a bag played again, a clock reset) clear the sync queues and the waiting frames
(``time_jumps``; the TF buffer starts each edge over by itself), so collection continues on the new time line.
"""

from __future__ import annotations

import re
from collections import Counter
from typing import Any, Callable

import numpy as np

from fruitnerfpp_ros.core.data.keyframe_store import Keyframe, KeyframeDecision, KeyframeStore
from fruitnerfpp_ros.core.geometry import transform_from_quaternion
from fruitnerfpp_ros.core.streams.tf_buffer import TfBuffer, TfFutureError, TfLookupError
from fruitnerfpp_ros.core.streams.time_sync import ApproximateTimeSynchronizer, SyncedSet
from fruitnerfpp_ros.errors import ConversionError, DatasetError, FruitNerfError
from fruitnerfpp_ros.nodes.conversions import (CameraModel, add_tf_message, camera_model_from_camera_info,
                                               depth_from_msg, image_from_msg, stamp_ns_from_header,
                                               transform_from_pose_msg, undistort_depth, undistort_image,
                                               undistort_mask, valid_pixels)
from fruitnerfpp_ros.nodes.depth_matcher import DepthMatcher, DepthWait
from fruitnerfpp_ros.nodes.log import LogFunction, LogLevel, ThrottledLog
from fruitnerfpp_ros.nodes.mask_source import MaskSource, mask_source_from_settings
from fruitnerfpp_ros.nodes.params import CounterSettings
from fruitnerfpp_ros.nodes.status import AssemblerStatus

__all__ = ['FrameAssembler']


class FrameAssembler:
    """Synchronises inputs, builds :class:`Keyframe` records and offers them to ``store``.

    Args:
        settings: topics, pose source, frames, sync tolerance.
        store: where keyframes go.
        log: ``log(level, message)``; the assembler throttles repeated warnings itself.
        mask_source: instance masks (default: from the ``mask_source`` parameter: the ``mask_topic`` or a
            segmenter built now).
    """

    def __init__(self, settings: CounterSettings, store: KeyframeStore, log: LogFunction,
                 mask_source: MaskSource | None = None) -> None:
        self.settings = settings
        self.store = store
        self.mask_source = mask_source or mask_source_from_settings(settings)
        self._log = log
        self._throttled = ThrottledLog(log)
        self.tf = TfBuffer()
        names = ['image']
        if self.mask_source.topic is not None:
            names.append('mask')
        if settings.pose_source in ('pose', 'odometry'):
            names.append(settings.pose_source)
        self._sync_index = {name: i for i, name in enumerate(names)}
        self.sync: ApproximateTimeSynchronizer[Any] = ApproximateTimeSynchronizer(
            names, int(settings.sync_slop_s * 1e9), settings.queue_size)
        extrinsic = settings.extrinsic_values()
        self._T_base_camera = None if extrinsic is None else transform_from_quaternion(extrinsic[:3], extrinsic[3:])
        self.depth = DepthMatcher(int(settings.sync_slop_s * 1e9), int(settings.pending_timeout_s * 1e9),
                                  settings.queue_size) if settings.depth_topic else None
        self.camera: CameraModel | None = None
        self._pending: list[SyncedSet] = []
        self._newest_stamp_ns = 0
        self.received: Counter[str] = Counter()
        self.errors: Counter[str] = Counter()
        self.decisions: Counter[str] = Counter()
        self.dropped_pending = 0
        self.time_jumps = 0
        self._write_errors_logged = 0
        self._other_frames: set[str] = set()

    # ------------------------------------------------------------------ input
    def topic_of(self, role: str) -> str:
        """The topic a role is read from (for messages)."""
        s = self.settings
        return {'image': s.image_topic, 'mask': s.mask_topic, 'pose': s.pose_topic, 'odometry': s.odometry_topic,
                'camera_info': s.camera_info_topic, 'tf': '/tf', 'tf_static': '/tf_static',
                'depth': s.depth_topic}[role]

    def required_roles(self) -> list[str]:
        """Roles without which no keyframe can be made (for checking a bag's topics)."""
        roles = ['image', 'camera_info'] + (['mask'] if self.mask_source.topic is not None else [])
        if self.settings.pose_source in ('pose', 'odometry'):
            roles.append(self.settings.pose_source)
        if self.settings.pose_source == 'tf':
            roles.append('tf')
        return roles

    def optional_roles(self) -> list[str]:
        """Roles used when present: without them keyframes are still made (``depth`` with a ``depth_topic``)."""
        return ['depth'] if self.depth is not None else []

    def on_message(self, role: str, msg: Any) -> list[KeyframeDecision]:
        """Feed one message; returns what the store decided for every frame this message completed."""
        self.received[role] += 1
        try:
            return self._dispatch(role, msg)
        except FruitNerfError as err:
            self.errors[role] += 1
            self._throttled(LogLevel.WARN, _kind(f'bad:{role}:{err}'), f'{self.topic_of(role)}: {err}; message dropped')
        except Exception as err:  # noqa: BLE001 - a malformed message must never stop the node
            self.errors[role] += 1
            self._throttled(LogLevel.WARN, f'bad:{role}', f'{self.topic_of(role)}: cannot read message '
                            f'({type(err).__name__}: {err}); message dropped')
        return []

    def _dispatch(self, role: str, msg: Any) -> list[KeyframeDecision]:
        if role in ('tf', 'tf_static'):
            add_tf_message(self.tf, msg, static=role == 'tf_static')
            return self._drain()
        if role == 'camera_info':
            camera = camera_model_from_camera_info(msg, topic=self.settings.camera_info_topic)
            if self.camera is None:
                self._log(LogLevel.INFO, f'{self.settings.camera_info_topic}: {camera.intrinsics.w}x'
                          f'{camera.intrinsics.h} camera, distortion {camera.distortion_model or "none"}')
            self.camera = camera
            return self._drain()
        if role not in self._sync_index and not (role == 'depth' and self.depth is not None):
            return []
        stamp_ns = stamp_ns_from_header(msg.header)
        if role in ('pose', 'odometry'):
            transform_from_pose_msg(msg.pose, topic=self.topic_of(role))  # reject NaN poses before matching
        if self._newest_stamp_ns - stamp_ns > self.settings.pending_timeout_s * 1e9:
            self._time_jump(role, stamp_ns)
        self._newest_stamp_ns = max(self._newest_stamp_ns, stamp_ns)
        if self.depth is not None:
            self.depth.saw_stamp(stamp_ns)
            if role == 'depth':
                self.depth.add(stamp_ns, msg)
                return self._drain()
        before = sum(self.sync.unmatched.values())
        self._pending.extend(self.sync.add(self._sync_index[role], stamp_ns, msg))
        if sum(self.sync.unmatched.values()) > before:
            self._throttled(LogLevel.WARN, 'unsynced', f'{", ".join(self.topic_of(r) for r in self._sync_index)}: '
                            f'stamps do not match within sync_slop_s={self.settings.sync_slop_s} s; '
                            f'unmatched so far {dict(self.sync.unmatched)}')
        return self._drain()

    def _time_jump(self, role: str, stamp_ns: int) -> None:
        """Stamps went back in time: start a new time line (sync queues and waiting frames cleared; the TF buffer
        restarts an edge's history when a transform older than its cache arrives)."""
        back_s = (self._newest_stamp_ns - stamp_ns) / 1e9
        self.time_jumps += 1
        self._throttled(LogLevel.WARN, 'time_jump', f'{self.topic_of(role)}: stamp jumped back {back_s:.1f} s (a bag '
                        'played again or a clock reset): sync queues and waiting frames cleared')
        self.sync.reset()
        if self.depth is not None:
            self.depth.reset()
        self.dropped_pending += len(self._pending)
        self._pending = []
        self._newest_stamp_ns = stamp_ns

    # ------------------------------------------------------------------ frames
    def _drain(self, *, final: bool = False) -> list[KeyframeDecision]:
        decisions, waiting = [], []
        for synced in self._pending:
            try:
                decisions.append(self._complete(synced, final=final))
            except (TfFutureError, _NoCameraInfo, DepthWait) as err:
                too_old = self._newest_stamp_ns - synced.stamp_ns > self.settings.pending_timeout_s * 1e9
                if final or too_old:
                    self.dropped_pending += 1
                    self.errors['waiting'] += 1
                    self._throttled(LogLevel.WARN, f'drop:{type(err).__name__}',
                                    f'frame at {synced.stamp_ns} ns dropped: {err}')
                else:
                    waiting.append(synced)
            except DatasetError as err:  # the store could not write the keyframe (a full disk): nothing half-stored
                self.errors['write'] += 1
                self._write_errors_logged = self.store.write_errors
                self._throttled(LogLevel.ERROR, 'write', f'frame at {synced.stamp_ns} ns dropped: {err}')
            except FruitNerfError as err:
                self.errors['frame'] += 1
                self._throttled(LogLevel.WARN, _kind(f'frame:{err}'), f'frame at {synced.stamp_ns} ns dropped: {err}')
            except Exception as err:  # noqa: BLE001 - one unreadable frame must not hold up the frames behind it
                self.errors['frame'] += 1
                self._throttled(LogLevel.WARN, f'frame:{type(err).__name__}', f'frame at {synced.stamp_ns} ns '
                                f'dropped: {type(err).__name__}: {err}')
        self._pending = waiting
        for decision in decisions:
            self.decisions[decision.value] += 1
        return decisions

    def flush(self) -> list[KeyframeDecision]:
        """Process what can be processed and drop every frame still waiting (end of a bag)."""
        return self._drain(final=True)

    def reset(self) -> None:
        """Forget queued and waiting frames (the TF buffer and camera model are kept)."""
        self.sync.reset()
        self._pending = []

    def _complete(self, synced: SyncedSet, *, final: bool = False) -> KeyframeDecision:
        items = dict(zip(self._sync_index, synced.items))
        image_msg = items['image']
        if self.camera is None:
            raise _NoCameraInfo(f'no CameraInfo received on {self.settings.camera_info_topic} yet')
        T_world_optical = self._pose_for(synced.stamp_ns, items)
        rgb = image_from_msg(image_msg, topic=self.settings.image_topic)
        camera = self.camera
        if rgb.shape[:2] != (camera.intrinsics.h, camera.intrinsics.w):
            raise ConversionError(f'{self.settings.image_topic}: image is {rgb.shape[1]}x{rgb.shape[0]} but '
                                  f'{self.settings.camera_info_topic} says {camera.intrinsics.w}x{camera.intrinsics.h}')
        depth = self._depth_for(synced.stamp_ns, image_msg, camera, final=final)  # may wait: before the work
        undistorted = undistort_image(rgb, camera)
        instances: np.ndarray | Callable[[], np.ndarray]
        if self.mask_source.topic is None:  # a segmenter: run on the undistorted image, only if the store keeps it
            source = self.mask_source
            instances = lambda: source.instances_for(undistorted, None)  # noqa: E731
        else:
            instances = undistort_mask(self.mask_source.instances_for(rgb, items.get('mask')), camera)
        keyframe = Keyframe(synced.stamp_ns, undistorted, instances, T_world_optical, camera.intrinsics,
                            valid_pixels(camera), depth)
        decision = self.store.offer(keyframe)
        if self.store.write_errors > self._write_errors_logged and self.store.last_write_error:
            self._write_errors_logged = self.store.write_errors  # a deferred transforms.json rewrite failed
            self._throttled(LogLevel.ERROR, 'write', self.store.last_write_error)
        if decision is KeyframeDecision.ACCEPTED:
            n = len(self.store)
            if n == 1 or n % 10 == 0:
                self._log(LogLevel.INFO, f'{n} keyframe(s) collected in {self.store.directory}')
        elif decision is KeyframeDecision.DUPLICATE_STAMP:
            self._throttled(LogLevel.WARN, 'duplicate', f'frame at {synced.stamp_ns} ns skipped: a keyframe with this '
                            'stamp is already stored (a repeated message)')
        elif decision is KeyframeDecision.FULL:
            self._throttled(LogLevel.WARN, 'full', f'max_keyframes={self.store.config.max_keyframes} reached; '
                            'further frames are ignored (call ~/train or ~/reset)')
        return decision

    def _depth_for(self, stamp_ns: int, image_msg: Any, camera: CameraModel, *, final: bool) -> np.ndarray | None:
        """The frame's undistorted depth (metres, 0 = no return), or None: no depth topic, no depth image for this
        stamp (the topic is silent, the image was lost), or a depth image refused (another size or frame: logged,
        ``errors['depth']``).

        Raises:
            DepthWait: the depth image may still arrive (the frame waits).
        """
        if self.depth is None:
            return None
        msg = self.depth.take(stamp_ns, self._newest_stamp_ns, final=final)
        s = self.settings
        if msg is None:
            silent_s = self.depth.silent_ns(self._newest_stamp_ns) / 1e9
            if silent_s > s.pending_timeout_s:
                self._throttled(LogLevel.WARN, 'depth:silent', f'{s.depth_topic}: no depth image for {silent_s:.1f} s; '
                                'keyframes are kept without depth')
            return None
        try:
            frames = (str(msg.header.frame_id), str(image_msg.header.frame_id))
            if all(frames) and frames[0] != frames[1]:
                raise ConversionError(f'{s.depth_topic}: depth is in frame {frames[0]!r}, the image in {frames[1]!r}; '
                                      'publish depth aligned to the colour camera (e.g. realsense2_camera '
                                      'align_depth.enable:=true)')
            shape = (camera.intrinsics.h, camera.intrinsics.w)
            return undistort_depth(depth_from_msg(msg, topic=s.depth_topic, expected_shape=shape), camera)
        except ConversionError as err:
            self.errors['depth'] += 1
            self._throttled(LogLevel.WARN, _kind(f'depth:{err}'), f'{err}; frame at {stamp_ns} ns kept without depth')
            return None

    def _check_world_frame(self, msg: Any) -> None:
        """Warn once per frame when a pose message is given in another frame than ``world_frame`` (the poses are
        used as they are; every output is stamped ``world_frame``, so a viewer would draw it in the wrong place)."""
        frame, s = str(msg.header.frame_id), self.settings
        if frame and frame != s.world_frame and frame not in self._other_frames:
            self._other_frames.add(frame)
            topic = s.pose_topic if s.pose_source == 'pose' else s.odometry_topic
            self._log(LogLevel.WARN, f'{topic}: poses in frame {frame!r}, world_frame is {s.world_frame!r}; the '
                      f'outputs are stamped {s.world_frame!r}: set world_frame:={frame} if that is the fixed frame')

    def _camera_frame(self, image_msg: Any) -> str:
        return self.settings.camera_frame or str(image_msg.header.frame_id)

    def _pose_for(self, stamp_ns: int, items: dict[str, Any]) -> np.ndarray:
        s = self.settings
        if s.pose_source in ('pose', 'odometry'):
            self._check_world_frame(items[s.pose_source])
        if s.pose_source == 'pose':
            return transform_from_pose_msg(items['pose'].pose, topic=s.pose_topic)
        if s.pose_source == 'odometry':
            T_world_base = transform_from_pose_msg(items['odometry'].pose, topic=s.odometry_topic)
            T_base_camera = self._T_base_camera
            if T_base_camera is None:
                try:
                    T_base_camera = self.tf.lookup(s.base_frame, self._camera_frame(items['image']), stamp_ns)
                except TfLookupError as err:
                    raise TfFutureError(f'camera extrinsic: {err} (set camera_extrinsic or publish /tf_static)') \
                        from err
            return T_world_base @ T_base_camera
        try:
            return self.tf.lookup(s.world_frame, self._camera_frame(items['image']), stamp_ns)
        except TfFutureError:
            raise
        except TfLookupError as err:
            raise TfFutureError(str(err)) from err

    # ------------------------------------------------------------------ status
    def status(self) -> AssemblerStatus:
        """Counters for diagnostics and reports (a copy: later messages do not change it)."""
        return AssemblerStatus(len(self.store), dict(self.received), dict(self.errors), dict(self.decisions),
                               {k.value: v for k, v in self.store.rejected.items()}, self.sync.matched,
                               dict(self.sync.unmatched), len(self._pending), self.dropped_pending,
                               self.store.write_errors, self.time_jumps)


def _kind(message: str) -> str:
    """Throttling key of a message: the same text up to its numbers is the same kind."""
    return re.sub(r'[-+.0-9eE]*[0-9]+', '#', message)[:200]


class _NoCameraInfo(ConversionError):
    """No CameraInfo has arrived yet (the frame waits)."""
