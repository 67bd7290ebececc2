"""Lighting, sky, ground and colour variation between scenes (``SynthConfig.appearance_variation``).

With ``appearance_variation = 0`` (the default) every scene is lit and coloured exactly as before this option
existed: :data:`DEFAULT_APPEARANCE` and unchanged primitive colours, so default datasets stay byte-identical.
With ``v > 0`` each seed draws, from its own random stream (the tree and the cameras are unchanged), a sun
direction and strength, an ambient level, a colour temperature (white balance), a sky tint, ground colours and
texture, a leaf and bark tint, and a colour / ripeness change per fruit; every change is scaled by ``v`` (1 = the
full range given below, e.g. sun elevation 25-70 degrees, colour temperature 3500-8500 K).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fruitnerfpp_ros.core.synthetic.primitives import Scene

__all__ = ['Appearance', 'DEFAULT_APPEARANCE', 'sample_appearance', 'vary_scene_colours', 'white_balance_rgb']

_SUN = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])
#: Colour temperature of the default (unvaried) light, kelvin.
_NEUTRAL_K = 5500.0


@dataclass(frozen=True)
class Appearance:
    """How one scene is lit and how its sky and ground look (colours linear 0..1).

    Attributes:
        sun_direction: unit vector towards the sun, world frame (z up).
        sun_strength: weight of the Lambertian sun term.
        ambient: weight of the ambient term (shade = ambient + sun_strength * cos).
        white_balance: RGB multipliers on the final colour (colour temperature of the light).
        sky_horizon_rgb / sky_zenith_rgb: sky gradient from the horizon to straight up.
        grass_rgb / soil_rgb: the two ground materials.
        ground_patch_per_m: spatial frequency of the grass / soil patches, 1/m.
        grass_threshold: noise level above which grass takes over (lower = more grass).
        ground_noise_seed: seed of the ground's value noise (the next seed is used for the fine grain).
    """

    sun_direction: tuple[float, float, float] = (float(_SUN[0]), float(_SUN[1]), float(_SUN[2]))
    sun_strength: float = 0.62
    ambient: float = 0.38
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    sky_horizon_rgb: tuple[float, float, float] = (0.80, 0.87, 0.95)
    sky_zenith_rgb: tuple[float, float, float] = (0.45, 0.62, 0.88)
    grass_rgb: tuple[float, float, float] = (0.30, 0.42, 0.16)
    soil_rgb: tuple[float, float, float] = (0.42, 0.34, 0.24)
    ground_patch_per_m: float = 3.0
    grass_threshold: float = 0.35
    ground_noise_seed: int = 11


DEFAULT_APPEARANCE = Appearance()


def _kelvin_rgb(kelvin: float) -> np.ndarray:
    """Approximate RGB (0..1) of a black body at ``kelvin`` (Tanner Helland's fit, 1000-40000 K)."""
    t = kelvin / 100.0
    r = 1.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592 / 255.0
    g = (99.4708025861 * np.log(t) - 161.1195681661) / 255.0 if t <= 66 \
        else 288.1221695283 * (t - 60) ** -0.0755148492 / 255.0
    b = 1.0 if t >= 66 else (0.0 if t <= 19 else (138.5177312231 * np.log(t - 10) - 305.0447927307) / 255.0)
    return np.clip(np.array([r, g, b], dtype=np.float64), 1e-3, 1.0)


def white_balance_rgb(kelvin: float) -> tuple[float, float, float]:
    """RGB multipliers (green = 1) of light at ``kelvin`` relative to the neutral 5500 K light."""
    rel = _kelvin_rgb(kelvin) / _kelvin_rgb(_NEUTRAL_K)
    rel = rel / rel[1]
    return float(rel[0]), float(rel[1]), float(rel[2])


def _stream(seed: int, tag: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, tag]))


