"""Configuration of the synthetic orchard generator (``fruitnerfpp synth``, ``config/synth.yaml``).

Every option added after the first release defaults to the old behaviour, so a default dataset (e.g. the CI
scene ``SynthConfig(fruit='apple', count=20, views=48, resolution=(96, 96), seed=0)``) keeps byte-identical images,
masks and poses. The ``row_*`` / ``camera_*`` options shape the ``row`` trajectory only.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from fruitnerfpp_ros.core.synthetic.fruit_types import FRUIT_NAMES, MIXED
from fruitnerfpp_ros.errors import SynthError

__all__ = ['SynthConfig', 'TRAJECTORIES', 'BAG_IMAGE_FORMATS', 'MIXED_DEFAULT_COUNT', 'DEPTH_MODELS']

TRAJECTORIES = ('hemisphere', 'row')
#: Image encodings of the bag's camera topic: raw ``sensor_msgs/Image`` rgb8 or JPEG ``CompressedImage``.
BAG_IMAGE_FORMATS = ('raw', 'jpeg')
#: Depth camera models (``depth_sensor.py``): none, the rendered depth, a stereo camera's errors, garbage.
DEPTH_MODELS = ('none', 'exact', 'stereo', 'random')
#: Default fruit count of a ``mixed`` tree (split evenly over the six types).
MIXED_DEFAULT_COUNT = 240
_FRAME_NAME = re.compile(r'^[A-Za-z_][A-Za-z0-9_/]*$')


def _number(config: 'SynthConfig', name: str, lo: float, hi: float) -> float:
    """The float field ``name``, checked to lie within [lo, hi]."""
    value = getattr(config, name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise SynthError(f'{name} must be a number within {lo:g}..{hi:g}, got {value!r}')
    return float(value)


def _numbers(config: 'SynthConfig', name: str, length: tuple[int, ...]) -> tuple[float, ...]:
    """The tuple field ``name`` as finite floats, of one of the lengths ``length``."""
    value = getattr(config, name)
    try:
        values = tuple(float(v) for v in value if not isinstance(v, bool))
    except (TypeError, ValueError):
        values = ()
    if len(values) not in length or len(values) != len(value) or not all(math.isfinite(v) for v in values):
        raise SynthError(f'{name} must be {" or ".join(map(str, length))} finite numbers, got {value!r}')
    return values


@dataclass(frozen=True)
class SynthConfig:
    """Settings of one synthetic tree scene. Invalid values raise :class:`SynthError` on construction."""

    fruit: str = 'apple'
    """Fruit type: apple, plum, lemon, pear, peach, mango, or ``mixed`` (all six types on one tree)."""
    count: int | None = None
    """Number of fruits; None = the type's default (the paper's count: apple 283, plum 745, ...)."""
    views: int = 32
    """Number of rendered camera views."""
    resolution: tuple[int, int] = (128, 128)
    """Image size (width, height) in pixels."""
    trajectory: str = 'hemisphere'
    """``hemisphere``: random views on the upper hemisphere looking at the tree (BlenderNeRF style);
    ``row``: a robot driving past the tree on both sides of the row (out on y < 0 along +x, back on y > 0 along
    -x), its camera facing the row centre line (x axis) from ``row_standoff_m``, views evenly spaced."""
    seed: int = 0
    """Random seed: the same seed gives byte-identical outputs."""
    fov_deg: float = 50.0
    """Field of view across the shorter image side, degrees (of the horizontal focal length ``fl_x``)."""
    leaf_scale: float = 1.0
    """Multiplier on the fruit type's leaf density (0 = no leaves)."""
    cluster_scale: float = 1.0
    """Multiplier on the probability that a fruit hangs in a cluster of touching fruits (0 = all single)."""
    device: str = 'auto'
    """Torch device for rendering: auto (CUDA when present), cpu, cuda."""
    sparse_points: int = 4000
    """Points in ``sparse_pc.ply`` (visible surface points, like a COLMAP sparse cloud)."""
    pose_noise_m: float = 0.0
    """Odometry error: standard deviation (m, per axis) of noise on the recorded camera positions (transforms.json
    and the bag); the images are rendered from the true poses."""
    pose_noise_deg: float = 0.0
    """Standard deviation (degrees, per axis) of a rotation noise on the recorded camera orientations."""
    mask_missed: float = 0.0
    """Instance masks as a learned segmenter's (``mask_noise.py``): the share of the fruit masks it misses (each
    removed with this probability, per view). The masks of the dataset and the bag are degraded alike; the ground
    truth (``gt_fruits.json``) stays the renderer's. transforms.json records ``mask_source: ground_truth_degraded``
    when any ``mask_*`` setting is on."""
    mask_false: float = 0.0
    """... false detections per fruit in a view (fruit-sized discs on leaves and gaps near the fruit)."""
    mask_boundary_px: int = 0
    """... each mask's boundary moved by this many pixels (eroded, kept or dilated with equal odds)."""
    pass_offset_m: float = 0.0
    """Odometry drift between the two sides: the recorded poses of every view on the +y side of the tree (a row's
    return pass) shifted along x by this (m), as the error a robot's odometry has built up after the turn. Feature
    tracks cannot see it: no view of one side shares features with a view of the other."""
    pass_offset_deg: float = 0.0
    """... and turned by this (degrees) about the vertical through those views' mean position."""
    row_standoff_m: float = 2.0
    """``row``: distance (m) from the row centre line (the trunk at y = 0) to the camera; orchards: 1.5-3 m. Must
    leave the camera outside the crown."""
    camera_height_m: float = 1.2
    """``row``: camera height above the ground (m); a mast on a robot: 0.8-2 m."""
    camera_pitch_deg: float = 5.0
    """``row``: camera pitch, degrees above the horizon (negative looks down); ground and sky stay in view for
    pitches well inside the vertical field of view."""
    row_jitter: float = 1.0
    """``row``: scale of the drive's smooth jitter along the path (1 = height 2 cm, standoff 3 cm, yaw 1.5 deg,
    pitch 0.7 deg, roll 1 deg standard deviations over metre-scale wavelengths); 0 = a perfect drive."""
    row_length_m: float | None = None
    """``row``: length (m) of each pass, centred on the tree; None = long enough for the tree to enter the view
    after the first view and leave it before the last."""
    fy_scale: float = 1.0
    """Vertical focal length ``fl_y`` = ``fl_x`` x this (unequal pixel pitch; real cameras: 0.98-1.02)."""
    principal_offset_px: tuple[float, float] = (0.0, 0.0)
    """Principal point offset (dx, dy) in pixels from the image centre (cx = w / 2 + dx, cy = h / 2 + dy)."""
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    """Lens distortion (k1, k2, p1, p2, k3), OpenCV's plumb_bob model on normalised coordinates. Non-zero: the
    images and masks are distorted, as a real camera delivers them, and transforms.json (nerfstudio ``OPENCV``
    keys k1, k2, p1, p2, plus k3 when non-zero) and the bag's CameraInfo (D = [k1, k2, p1, p2, k3]) record the
    coefficients. The model must be invertible over the image (SynthError when generating otherwise)."""
    appearance_variation: float = 0.0
    """0..1: how much lighting (sun direction and strength, ambient, colour temperature), sky, ground texture,
    leaf / bark tint and per-fruit colour vary with the seed (``appearance.py``); 0 = the fixed look."""
    bag_image_format: str = 'raw'
    """Bag camera images: ``raw`` (sensor_msgs/Image rgb8 on /camera/image_raw) or ``jpeg``
    (sensor_msgs/CompressedImage on /camera/image_raw/compressed, as image_transport's compressed plugin)."""
    bag_jpeg_quality: int = 90
    """JPEG quality 1..100 of ``bag_image_format: jpeg``."""
    world_frame: str = 'map'
    """Fixed frame of the bag: PoseStamped header and the /tf parent of ``base_link`` (e.g. map, odom)."""
    depth: str = 'none'
    """A depth camera aligned to the colour camera (``depth_sensor.py``): ``none``; ``stereo`` (range noise
    growing with range squared, holes at depth edges and on thin leaves, a maximum range); ``exact`` (the rendered
    depth); ``random`` (garbage). Written as depths/NNNN.png (16-bit millimetres, ``depth_file_path``) and, with a
    bag, as 16UC1 on /camera/aligned_depth_to_color/image_raw; ``none`` leaves every other file unchanged."""
    depth_baseline_m: float = 0.05
    """Stereo baseline b (m) of the ``stereo`` model: sigma(z) = k z^2 / (f b)."""
    depth_focal_px: float = 640.0
    """Focal length f of the depth sensor in its own pixels (a 1280x720 stereo pair: ~640)."""
    depth_disparity_noise_px: float = 0.08
    """Disparity noise k (px) of the stereo matcher."""
    depth_max_range_m: float = 6.0
    """Farthest depth the sensor returns, metres."""

    def __post_init__(self) -> None:
        known = (*FRUIT_NAMES, MIXED)
        if self.fruit not in known:
            raise SynthError(f'unknown fruit type {self.fruit!r}; expected one of {", ".join(known)}')
        if self.count is not None and (isinstance(self.count, bool) or not isinstance(self.count, int)
                                       or self.count < 1 or self.count > 20000):
            raise SynthError(f'count must be an integer between 1 and 20000, got {self.count!r}')
        if isinstance(self.views, bool) or not isinstance(self.views, int) or self.views < 1:
            raise SynthError(f'views must be a positive integer, got {self.views!r}')
        res = tuple(self.resolution)
        if (len(res) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in res)
                or min(res) < 8 or max(res) > 8192):
            raise SynthError(f'resolution must be (width, height) with 8..8192 px each, got {self.resolution!r}')
        object.__setattr__(self, 'resolution', res)
        for name in ('pose_noise_m', 'pose_noise_deg'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0.0 <= value < 1e3:
                raise SynthError(f'{name} must be a number >= 0, got {value!r}')
        _number(self, 'mask_missed', 0.0, 1.0)
        _number(self, 'mask_false', 0.0, 1.0)
        if isinstance(self.mask_boundary_px, bool) or not isinstance(self.mask_boundary_px, int) \
                or not 0 <= self.mask_boundary_px <= 10:
            raise SynthError(f'mask_boundary_px must be an integer within 0..10, got {self.mask_boundary_px!r}')
        for name in ('pass_offset_m', 'pass_offset_deg'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not abs(value) < 1e3:
                raise SynthError(f'{name} must be a number, got {value!r}')
        if self.trajectory not in TRAJECTORIES:
            raise SynthError(f'unknown trajectory {self.trajectory!r}; expected one of {", ".join(TRAJECTORIES)}')
        if not 10.0 <= float(self.fov_deg) <= 120.0:
            raise SynthError(f'fov_deg must be within 10..120 degrees, got {self.fov_deg!r}')
        if self.leaf_scale < 0 or self.cluster_scale < 0:
            raise SynthError('leaf_scale and cluster_scale must be >= 0')
        if self.sparse_points < 0:
            raise SynthError(f'sparse_points must be >= 0, got {self.sparse_points!r}')
        self._check_row_and_camera()
        if self.bag_image_format not in BAG_IMAGE_FORMATS:
            raise SynthError(f'unknown bag_image_format {self.bag_image_format!r}; expected one of '
                             f'{", ".join(BAG_IMAGE_FORMATS)}')
        quality = self.bag_jpeg_quality
        if isinstance(quality, bool) or not isinstance(quality, int) or not 1 <= quality <= 100:
            raise SynthError(f'bag_jpeg_quality must be an integer within 1..100, got {quality!r}')
        if not isinstance(self.world_frame, str) or not _FRAME_NAME.match(self.world_frame):
            raise SynthError(f'world_frame must be a ROS frame name like map or odom (letters, digits, _ and /, '
                             f'no leading /), got {self.world_frame!r}')
        if self.depth not in DEPTH_MODELS:
            raise SynthError(f'unknown depth model {self.depth!r}; expected one of {", ".join(DEPTH_MODELS)}')
        _number(self, 'depth_baseline_m', 0.005, 2.0)
        _number(self, 'depth_focal_px', 10.0, 1e5)
        _number(self, 'depth_disparity_noise_px', 0.0, 10.0)
        _number(self, 'depth_max_range_m', 0.5, 1000.0)

    def _check_row_and_camera(self) -> None:
        _number(self, 'row_standoff_m', 0.3, 50.0)
        _number(self, 'camera_height_m', 0.05, 20.0)
        _number(self, 'camera_pitch_deg', -60.0, 60.0)
        _number(self, 'row_jitter', 0.0, 10.0)
        if self.row_length_m is not None:
            _number(self, 'row_length_m', 0.01, 1000.0)
        _number(self, 'fy_scale', 0.5, 2.0)
        w, h = self.resolution
        dx, dy = _numbers(self, 'principal_offset_px', (2,))
        if abs(dx) >= 0.5 * w or abs(dy) >= 0.5 * h:
            raise SynthError(f'principal_offset_px must keep the principal point inside the {w}x{h} image, got '
                             f'{self.principal_offset_px!r}')
        object.__setattr__(self, 'principal_offset_px', (dx, dy))
        coefficients = _numbers(self, 'distortion', (4, 5))
        if any(abs(k) > 10.0 for k in coefficients):
            raise SynthError(f'distortion coefficients must be within -10..10, got {self.distortion!r}')
        object.__setattr__(self, 'distortion', (coefficients + (0.0,))[:5])
        _number(self, 'appearance_variation', 0.0, 1.0)

    @property
    def degrades_masks(self) -> bool:
        """Whether the masks are degraded as a segmenter's (any ``mask_*`` setting on)."""
        return self.mask_missed > 0 or self.mask_false > 0 or self.mask_boundary_px > 0

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return self.resolution[0]

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return self.resolution[1]
