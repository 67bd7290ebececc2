"""``generate_orchard``: build, render and write one synthetic tree scene with exact ground truth.

Output directory::

    transforms.json     nerfstudio convention (OpenGL camera-to-world, top-left-corner cx, cy; camera_model OPENCV
                        with k1, k2, p1, p2 (k3) when the lens distorts), per-frame instance_path and semantic_path,
                        ply_file_path
    images/0000.png     RGB (distorted like the lens when ``distortion`` is set)
    instances/0000.png  uint16 instance ids (0 = background, k = fruit k of gt_fruits.json), from the same pixel rays
    semantics/0000.png  fruit = 255, rest = 0
    depths/0000.png     (``depth`` other than none) 16-bit depth in millimetres along the optical axis, aligned to the
                        image (distorted like it), 0 = no return; ``depth_file_path`` per frame and
                        ``depth_unit_scale_factor`` 0.001 in transforms.json (depth_sensor.py: the sensor model)
    gt_fruits.json      {"fruits": [{"id", "type", "center", "radii", "diameter", "rotation", "views_visible",
                        "n_views_visible"}]}: views_visible lists every view (training and held-out alike: the
                        generator knows no split) showing at least one pixel of the fruit
    sparse_pc.ply       a few thousand visible surface points (like a COLMAP sparse cloud)
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.config_io import config_to_mapping
from fruitnerfpp_ros.core.data.depth_image import DEPTH_PNG_UNIT_M, write_depth_png
from fruitnerfpp_ros.core.data.transforms_format import MASK_SOURCE_KEY, CameraIntrinsics, FrameEntry, TransformsFile, \
    write_transforms
from fruitnerfpp_ros.core.device import resolve_device
from fruitnerfpp_ros.core.geometry import T_OPENGL_OPTICAL
from fruitnerfpp_ros.core.progress import Phase, ProgressCallback, ProgressEvent, ignore_progress
from fruitnerfpp_ros.core.synthetic.appearance import sample_appearance, vary_scene_colours
from fruitnerfpp_ros.core.synthetic.bag_writer import BAG_START_NS, FRAME_PERIOD_NS, BagWriter
from fruitnerfpp_ros.core.synthetic.cameras import make_intrinsics, make_poses
from fruitnerfpp_ros.core.synthetic.config import SynthConfig
from fruitnerfpp_ros.core.data.png_io import write_mask_png, write_rgb_png, write_uint16_png
from fruitnerfpp_ros.core.synthetic.depth_sensor import sensed_depth
from fruitnerfpp_ros.core.synthetic.dataset_writer import GT_NAME, SPARSE_PLY_NAME, write_gt_fruits, write_sparse_ply
from fruitnerfpp_ros.core.synthetic.lens import is_distorted, undistorted_pixel_grid
from fruitnerfpp_ros.core.synthetic.mask_noise import degrade_instances
from fruitnerfpp_ros.core.synthetic.preview import preview_view_indices, write_preview
from fruitnerfpp_ros.core.synthetic.rasterizer import Renderer
from fruitnerfpp_ros.core.synthetic.primitives import Scene
from fruitnerfpp_ros.core.synthetic.scene import build_scene, fruit_type_counts
from fruitnerfpp_ros.errors import ConfigError, SynthError

__all__ = ['SynthResult', 'generate_orchard']


@dataclass(frozen=True)
class SynthResult:
    """What :func:`generate_orchard` wrote.

    Attributes:
        dataset_dir: the output directory (holds transforms.json).
        n_fruits: fruits on the tree (ids 1..n_fruits).
        n_views: rendered views.
        gt_path: path of gt_fruits.json.
        transforms_path: path of transforms.json.
        bag_path: rosbag2 directory, or None when no bag was asked for.
        preview_path: contact sheet PNG, or None.
        n_fruits_visible: fruits seen (at least one pixel) by at least one view.
        seconds: wall time of the whole generation.
    """

    dataset_dir: Path
    n_fruits: int
    n_views: int
    gt_path: Path
    transforms_path: Path
    bag_path: Path | None
    preview_path: Path | None
    n_fruits_visible: int
    seconds: float


def _prepare_out_dir(out_dir: Path, n_views: int, depth: bool) -> None:
    try:
        if out_dir.exists() and not out_dir.is_dir():
            raise SynthError(f'output path {out_dir} exists and is not a directory')
        subs = ('images', 'instances', 'semantics') + (('depths',) if depth else ())
        for sub in subs:
            (out_dir / sub).mkdir(parents=True, exist_ok=True)
        probe = out_dir / '.write_test'
        probe.write_bytes(b'')
        probe.unlink()
        # Frames of an earlier, larger run would otherwise linger next to this run's frames.
        for sub in subs:
            for stale in (out_dir / sub).glob('[0-9][0-9][0-9][0-9].png'):
                if int(stale.stem) >= n_views:
                    stale.unlink()
    except OSError as err:
        raise SynthError(f'cannot write to output directory {out_dir}: {err.strerror or err}') from err


def generate_orchard(config: SynthConfig, out_dir: str | Path, *, bag: str | Path | None = None,
                     bag_storage: str = 'mcap', preview: str | Path | None = None,
                     progress: ProgressCallback | None = None, scene: Scene | None = None,
                     transforms_extra: Mapping[str, Any] | None = None, gnss_fixes: Sequence[Any] = ()
                     ) -> SynthResult:
    """Generate one synthetic tree scene into ``out_dir`` (created), optionally a rosbag2 and a preview.

    Args:
        config: scene settings (same config and seed -> byte-identical files).
        out_dir: dataset directory.
        bag: rosbag2 directory to write (must not exist, or be a previous bag), or None.
        bag_storage: ``mcap`` or ``sqlite3``.
        preview: contact sheet PNG path (RGB | instance | semantic of a few views), or None.
        progress: called with ``ProgressEvent(Phase.SYNTH_RENDER, view, views)`` after each view.
        scene: the scene to render instead of ``build_scene(config)`` (a row of trees: ``row_scene.py``).
        transforms_extra: top-level keys added to (or replacing) those of transforms.json.
        gnss_fixes: GNSS fixes (:class:`~fruitnerfpp_ros.core.orchard.gnss.GnssFix`, by stamp) written to the bag
            as sensor_msgs/NavSatFix between the frames of their stamps (none: no GNSS topic).

    Raises:
        SynthError: unwritable output, bad bag path or storage, unknown device, a lens distortion that cannot be
            inverted over the image, or a row standoff inside the tree.
    """
    started = time.perf_counter()
    progress = progress or ignore_progress
    out_dir = Path(out_dir)
    with_depth = config.depth != 'none'
    _prepare_out_dir(out_dir, config.views, with_depth)
    try:
        device = resolve_device(config.device)
    except ConfigError as err:
        raise SynthError(str(err)) from err

    scene = vary_scene_colours(build_scene(config) if scene is None else scene, config.seed,
                               config.appearance_variation)
    poses = make_poses(scene, config)
    K = make_intrinsics(config)
    pixel_grid = undistorted_pixel_grid(K) if is_distorted(K) else None  # checks the lens before writing
    renderer = Renderer(scene, device, sample_appearance(config.seed, config.appearance_variation))
    n_fruits = len(scene.fruits)
    visible = np.zeros((config.views, n_fruits + 1), dtype=bool)
    preview_idx = set(preview_view_indices(config.views, two_passes=config.trajectory == 'row')) \
        if preview is not None else set()
    preview_rgb, preview_inst, preview_labels = [], [], []
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x9C]))
    depth_rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x9E]))  # the depth sensor's own stream
    mask_rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0xA1]))  # the masks' errors: own stream
    per_view = int(np.ceil(config.sparse_points / config.views)) if config.sparse_points else 0
    recorded = _noisy_poses(poses, config)
    pc_points, pc_colors = [], []
    frames = []
    bag_ctx = contextlib.nullcontext() if bag is None else BagWriter(
        bag, bag_storage, image_format=config.bag_image_format, jpeg_quality=config.bag_jpeg_quality,
        world_frame=config.world_frame, depth=with_depth, **({'gnss': True} if gnss_fixes else {}))
    pending_fixes = list(gnss_fixes)
    progress(ProgressEvent(Phase.SYNTH_RENDER, 0, config.views, f'{n_fruits} fruits'))
    with bag_ctx as bag_writer:
        for i, T in enumerate(poses):
            view = renderer.render(T, K)
            name = f'{i:04d}.png'
            write_rgb_png(out_dir / 'images' / name, view.rgb)
            masks = degrade_instances(view.instance, mask_rng, missed=config.mask_missed,
                                      false_rate=config.mask_false, boundary_px=config.mask_boundary_px) \
                if config.degrades_masks else view.instance
            write_uint16_png(out_dir / 'instances' / name, masks)
            write_mask_png(out_dir / 'semantics' / name, masks > 0)
            visible[i] = np.bincount(view.instance.reshape(-1).astype(np.int64), minlength=n_fruits + 1) > 0
            stamp_ns = BAG_START_NS + i * FRAME_PERIOD_NS
            depth = None
            if with_depth:
                depth = sensed_depth(view.depth, view.surface, config.depth, depth_rng,
                                     max_range_m=config.depth_max_range_m,
                                     disparity_noise_px=config.depth_disparity_noise_px,
                                     focal_px=config.depth_focal_px, baseline_m=config.depth_baseline_m)
                write_depth_png(out_dir / 'depths' / name, depth)
            frames.append(FrameEntry(f'images/{name}', recorded[i], f'instances/{name}', f'semantics/{name}',
                                     stamp_ns=stamp_ns, depth_path=f'depths/{name}' if with_depth else None))
            if per_view:
                pts, cols = _sample_surface(view.depth, view.rgb, T, K, per_view, scene.bound_radius, rng,
                                            pixel_grid)
                pc_points.append(pts)
                pc_colors.append(cols)
            if bag_writer is not None:
                while pending_fixes and pending_fixes[0].stamp_ns <= stamp_ns:
                    bag_writer.write_gnss_fix(pending_fixes.pop(0))
                bag_writer.write_frame(stamp_ns, view.rgb, masks, recorded[i], K, depth)
            if i in preview_idx:
                preview_rgb.append(view.rgb)
                preview_inst.append(masks)
                preview_labels.append(f'view {i}')
            progress(ProgressEvent(Phase.SYNTH_RENDER, i + 1, config.views))
        for fix in pending_fixes if bag_writer is not None else ():
            bag_writer.write_gnss_fix(fix)

    ply_name = None
    if per_view:
        write_sparse_ply(out_dir / SPARSE_PLY_NAME, np.concatenate(pc_points), np.concatenate(pc_colors))
        ply_name = SPARSE_PLY_NAME
    counts = fruit_type_counts(config)
    extra = {
        'camera_model': 'OPENCV',
        'fruit_types': sorted(counts),
        'generator': {'name': 'fruitnerfpp synth', 'config': _recorded_config(config)},
        'frame': 'world: z up, metres, ground at z = 0, tree trunk at the origin',
        MASK_SOURCE_KEY: 'ground_truth_degraded' if config.degrades_masks else 'ground_truth',  # rendered ids
        **(transforms_extra or {}),
    }
    transforms_path = write_transforms(out_dir, TransformsFile(K, frames, ply_name, extra,
                                                               DEPTH_PNG_UNIT_M if with_depth else None))
    gt_path = out_dir / GT_NAME
    write_gt_fruits(gt_path, scene.fruits, visible[:, 1:], {
        'units': 'm', 'frame': 'world (z up, ground z = 0), same as transforms.json',
        'counts': {k: v for k, v in sorted(counts.items())}, 'n_views': config.views,
        'view_stamps_ns': [frame.stamp_ns for frame in frames]})
    preview_path = None
    if preview is not None:
        preview_path = Path(preview)
        write_preview(preview_path, preview_rgb, preview_inst, preview_labels)
    return SynthResult(out_dir, n_fruits, config.views, gt_path, transforms_path,
                       Path(bag) if bag is not None else None, preview_path,
                       int(np.count_nonzero(visible[:, 1:].any(axis=0))), time.perf_counter() - started)


def _recorded_config(config: SynthConfig) -> dict:
    """The config as transforms.json records it; without a depth camera its depth_* settings are left out, and with
    exact masks its mask_* settings, so such a dataset is byte-identical to one written before these existed."""
    mapping = config_to_mapping(config)
    if config.depth == 'none':
        mapping = {k: v for k, v in mapping.items() if not k.startswith('depth')}
    if not config.degrades_masks:
        mapping = {k: v for k, v in mapping.items() if not k.startswith('mask_')}
    return mapping


def _noisy_poses(poses: list[np.ndarray] | np.ndarray, config: SynthConfig) -> list[np.ndarray]:
    """The poses as a robot would record them: the +y side's drift (``pass_offset_*``), then ``pose_noise_m`` /
    ``pose_noise_deg`` Gaussian errors (their own random stream, so noise-free datasets stay byte-identical)."""
    poses = _pass_offset([np.asarray(T, dtype=np.float64) for T in poses], config)
    if config.pose_noise_m == 0 and config.pose_noise_deg == 0:
        return poses
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x9D]))
    out = []
    for T in poses:
        noisy = T.copy()
        rotvec = np.radians(config.pose_noise_deg) * rng.normal(size=3)
        noisy[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(rotvec).as_matrix()
        noisy[:3, 3] = T[:3, 3] + config.pose_noise_m * rng.normal(size=3)
        out.append(noisy)
    return out


def _pass_offset(poses: list[np.ndarray], config: SynthConfig) -> list[np.ndarray]:
    """``poses`` with those on the +y side moved rigidly by ``pass_offset_m`` along x and turned by
    ``pass_offset_deg`` about the vertical through their mean position."""
    stacked = np.stack(poses)
    back = stacked[:, 1, 3] > 0
    if (config.pass_offset_m == 0 and config.pass_offset_deg == 0) or not back.any():
        return poses
    centre = stacked[back, :3, 3].mean(axis=0)
    drift = np.eye(4)                                   # turn about the vertical through `centre`, then shift
    drift[:3, :3] = Rotation.from_euler('z', config.pass_offset_deg, degrees=True).as_matrix()
    drift[:3, 3] = centre - drift[:3, :3] @ centre + np.array([config.pass_offset_m, 0.0, 0.0])
    stacked[back] = drift @ stacked[back]
    return list(stacked)


def _sample_surface(depth: np.ndarray, rgb: np.ndarray, T_world_camera: np.ndarray, K: CameraIntrinsics, count: int,
                    bound_radius: float, rng: np.random.Generator, pixel_grid: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Back-project ``count`` random non-sky pixels of one view near the tree into world points + colours.

    ``pixel_grid``: [H * W, 2] undistorted normalised coordinates of the pixels of a distorted camera, else None.
    """
    v, u = np.nonzero(np.isfinite(depth))
    if len(v) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    pick = rng.choice(len(v), size=min(count * 2, len(v)), replace=False)
    pick.sort()
    v, u = v[pick], u[pick]
    z = depth[v, u].astype(np.float64)
    if pixel_grid is None:
        d_opt = np.stack([(u + 0.5 - K.cx) / K.fl_x, (v + 0.5 - K.cy) / K.fl_y, np.ones_like(z)], axis=1)
    else:
        d_opt = np.concatenate([pixel_grid[v * K.w + u], np.ones((len(z), 1))], axis=1)
    T_world_optical = T_world_camera @ T_OPENGL_OPTICAL
    points = T_world_optical[:3, 3] + (d_opt * z[:, None]) @ T_world_optical[:3, :3].T
    near = np.linalg.norm(points[:, :2], axis=1) < 1.5 * bound_radius
    points, colors = points[near][:count], rgb[v, u][near][:count]
    return points, colors
