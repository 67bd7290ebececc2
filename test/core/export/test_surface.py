"""Surface export against an exact sphere field over the stand-in scene: fruit surfaces in, fog and floaters out."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.export.surface import export_surface_cloud, merge_on_voxels
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings
from test.core.export.sphere_nerf import SphereNeRF, full_grid
from test.core.training.stand_in_scene import make_sphere_scene

SETTINGS = RenderSettings(step=0.01, near=0.05)
FRUIT_D = 0.16  # the stand-in fruits are spheres of 7-9 cm radius


@pytest.fixture(scope='module')
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sphere_scene(tmp_path_factory.mktemp('spheres'), views=24, size=64, fruits=6)


def _export(scene: Path, field: SphereNeRF, **config: object) -> tuple:
    dataset = load_dataset(scene, eval_every=0)
    return export_surface_cloud(field, full_grid(), SETTINGS, dataset, dataset.T_world_camera, FRUIT_D,
                                ExportConfig(**config))


def _surface_gap(xyz: np.ndarray, scene: Path) -> np.ndarray:
    spheres = np.load(scene / 'spheres.npz')
    fruit = spheres['is_fruit']
    gap = np.abs(np.linalg.norm(xyz[:, None] - spheres['centres'][fruit][None], axis=-1) - spheres['radii'][fruit])
    return gap.min(axis=1)


def test_points_lie_on_the_fruit_surfaces_and_count_as_the_fruits(scene: Path) -> None:
    cloud, report = _export(scene, SphereNeRF(scene))
    # 64 px views 3.2 m away: a pixel is ~4.6 cm on the fruit, wider than d / 8 = 2 cm: the voxel follows the pixel
    assert report.n_kept == len(cloud) > 0 and 0.035 < report.voxel_size_m < 0.06
    assert np.all(_surface_gap(cloud.xyz, scene) < 0.6 * report.voxel_size_m + SETTINGS.step)
    spheres = np.load(scene / 'spheres.npz')
    fruit, leaf = spheres['is_fruit'], ~spheres['is_fruit']
    # a fruit sphere wholly inside a leaf sphere is hidden from every view
    depth_in_leaf = (spheres['radii'][leaf][None] - np.linalg.norm(
        spheres['centres'][fruit][:, None] - spheres['centres'][leaf][None], axis=-1)).max(axis=1)
    visible = spheres['centres'][fruit][depth_in_leaf < spheres['radii'][fruit]]
    assert len(visible) >= 4
    result = count_fruits(dataclasses.replace(cloud, fruit_diameter_m=FRUIT_D), ClusterConfig(n_jobs=1))
    assert result.count == len(visible)
    found = np.linalg.norm(result.centers()[:, None] - visible[None], axis=-1).min(axis=0)
    # the points moved along their viewing directions put each centre within a quarter radius of the fruit's
    # (the caps' own medians: up to 0.042 m) and the diameters within 15 % (from the caps' medians: up to +13 %)
    assert np.all(found < 0.03)
    nearest = np.linalg.norm(result.centers()[:, None] - spheres['centres'][fruit][None], axis=-1).argmin(axis=1)
    ratio = np.array([f.diameter_m for f in result.fruits]) / (2 * spheres['radii'][fruit][nearest])
    assert np.all((ratio > 0.85) & (ratio < 1.1))


def test_each_point_knows_the_direction_it_was_seen_from(scene: Path) -> None:
    """The cloud's view_dir: the mean direction of the rays that gave a point, pointing from the camera into the
    fruit (from the surface towards the centre); clustering moves the points along it to the fruit's centre."""
    cloud, _ = _export(scene, SphereNeRF(scene))
    assert cloud.view_dir is not None and cloud.view_dir.shape == cloud.xyz.shape
    length = np.linalg.norm(cloud.view_dir, axis=1)
    assert np.all((length > 0.3) & (length <= 1.0 + 1e-5))
    spheres = np.load(scene / 'spheres.npz')
    centres = spheres['centres'][spheres['is_fruit']]
    inward = centres[np.linalg.norm(cloud.xyz[:, None] - centres[None], axis=-1).argmin(1)] - cloud.xyz
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    cosine = np.einsum('ij,ij->i', inward, cloud.view_dir / length[:, None])
    assert np.mean(cosine > 0) > 0.95 and np.median(cosine) > 0.6   # every ray that meets a sphere enters it


def test_a_semi_transparent_fruit_gives_no_point(scene: Path) -> None:
    """Fruit 0 rendered as haze (2/m over its 16 cm: opacity ~0.3) is fog, however fruit-like its semantics."""
    centre = np.load(scene / 'fruit_centres.npy')[0]
    field = SphereNeRF(scene, faded={0: 2.0})
    near = lambda cloud: int((np.linalg.norm(cloud.xyz - centre, axis=1) < 0.1).sum())  # noqa: E731
    unfiltered, _ = _export(scene, field, min_opacity=0.0)
    filtered, report = _export(scene, field)
    assert near(unfiltered) > 0 and near(filtered) == 0
    assert report.n_opaque < report.n_rays
    assert near(_export(scene, SphereNeRF(scene))[0]) > 0  # the opaque fruit 0 is exported