def sample_appearance(seed: int, variation: float) -> Appearance:
    """The lighting of scene ``seed``: :data:`DEFAULT_APPEARANCE` when ``variation`` is 0, else drawn from a
    stream of its own with every change scaled by ``variation`` (0..1)."""
    if variation == 0:
        return DEFAULT_APPEARANCE
    v = float(variation)
    rng = _stream(seed, 0xA991)
    base = DEFAULT_APPEARANCE
    elevation = np.arcsin(_SUN[2]) + v * np.radians(rng.uniform(-30.0, 15.0))
    azimuth = np.arctan2(_SUN[1], _SUN[0]) + v * rng.uniform(-np.pi, np.pi)
    sun = (float(np.cos(elevation) * np.cos(azimuth)), float(np.cos(elevation) * np.sin(azimuth)),
           float(np.sin(elevation)))
    strength = base.sun_strength * (1.0 + v * rng.uniform(-0.35, 0.25))
    ambient = base.ambient * (1.0 + v * rng.uniform(-0.25, 0.35))
    kelvin = _NEUTRAL_K + v * rng.uniform(-2000.0, 3000.0)
    overcast = v * rng.uniform(0.0, 0.5)
    grey = np.array([0.78, 0.80, 0.82])

    def sky(rgb: tuple[float, float, float]) -> tuple[float, float, float]:
        mixed = (1.0 - overcast) * np.array(rgb) + overcast * grey
        return float(mixed[0]), float(mixed[1]), float(mixed[2])

    def tinted(rgb: tuple[float, float, float], spread: float) -> tuple[float, float, float]:
        out = np.clip(np.array(rgb) * (1.0 + v * rng.normal(scale=spread, size=3)), 0.02, 1.0)
        return float(out[0]), float(out[1]), float(out[2])

    return Appearance(
        sun_direction=sun, sun_strength=float(strength), ambient=float(ambient),
        white_balance=white_balance_rgb(kelvin),
        sky_horizon_rgb=sky(base.sky_horizon_rgb), sky_zenith_rgb=sky(base.sky_zenith_rgb),
        grass_rgb=tinted(base.grass_rgb, 0.15), soil_rgb=tinted(base.soil_rgb, 0.15),
        ground_patch_per_m=float(base.ground_patch_per_m * np.exp(v * rng.uniform(-0.7, 0.7))),
        grass_threshold=float(base.grass_threshold + v * rng.uniform(-0.25, 0.25)),
        ground_noise_seed=base.ground_noise_seed + 2 * int(rng.integers(1, 1000)))


def vary_scene_colours(scene: Scene, seed: int, variation: float) -> Scene:
    """``scene`` with varied colours: leaf tint (per scene and per leaf), bark tint, and per fruit a colour tint,
    a brightness and a blush (ripeness) change shared by all ellipsoids of that fruit. The geometry and the
    ground truth are unchanged; ``variation`` 0 returns ``scene`` itself."""
    if variation == 0:
        return scene
    v = float(variation)
    rng = _stream(seed, 0xC010)
    e, lv, c = scene.ellipsoids, scene.leaves, scene.cylinders
    n_fruits = len(scene.fruits)
    leaf_tint = 1.0 + v * rng.normal(scale=0.12, size=3)
    leaf_gain = 1.0 + v * rng.normal(scale=0.10, size=(len(lv.center), 1))
    bark_gain = 1.0 + v * rng.normal(scale=0.12, size=3)
    fruit_tint = 1.0 + v * rng.normal(scale=0.08, size=(n_fruits + 1, 3))
    fruit_gain = 1.0 + v * rng.normal(scale=0.12, size=(n_fruits + 1, 1))
    blush_shift = v * rng.normal(scale=0.2, size=n_fruits + 1)
    fruit = e.instance > 0
    gain = np.where(fruit[:, None], fruit_tint[e.instance] * fruit_gain[e.instance], bark_gain[None])
    ellipsoids = e._replace(albedo=np.clip(e.albedo * gain, 0.0, 1.0), blush=np.clip(e.blush * gain, 0.0, 1.0),
                            blush_amount=np.where(fruit, np.clip(e.blush_amount + blush_shift[e.instance], 0.0, 0.95),
                                                  e.blush_amount))
    leaves = lv._replace(albedo=np.clip(lv.albedo * leaf_tint * leaf_gain, 0.02, 1.0))
    cylinders = c._replace(albedo=np.clip(c.albedo * bark_gain, 0.0, 1.0))
    return scene._replace(ellipsoids=ellipsoids, leaves=leaves, cylinders=cylinders)
