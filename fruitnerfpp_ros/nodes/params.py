"""Parameters of the fruit_counter node and of bag replay: declared, typed and documented in ONE place.

:class:`CounterSettings` is the single source: each field's default, type and ``description`` metadata become
the ROS parameter declarations (:func:`declare_parameters`), the rows of the docs table and the keys of
``config/fruit_counter.yaml``. :func:`pipeline_configs` and :func:`keyframe_config` are the one mapping from
these settings onto the core's config dataclasses.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Mapping, NamedTuple


from fruitnerfpp_ros.core.config_io import (config_from_mapping, config_to_mapping, load_pipeline_sections,
                                            load_yaml_mapping, replace_nested)
from fruitnerfpp_ros.core.data.keyframe_store import KeyframeConfig
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['CounterSettings', 'ParamSpec', 'PARAMETERS', 'settings_from_parameters', 'load_parameter_file',
           'keyframe_config', 'PipelineConfigs', 'pipeline_configs', 'use_node_cpu_threads', 'declare_parameters',
           'parameter_table']


def _p(default: Any, description: str) -> Any:
    return field(default=default, metadata={'description': description})


@dataclass(frozen=True)
class CounterSettings:
    """Every parameter of fruit_counter / bag replay (see each field's ``description``)."""

    image_topic: str = _p('/camera/image_raw', 'Camera images: sensor_msgs/Image (rgb8, bgr8, rgba8, bgra8, mono8), '
                          'or sensor_msgs/CompressedImage when compressed_image is true.')
    compressed_image: bool = _p(False, 'Subscribe to image_topic as sensor_msgs/CompressedImage (jpeg/png). The bag '
                                'replay reads image_topic/compressed by itself when only that is recorded.')
    camera_info_topic: str = _p('/camera/camera_info', 'sensor_msgs/CameraInfo of the camera; plumb_bob, '
                                'rational_polynomial and equidistant distortion is undone.')
    mask_topic: str = _p('/camera/instance_mask', 'Instance masks, sensor_msgs/Image mono16/16UC1/32SC1 '
                         '(0 = background, k = fruit k), same size and stamp as the image.')
    depth_topic: str = _p('', 'Optional depth images aligned to the colour image (an RGB-D camera, e.g. '
                          "realsense2_camera's /camera/aligned_depth_to_color/image_raw): sensor_msgs/Image 16UC1 "
                          'millimetres or 32FC1 metres, 0 / NaN = no return, same size, frame and stamp as the image; '
                          "training then adds a depth loss. '' = no depth. A frame never waits for a silent depth "
                          'topic: it is kept without depth (and /diagnostics warns).')
    mask_source: Literal['topic', 'semantic_topic', 'fallback', 'torchscript', 'sam'] = _p(
        'topic', "Where instance masks come from: 'topic' = mask_topic; 'semantic_topic' = mask_topic carries binary "
        'fruit masks (non-zero = fruit, e.g. mono8 0 / 255 from a semantic segmenter), split into instances by '
        "connected blobs; 'fallback' = the built-in fruit-agnostic colour segmenter run on each image; "
        "'torchscript' / 'sam' = a TorchScript instance-segmentation model / Segment Anything loaded from "
        'segmenter_checkpoint. With a segmenter, mask_topic is not subscribed.')
    segmenter_checkpoint: str = _p('', "Local model file for mask_source 'torchscript' (a torch.jit.save file) or "
                                   "'sam' (a Segment Anything .pth); nothing is downloaded.")
    segmenter_config_file: str = _p('', "Optional SegmenterConfig YAML (config/segmentation.yaml): the segmenter's "
                                    'thresholds; mask_source, segmenter_checkpoint (when set) and device override '
                                    'its method, checkpoint and device.')
    pose_source: Literal['pose', 'odometry', 'tf'] = _p(
        'pose', "Camera pose: 'pose' = geometry_msgs/PoseStamped of the optical frame in world_frame on pose_topic; "
        "'odometry' = nav_msgs/Odometry of base_frame on odometry_topic plus camera_extrinsic; 'tf' = /tf + "
        '/tf_static chain world_frame -> camera_frame, interpolated to the image stamp.')
    pose_topic: str = _p('/camera/pose', 'geometry_msgs/PoseStamped topic (pose_source pose).')
    odometry_topic: str = _p('/odom', 'nav_msgs/Odometry topic (pose_source odometry).')
    world_frame: str = _p('map', 'Fixed frame of the poses and of every output (poses stamped in another '
                                 'frame are used as given, with one warning per frame).')
    camera_frame: str = _p('', "Camera optical frame (REP-103: z forward, x right, y down); '' = the image's "
                           'header frame_id.')
    base_frame: str = _p('base_link', 'Robot body frame that the odometry pose describes (pose_source odometry).')
    camera_extrinsic: str = _p('', "T_base_camera as 'x y z qx qy qz qw' (metres, quaternion) for pose_source "
                               "odometry; '' = look base_frame -> camera_frame up in /tf_static.")
    input_reliability: Literal['best_effort', 'reliable'] = _p(
        'best_effort', 'QoS reliability of the sensor subscriptions (best_effort = sensor-data QoS).')
    sync_slop_s: float = _p(0.02, 'Largest stamp difference between image, mask and pose of one frame, seconds.')
    queue_size: int = _p(30, 'Messages kept per input queue (oldest dropped and counted when full).')
    pending_timeout_s: float = _p(2.0, 'How long a synchronised frame waits for camera_info / TF before it is '
                                  'dropped, seconds of stamp time.')
    min_translation_m: float = _p(0.05, 'New keyframe when the camera moved this far since the last one, metres...')
    min_rotation_deg: float = _p(5.0, '...or turned this much, degrees.')
    max_keyframes: int = _p(300, 'Stop collecting after this many keyframes.')
    blur_threshold: float = _p(0.0, 'Reject frames whose variance of the Laplacian (8-bit grey) is below this; '
                               '0 = off.')
    preset: Literal['auto', 'tiny', 'cpu', 'default', 'paper'] = _p(
        'auto', "Training preset; 'auto' = default on CUDA, cpu on the CPU; 'tiny' = about 3x faster than cpu, "
        "fewer of a row's fruit counted.")
    device: str = _p('auto', "Torch device: auto, cpu, cuda or cuda:N.")
    auto_train_after: int = _p(0, 'Start training by itself once this many keyframes are collected (once); '
                               '0 = only on ~/train.')
    min_keyframes: int = _p(5, 'Fewest keyframes that ~/train accepts.')
    config_file: str = _p('', "Optional YAML with sections 'train', 'export', 'clustering' overriding the preset "
                          'and the export / clustering defaults.')
    output_dir: str = _p('', "Run directory (keyframes/, training runs, results); '' = "
                         '~/.ros/fruitnerfpp/run_<UTC time>.')
    diagnostics_period_s: float = _p(1.0, 'Period of /diagnostics, seconds.')
    silent_input_warning_s: float = _p(5.0, 'Warn when an input topic has been silent this long, seconds.')

    def __post_init__(self) -> None:
        if self.sync_slop_s < 0 or self.queue_size < 1 or self.pending_timeout_s <= 0:
            raise ConfigError('sync_slop_s must be >= 0, queue_size >= 1 and pending_timeout_s > 0')
        if self.auto_train_after < 0 or self.min_keyframes < 1:
            raise ConfigError('auto_train_after must be >= 0 and min_keyframes >= 1')
        if self.diagnostics_period_s <= 0 or self.silent_input_warning_s <= 0:
            raise ConfigError('diagnostics_period_s and silent_input_warning_s must be > 0')
        if self.camera_extrinsic:
            self.extrinsic_values()

    def extrinsic_values(self) -> tuple[float, ...] | None:
        """The 7 numbers of ``camera_extrinsic`` (x y z qx qy qz qw), or None when it is empty."""
        if not self.camera_extrinsic.strip():
            return None
        try:
            values = tuple(float(v) for v in self.camera_extrinsic.replace(',', ' ').split())
        except ValueError as err:
            raise ConfigError(f'camera_extrinsic: not numbers: {self.camera_extrinsic!r}') from err
        if len(values) != 7:
            raise ConfigError(f"camera_extrinsic: expected 'x y z qx qy qz qw' (7 numbers), got {len(values)}")
        return values


class ParamSpec(NamedTuple):
    """One declared parameter: name, default (its type is the parameter's type) and description."""

    name: str
    default: Any
    description: str


PARAMETERS: tuple[ParamSpec, ...] = tuple(
    ParamSpec(f.name, f.default, f.metadata['description']) for f in dataclasses.fields(CounterSettings))


def settings_from_parameters(values: Mapping[str, Any] | None) -> CounterSettings:
    """Validated settings from parameter values (missing ones keep their defaults).

    Raises:
        ConfigError: unknown parameter name, wrong type or value out of range (the message names it).
    """
    values = dict(values or {})
    hints = {f.name: f.type for f in dataclasses.fields(CounterSettings)}
    for name, value in list(values.items()):  # YAML may give an int where a float is declared
        if hints.get(name) in (float, 'float') and isinstance(value, int) and not isinstance(value, bool):
            values[name] = float(value)
    return config_from_mapping(CounterSettings, values)


def load_parameter_file(path: str | Path, node_name: str = 'fruit_counter') -> dict[str, Any]:
    """Parameters for ``node_name`` from a ROS 2 params file (``/**:`` or ``<node_name>:`` → ``ros__parameters``).

    A plain mapping of parameter names (no ``ros__parameters`` level) is accepted too.

    Raises:
        ConfigError: the file is missing, not YAML or not shaped like a params file.
    """
    path = Path(path)
    data = load_yaml_mapping(path, kind='params file')
    merged: dict[str, Any] = {}
    sections = [v for k, v in data.items() if k in ('/**', node_name, f'/{node_name}')]
    if not sections and not any(isinstance(v, Mapping) and 'ros__parameters' in v for v in data.values()):
        return dict(data)
    for section in sections:
        params = section.get('ros__parameters') if isinstance(section, Mapping) else None
        if not isinstance(params, Mapping):
            raise ConfigError(f'{path}: section for {node_name} has no ros__parameters mapping')
        merged.update(params)
    return merged


def keyframe_config(settings: CounterSettings) -> KeyframeConfig:
    """Keyframe selection of the core from the settings."""
    return KeyframeConfig(settings.min_translation_m, settings.min_rotation_deg, settings.max_keyframes,
                          settings.blur_threshold)


class PipelineConfigs(NamedTuple):
    """Configs handed to :func:`fruitnerfpp_ros.core.pipeline.run_pipeline`, plus notes for the log."""

    train: Any
    export: Any
    cluster: Any
    preset: str
    notes: tuple[str, ...]


def pipeline_configs(settings: CounterSettings) -> PipelineConfigs:
    """TrainConfig (preset + ``config_file`` 'train' overrides), ExportConfig and ClusterConfig of the settings.

    Raises:
        ConfigError: an unreadable config_file or an unknown key in it.
    """
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.export.config import ExportConfig
    from fruitnerfpp_ros.core.training import TrainConfig
    from fruitnerfpp_ros.core.device import device_preset
    name, note = device_preset(settings.preset, settings.device)
    sections: dict[str, Any] = {}
    if settings.config_file:  # the same file `fruitnerfpp run --config` reads, under the same rules
        sections = load_pipeline_sections(settings.config_file, kind='config_file')
    try:
        train = TrainConfig.preset(name)
        if sections.get('train'):
            train = replace_nested(train, sections['train'])
        export = config_from_mapping(ExportConfig, sections.get('export') or {})
        cluster = config_from_mapping(ClusterConfig, sections.get('clustering') or {})
    except ConfigError as err:
        raise ConfigError(f'config_file {settings.config_file}: {err}' if settings.config_file else str(err)) \
            from err
    return PipelineConfigs(train, export, cluster, name, (note,) if note else ())


def use_node_cpu_threads(configs: PipelineConfigs, device: str) -> None:
    """Set the training threads of a node's process: the config's count, and one thread for auto (0): a node shares
    the robot's cores with its other processes, where more threads' OpenMP barriers stall."""
    from fruitnerfpp_ros.core.device import use_cpu_threads
    use_cpu_threads(configs.train.cpu_threads or 1, device)


def declare_parameters(node: Any) -> CounterSettings:
    """Declare every parameter on an rclpy node (typed, with its description) and return the settings.

    Raises:
        ConfigError: a value of the wrong type or out of range.
    """
    from rcl_interfaces.msg import ParameterDescriptor, ParameterType
    types = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
             float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}
    values = {}
    for spec in PARAMETERS:
        descriptor = ParameterDescriptor(name=spec.name, type=types[type(spec.default)],
                                         description=spec.description)
        values[spec.name] = node.declare_parameter(spec.name, spec.default, descriptor).value
    return settings_from_parameters(values)


def parameter_table() -> str:
    """Markdown table of every parameter (used for docs/ros_interface.md)."""
    rows = ['| Parameter | Type | Default | Description |', '|---|---|---|---|']
    for spec in PARAMETERS:
        rows.append(f'| `{spec.name}` | {type(spec.default).__name__} | `{spec.default!r}` | {spec.description} |')
    return '\n'.join(rows)


def settings_mapping(settings: CounterSettings) -> dict[str, Any]:
    """Plain mapping of the settings (for logging and the resolved params file)."""
    return config_to_mapping(settings)