def test_a_fruit_behind_foliage_is_exported_on_the_fruit(scene: Path) -> None:
    """Fruit 0 wrapped in a haze of foliage (15/m over >= 12 cm in front of it: opacity >= 0.83 before any fruit
    ray reaches it, as a briefly trained field leaves leaves and gaps): every fruit ray of fruit 0 ends in the haze,
    which is not fruit, so the surface alone has nothing there; the fruit behind it is found, on the fruit, and
    counted, and the haze gives no point."""
    spheres = np.load(scene / 'spheres.npz')
    centre, radius = spheres['centres'][0], spheres['radii'][0]
    field = SphereNeRF(scene, veil=(centre, 0.2, 15.0))
    near = lambda cloud: int((np.linalg.norm(cloud.xyz - centre, axis=1) < 0.1).sum())  # noqa: E731
    surface_only, report_off = _export(scene, field, behind_foliage='none')
    assert near(surface_only) == 0 and report_off.n_behind == 0
    cloud, report = _export(scene, field)        # the default: behind foliage, along the rays with no surface point
    assert report.n_behind > 0 and near(cloud) >= 5
    at = cloud.xyz[np.linalg.norm(cloud.xyz - centre, axis=1) < 0.2]   # also what the haze around it could give
    assert np.all(np.linalg.norm(at - centre, axis=1) <= radius + report.voxel_size_m)   # on or in the fruit
    counted = count_fruits(dataclasses.replace(cloud, fruit_diameter_m=FRUIT_D), ClusterConfig(n_jobs=1))
    assert np.linalg.norm(counted.centers() - centre, axis=1).min() < 0.09
    assert count_fruits(dataclasses.replace(surface_only, fruit_diameter_m=FRUIT_D),
                        ClusterConfig(n_jobs=1)).count == counted.count - 1
    everywhere, report_all = _export(scene, field, behind_foliage='all')   # every fruit ray followed, not only
    assert report_all.n_behind > report.n_behind and near(everywhere) >= near(cloud)  # the ones with no surface


def test_a_floater_seen_by_one_view_is_not_a_fruit(scene: Path) -> None:
    """A fruit-labelled floater in front of a fruit of view 0 (inside the box) catches that view's fruit rays; the
    other views' masks disown it."""
    import cv2
    dataset = load_dataset(scene, eval_every=0)
    ids = cv2.imread(str(scene / 'instances' / '0000.png'), cv2.IMREAD_UNCHANGED)
    biggest = np.bincount(ids[ids > 0]).argmax()
    rows, cols = np.nonzero(ids == biggest)
    T, K = dataset.T_world_camera[0].numpy(), dataset.intrinsics[0].numpy()
    d_cam = np.array([(cols.mean() + 0.5 - K[2]) / K[0], -(rows.mean() + 0.5 - K[3]) / K[1], -1.0])
    direction = T[:3, :3] @ d_cam / np.linalg.norm(d_cam)
    floater = T[:3, 3] + 2.2 * direction                  # 2.2 m along view 0's ray to its biggest fruit
    spheres = dict(np.load(scene / 'spheres.npz'))
    ghost = scene.parent / 'ghost'
    ghost.mkdir(exist_ok=True)
    np.savez(ghost / 'spheres.npz', centres=np.vstack([spheres['centres'], floater]),
             radii=np.append(spheres['radii'], 0.06), is_fruit=np.append(spheres['is_fruit'], True))
    field = SphereNeRF(ghost)
    near_floater = lambda cloud: int((np.linalg.norm(cloud.xyz - floater, axis=1) < 0.08).sum())  # noqa: E731
    unfiltered, _ = _export(scene, field, min_mask_agreement=0.0, min_views=1)
    filtered, report = _export(scene, field)
    assert near_floater(unfiltered) > 0
    assert near_floater(filtered) == 0
    assert report.n_kept < report.n_multi_view or report.n_multi_view < report.n_voxels


def test_merge_counts_distinct_views_per_voxel() -> None:
    xyz = torch.tensor([[0.001, 0.001, 0.001], [0.002, 0.002, 0.002], [0.003, 0.001, 0.002], [0.5, 0.5, 0.5]])
    view = torch.tensor([3, 3, 7, 1])
    emb = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    mean, values, n_views = merge_on_voxels(xyz, view, {'emb': emb}, voxel=0.01)
    order = torch.argsort(mean[:, 0])
    assert n_views[order].tolist() == [2, 1]
    assert torch.allclose(values['emb'][order][0], torch.tensor([2 / 3, 1 / 3]))


def test_an_empty_export_says_why(scene: Path) -> None:
    _, report = _export(scene, SphereNeRF(scene, density=0.5))  # the field stays transparent
    assert report.n_kept == 0 and 'no fruit ray became opaque' in report.explain()
