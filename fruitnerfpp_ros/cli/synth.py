"""``fruitnerfpp synth``: generate a synthetic orchard tree (transforms.json dataset, ground truth, optional bag).

Example::

    fruitnerfpp synth --fruit apple --count 30 --views 32 --resolution 128 --out synth_apple \\
        --bag synth_apple_bag --preview synth_apple/preview.png

    # a robot's drive along the row, a 4:3 distorted camera, a JPEG bag in the odom frame
    fruitnerfpp synth --fruit apple --count 300 --views 64 --resolution 160 120 --trajectory row \\
        --row-standoff 2.0 --camera-height 1.2 --camera-pitch 5 --fy-scale 1.02 --principal-offset 3 -2 \\
        --distortion -0.15 0.03 0.001 -0.001 --bag-image-format jpeg --world-frame odom --out row --bag row_bag

    # an RGB-D camera: depths/ (16-bit mm) and a 16UC1 depth topic, with a stereo camera's errors
    fruitnerfpp synth --fruit apple --count 20 --views 48 --resolution 96 --depth --out rgbd --bag rgbd_bag

    # a row of 5 trees (20 apples each on average) driven on both sides, with GNSS fixes in the bag
    fruitnerfpp synth --scene row --trees 5 --count 20 --views 160 --resolution 240 180 --gnss --out row5 --bag row5_bag

Every flag overrides the same-named field of :class:`~fruitnerfpp_ros.core.synthetic.SynthConfig` (and of
``--config`` YAML); a flag left out keeps the YAML's or the default value.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any, Callable, NamedTuple

from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.progress import ProgressEvent
from fruitnerfpp_ros.errors import ConfigError, SynthError

__all__ = ['register', 'run', 'parse_resolution']


def parse_resolution(text: str | list[str]) -> tuple[int, int]:
    """``'128'`` -> (128, 128); ``'160x120'`` or ``['160', '120']`` -> (160, 120) (width, height).

    Raises:
        SynthError: not a size.
    """
    shown = ' '.join(text) if isinstance(text, list) else text
    parts = text if isinstance(text, list) else [text]
    if len(parts) == 1:
        parts = parts[0].lower().split('x')
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) == 1:
        values = values * 2
    if len(values) != 2:
        raise SynthError(f'--resolution: expected a size like 128, 160x120 or 160 120, got {shown!r}')
    return values[0], values[1]


def _int(text: str, flag: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise SynthError(f'{flag}: expected an integer, got {text!r}') from None


def _float(text: str, flag: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise SynthError(f'{flag}: expected a number, got {text!r}') from None


def _floats(texts: list[str], flag: str) -> tuple[float, ...]:
    return tuple(_float(t, flag) for t in texts)


class _Flag(NamedTuple):
    """A command-line flag overriding SynthConfig ``field`` (``convert`` turns the parsed text into its value)."""

    flag: str
    field: str
    convert: Callable[[Any, str], Any]
    help: str
    nargs: str | int | None = None
    metavar: str | tuple[str, ...] | None = None


def _text(value: str, flag: str) -> str:
    return value


_FLAGS = (
    _Flag('--fruit', 'fruit', _text, 'apple, plum, lemon, pear, peach, mango or mixed (default apple)'),
    _Flag('--count', 'count', _int, "number of fruits (default: the type's paper count, e.g. apple 283)"),
    _Flag('--views', 'views', _int, 'number of camera views (default 32)'),
    _Flag('--resolution', 'resolution', lambda v, f: parse_resolution(v),
          'image size: 128 (square), WxH like 160x120, or W H (default 128)', '+', 'SIZE'),
    _Flag('--trajectory', 'trajectory', _text, 'hemisphere (default) or row (a drive on both sides of the row)'),
    _Flag('--seed', 'seed', _int, 'random seed (default 0)'),
    _Flag('--device', 'device', _text, 'auto (default), cpu or cuda'),
    _Flag('--fov', 'fov_deg', _float, 'field of view across the shorter image side, degrees (default 50)'),
    _Flag('--leaf-scale', 'leaf_scale', _float, 'multiplier on leaf density (occlusion; default 1, 0 = no leaves)'),
    _Flag('--cluster-scale', 'cluster_scale', _float, 'multiplier on touching-fruit clusters (default 1)'),
    _Flag('--sparse-points', 'sparse_points', _int, 'points in sparse_pc.ply (default 4000)'),
    _Flag('--row-standoff', 'row_standoff_m', _float, 'row: camera distance from the row centre line, m (default 2)'),
    _Flag('--camera-height', 'camera_height_m', _float, 'row: camera height above the ground, m (default 1.2)'),
    _Flag('--camera-pitch', 'camera_pitch_deg', _float, 'row: camera pitch above the horizon, degrees (default 5)'),
    _Flag('--row-jitter', 'row_jitter', _float,
          'row: scale of the smooth height/standoff/yaw/pitch/roll jitter of the drive (default 1, 0 = none)'),
    _Flag('--row-length', 'row_length_m', _float,
          'row: length of each pass, m (default: the tree enters and leaves the view)'),
    _Flag('--fy-scale', 'fy_scale', _float, 'vertical focal length = horizontal x this (default 1)'),
    _Flag('--principal-offset', 'principal_offset_px', _floats,
          'principal point offset from the image centre, pixels (default 0 0)', 2, ('DX', 'DY')),
    _Flag('--distortion', 'distortion', _floats,
          "lens distortion K1 K2 P1 P2 [K3], OpenCV's plumb_bob (default none): images and masks are distorted",
          '+', 'K'),
    _Flag('--appearance-variation', 'appearance_variation', _float,
          '0..1: lighting, colour temperature, ground, leaf and fruit colours vary with the seed (default 0)'),
    _Flag('--bag-image-format', 'bag_image_format', _text,
          'raw (Image rgb8, default) or jpeg (CompressedImage on /camera/image_raw/compressed)'),
    _Flag('--jpeg-quality', 'bag_jpeg_quality', _int, 'JPEG quality 1..100 of --bag-image-format jpeg (default 90)'),
    _Flag('--world-frame', 'world_frame', _text, 'fixed frame of the bag: pose header and /tf parent (default map)'),
    _Flag('--depth-baseline', 'depth_baseline_m', _float, 'depth: stereo baseline, m (default 0.05)'),
    _Flag('--depth-focal', 'depth_focal_px', _float,
          'depth: focal length of the depth sensor, its own pixels (default 640)'),
    _Flag('--depth-disparity-noise', 'depth_disparity_noise_px', _float,
          'depth: stereo disparity noise, px (default 0.08): sigma(z) = noise z^2 / (focal baseline)'),
    _Flag('--depth-max-range', 'depth_max_range_m', _float, 'depth: farthest return, m (default 6)'),
)


def register(subparsers: Any) -> None:
    """Add the ``synth`` subcommand."""
    parser = subparsers.add_parser(
        'synth', help='generate a synthetic fruit tree with ground truth',
        description='Render a procedural fruit tree to a transforms.json dataset (RGB, instance and semantic '
                    'masks), gt_fruits.json and sparse_pc.ply; optionally a rosbag2 recording and a preview.')
    for flag in _FLAGS:
        parser.add_argument(flag.flag, dest=flag.field, help=flag.help, nargs=flag.nargs, metavar=flag.metavar)
    parser.add_argument('--depth', nargs='?', const='stereo', metavar='MODEL',
                        help='also write depth images aligned to the colour images (depths/, and a 16UC1 depth topic '
                             'in the bag): stereo (the default model: noise growing with range squared, holes at '
                             'depth edges and on leaves, a maximum range), exact, or random (garbage)')
    parser.add_argument('--pose-noise', nargs=2, metavar=('METRES', 'DEGREES'),
                        help='odometry error: per-axis standard deviations of noise on the recorded camera positions '
                             'and orientations (images stay rendered from the true poses)')
    parser.add_argument('--pass-offset', nargs=2, type=float, metavar=('METRES', 'DEGREES'),
                        help='odometry drift between the sides: the recorded poses of the views on the +y side (a '
                             "row's return pass) shifted along x and turned about the vertical")
    parser.add_argument('--mask-noise', nargs=3, type=float, metavar=('MISSED', 'FALSE', 'BOUNDARY_PX'),
                        help="instance masks as a learned segmenter's: the share of fruit masks missed, false "
                             'detections per fruit, boundaries moved by this many pixels (e.g. 0.15 0.1 1); the '
                             'ground truth stays exact')
    row = parser.add_argument_group('a row of trees (--scene row)')
    row.add_argument('--scene', choices=('tree', 'row'), default='tree',
                     help='tree (default): one tree; row: a row of --trees trees whose canopies touch or overlap, '
                          'driven on both sides (the row trajectory; --count = mean fruits per tree); writes '
                          'gt_trees.json and a planting map too')
    row.add_argument('--trees', type=int, help='row: number of trees (default 5)')
    row.add_argument('--tree-spacing', type=float, metavar='M',
                     help='row: trunk spacing along the row, m (default: neighbouring canopies overlap by 10%%)')
    row.add_argument('--gnss', action='store_true',
                     help='row: GNSS fixes of an antenna 0.5 m above the camera (5 Hz, RTK noise 2 cm / 4 cm): '
                          'sensor_msgs/NavSatFix on /gnss/fix in the bag and gnss.json')
    row.add_argument('--gnss-noise', nargs=2, type=float, metavar=('HORIZONTAL', 'VERTICAL'),
                     help='row: standard deviation of the fixes, m (default 0.02 0.04)')
    row.add_argument('--datum', nargs='+', type=float, metavar='V',
                     help='row: LAT LON ALT [YAW_DEG] of the world origin and the heading of the row (x axis, '
                          'counter-clockwise from east); recorded in transforms.json')
    parser.add_argument('--out', required=True, help='output dataset directory')
    parser.add_argument('--bag', help='also write a rosbag2 directory here')
    parser.add_argument('--bag-storage', default='mcap', help='mcap (default) or sqlite3')
    parser.add_argument('--preview', help='write a contact sheet PNG (RGB | instance | semantic)')
    parser.add_argument('--config', help='YAML file with SynthConfig defaults (e.g. config/synth.yaml)')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    parser.set_defaults(func=run)


def _config_from_args(args: argparse.Namespace) -> Any:
    from fruitnerfpp_ros.core.synthetic import SynthConfig

    if args.config is not None:
        try:
            base = load_config(SynthConfig, args.config)
        except ConfigError as err:
            raise SynthError(str(err)) from err
    else:
        base = SynthConfig()
    overrides: dict[str, Any] = {}
    for flag in _FLAGS:
        value = getattr(args, flag.field)
        if value is not None:
            overrides[flag.field] = flag.convert(value, flag.flag)
    if args.depth is not None:
        overrides['depth'] = args.depth
    if args.pose_noise is not None:
        try:
            overrides['pose_noise_m'], overrides['pose_noise_deg'] = (float(v) for v in args.pose_noise)
        except ValueError:
            raise SynthError(f'--pose-noise: expected two numbers (metres, degrees), got {args.pose_noise}') from None
    if args.pass_offset is not None:
        overrides['pass_offset_m'], overrides['pass_offset_deg'] = args.pass_offset
    if args.mask_noise is not None:
        missed, false, boundary = args.mask_noise
        if boundary != int(boundary):
            raise SynthError(f'--mask-noise: BOUNDARY_PX must be a whole number of pixels, got {boundary}')
        overrides.update(mask_missed=missed, mask_false=false, mask_boundary_px=int(boundary))
    return dataclasses.replace(base, **overrides)


def _row_config(args: argparse.Namespace) -> Any:
    """The RowSceneConfig of the row flags (``--scene row``)."""
    from fruitnerfpp_ros.core.synthetic.row_scene import RowSceneConfig

    values: dict[str, Any] = {'gnss': bool(args.gnss)}
    if args.trees is not None:
        values['trees'] = args.trees
    if args.tree_spacing is not None:
        values['tree_spacing_m'] = args.tree_spacing
    if args.gnss_noise is not None:
        values['gnss_noise_m'] = tuple(args.gnss_noise)
    if args.datum is not None:
        if len(args.datum) not in (3, 4):
            raise SynthError('--datum: expected LAT LON ALT [YAW_DEG]')
        values['datum'] = tuple(args.datum[:3])
        if len(args.datum) == 4:
            values['datum_yaw_deg'] = args.datum[3]
    try:
        return RowSceneConfig(**values)
    except ConfigError as err:
        raise SynthError(str(err)) from err


def _check_row_flags(args: argparse.Namespace) -> None:
    used = [flag for flag, value in (('--trees', args.trees), ('--tree-spacing', args.tree_spacing),
                                     ('--gnss-noise', args.gnss_noise), ('--datum', args.datum)) if value is not None]
    if args.gnss:
        used.append('--gnss')
    if used and args.scene != 'row':
        raise SynthError(f'{", ".join(used)}: only with --scene row')


def run(args: argparse.Namespace) -> int:
    """Run ``synth`` from parsed arguments; returns the exit code."""
    from fruitnerfpp_ros.core.synthetic import generate_orchard

    _check_row_flags(args)
    config = _config_from_args(args)
    bar: Any = None

    def on_progress(event: ProgressEvent) -> None:
        nonlocal bar
        if args.quiet:
            return
        if bar is None:  # created on the first event, so input errors print one line only
            from tqdm import tqdm
            bar = tqdm(total=event.total, desc='synth', unit='view')
        bar.n = event.step
        if event.message:
            bar.set_postfix_str(event.message, refresh=False)
        bar.refresh()

    try:
        if args.scene == 'row':
            from fruitnerfpp_ros.core.synthetic.row_scene import generate_row
            result = generate_row(config, _row_config(args), Path(args.out), bag=args.bag,
                                  bag_storage=args.bag_storage, preview=args.preview, progress=on_progress)
        else:
            result = generate_orchard(config, Path(args.out), bag=args.bag, bag_storage=args.bag_storage,
                                      preview=args.preview, progress=on_progress)
    finally:
        if bar is not None:
            bar.close()
    print(f'wrote {result.n_views} views of {result.n_fruits} fruits ({result.n_fruits_visible} visible) to '
          f'{result.dataset_dir} in {result.seconds:.1f} s'
          + (f'; bag {result.bag_path}' if result.bag_path else '')
          + (f'; preview {result.preview_path}' if result.preview_path else ''))
    if result.n_fruits and not result.n_fruits_visible:
        print('warning: no view shows any of the fruits: the cameras look past the tree (a small tree is low: '
              'lower --camera-height, pitch down with --camera-pitch, or widen --fov)', file=sys.stderr)
    return 0
