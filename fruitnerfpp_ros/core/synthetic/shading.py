"""Shading of the rendered tree: Lambertian sun + ambient, a crown-depth darkening, a sky gradient, a textured
ground with the crown's soft shadow, and procedural value-noise textures anchored to the world (multi-view
consistent). Lighting and sky / ground colours come from an :class:`Appearance`.
"""

from __future__ import annotations

import torch

from fruitnerfpp_ros.core.synthetic.appearance import Appearance
from fruitnerfpp_ros.core.synthetic.intersect import SceneTensors

__all__ = ['Shader', 'value_noise']


def _hash(ix: torch.Tensor, seed: int) -> torch.Tensor:
    """Integer hash of int64 lattice coordinates [..., D] to floats in [0, 1) (identical on CPU and CUDA)."""
    primes = (73856093, 19349663, 83492791)
    h = torch.full(ix.shape[:-1], seed * 2654435761 % (1 << 32), dtype=torch.int64, device=ix.device)
    for k in range(ix.shape[-1]):
        h = (h ^ ((ix[..., k] * primes[k]) & 0xFFFFFFFF)) & 0xFFFFFFFF
        h = ((h ^ (h >> 15)) * 0x2C1B3C6D) & 0xFFFFFFFF
        h = ((h ^ (h >> 12)) * 0x297A2D39) & 0xFFFFFFFF
        h = h ^ (h >> 15)
    return (h & 0xFFFFFF).to(torch.float32) / float(1 << 24)


def value_noise(x: torch.Tensor, seed: int = 0, octaves: int = 1) -> torch.Tensor:
    """Smooth value noise in [0, 1] at points ``x`` [P, D] (D = 2 or 3), summed over ``octaves`` (fBm)."""
    total = torch.zeros(x.shape[0], dtype=torch.float32, device=x.device)
    weight_sum = 0.0
    for octave in range(octaves):
        p = x * (2.0 ** octave)
        base = torch.floor(p)
        f = p - base
        f = f * f * (3.0 - 2.0 * f)
        ib = base.to(torch.int64)
        value = torch.zeros_like(total)
        d = x.shape[1]
        for corner in range(1 << d):
            offset = torch.tensor([(corner >> k) & 1 for k in range(d)], device=x.device)
            w = torch.prod(torch.where(offset.bool(), f, 1.0 - f), dim=1)
            value = value + w * _hash(ib + offset, seed + octave)
        amp = 0.5 ** octave
        total = total + amp * value
        weight_sum += amp
    return total / weight_sum


class Shader:
    """Colours of the z-buffer's winners.

    Args:
        tensors: the scene's primitives.
        crown_center / crown_radii: [3] crown ellipsoid (metres), for the crown darkening and the ground shadow.
        appearance: lighting, sky and ground.
    """

    def __init__(self, tensors: SceneTensors, crown_center: torch.Tensor, crown_radii: torch.Tensor,
                 appearance: Appearance) -> None:
        self.s = tensors
        self.device = tensors.device
        self.crown_center, self.crown_radii = crown_center, crown_radii
        self.look = appearance
        self.sun = torch.tensor(appearance.sun_direction, dtype=torch.float32, device=self.device)
        self.ground_index = tensors.total
        self.sky_index = tensors.total + 1

    def _rgb(self, values: tuple[float, float, float]) -> torch.Tensor:
        return torch.tensor(values, device=self.device)

    def shade(self, winner: torch.Tensor, origin: torch.Tensor, dirs: torch.Tensor, t_ground: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(rgb [P, 3] uint8, instance [P] int32, depth [P] float32 along ``dirs``, inf = sky) of the pixels
        whose z-buffer winner is ``winner`` [P] (global primitive index, ground_index or sky_index)."""
        dev, look = self.device, self.look
        n_pix = len(winner)
        rgb = torch.zeros((n_pix, 3), dtype=torch.float32, device=dev)
        depth = torch.full((n_pix,), torch.inf, dtype=torch.float32, device=dev)
        instance = torch.zeros(n_pix, dtype=torch.int64, device=dev)
        # Sky: a gradient with the ray's elevation.
        sky = winner == self.sky_index
        if bool(sky.any()):
            elev = torch.clamp(dirs[sky, 2] / torch.linalg.norm(dirs[sky], dim=1), 0.0, 1.0)[:, None]
            rgb[sky] = (1 - elev) * self._rgb(look.sky_horizon_rgb) + elev * self._rgb(look.sky_zenith_rgb)
        ground = winner == self.ground_index
        if bool(ground.any()):
            t = t_ground[ground]
            rgb[ground] = self._ground(origin + t[:, None] * dirs[ground])
            depth[ground] = t
        for kind in range(3):
            lo = self.s.offsets[kind]
            mask = (winner >= lo) & (winner < lo + self.s.counts[kind])
            if not bool(mask.any()):
                continue
            idx = winner[mask] - lo
            d = dirs[mask]
            t = self.s.hit(kind, origin, d, idx)
            p = origin + t[:, None] * d
            depth[mask] = t
            if kind == 0:
                albedo, normal, inst = self._ellipsoid_surface(p, idx)
                instance[mask] = inst
            elif kind == 1:
                albedo, normal = self._leaf_surface(p, idx)
            else:
                albedo, normal = self._cylinder_surface(p, idx)
            # Face the camera (two-sided leaves), Lambert + ambient, darker deep inside the crown.
            normal = torch.where(((normal * d).sum(1, keepdim=True) > 0), -normal, normal)
            lambert = torch.clamp((normal * self.sun).sum(1), min=0.0)
            rel = (p - self.crown_center) / self.crown_radii
            radial = torch.linalg.norm(rel, dim=1)
            ao = torch.clamp(0.45 + 0.55 * radial, 0.45, 1.0)
            rgb[mask] = albedo * ((look.ambient + look.sun_strength * lambert) * ao)[:, None]
        if look.white_balance != (1.0, 1.0, 1.0):
            rgb = rgb * self._rgb(look.white_balance)
        rgb8 = torch.clamp(rgb * 255.0 + 0.5, 0.0, 255.0).to(torch.uint8)
        return rgb8, instance.to(torch.int32), depth

    def _ground(self, p: torch.Tensor) -> torch.Tensor:
        """Grass / soil texture at ground points [P, 3], darker in the crown's shadow."""
        look = self.look
        xy = p[:, :2]
        n1 = value_noise(xy * look.ground_patch_per_m, seed=look.ground_noise_seed, octaves=3)
        n2 = value_noise(xy * 40.0, seed=look.ground_noise_seed + 1, octaves=2)
        mix = torch.clamp((n1 - look.grass_threshold) * 2.5, 0.0, 1.0)[:, None]
        albedo = (mix * self._rgb(look.grass_rgb) + (1 - mix) * self._rgb(look.soil_rgb)) * (0.75 + 0.5 * n2)[:, None]
        shadow_center = self.crown_center[:2] - self.sun[:2] / self.sun[2] * self.crown_center[2]
        r2 = ((xy - shadow_center) ** 2).sum(1) / (self.crown_radii[0] ** 2)
        shade = look.ambient + look.sun_strength * self.sun[2] * (1.0 - 0.6 * torch.exp(-r2 * r2))
        return albedo * shade[:, None]

    def _ellipsoid_surface(self, p: torch.Tensor, idx: torch.Tensor
                           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        s = self.s
        R, r = s.e_rot[idx], s.e_radii[idx]
        local = torch.einsum('pji,pj->pi', R, p - s.e_center[idx])
        normal = torch.einsum('pij,pj->pi', R, local / (r * r))
        normal = normal / torch.linalg.norm(normal, dim=1, keepdim=True)
        unit = local / r
        blotch = value_noise(unit * 1.6 + idx[:, None].to(torch.float32) * 7.31, seed=21, octaves=2)
        amount = s.e_amount[idx]
        blend = torch.clamp((blotch - (1.0 - amount)) * 4.0 + amount * 0.3, 0.0, 1.0)[:, None]
        fine = value_noise(p * 180.0, seed=22)[:, None]
        albedo = ((1 - blend) * s.e_albedo[idx] + blend * s.e_blush[idx]) * (0.92 + 0.16 * fine)
        inst = s.e_instance[idx]
        bark = inst == 0
        if bool(bark.any()):
            albedo[bark] = s.e_albedo[idx[bark]] * (0.7 + 0.6 * value_noise(p[bark] * 60.0, seed=31))[:, None]
        return albedo, normal, inst

    def _leaf_surface(self, p: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.s
        rel = p - s.l_center[idx]
        half = s.l_half[idx]
        x = (rel * s.l_u[idx]).sum(1) / half[:, 0]
        y = (rel * s.l_v[idx]).sum(1) / half[:, 1]
        edge = torch.clamp(1.0 - x * x, min=1e-3)
        vein = torch.exp(-(y / edge / 0.08) ** 2)   # midrib
        side = 0.9 + 0.1 * torch.cos(18.0 * (x + 0.5 * y.abs() / edge))  # side veins
        tone = 0.85 + 0.3 * value_noise(p * 90.0, seed=41)
        albedo = s.l_albedo[idx] * (tone * side * (1.0 - 0.25 * vein) + 0.0)[:, None] \
            + 0.15 * vein[:, None] * torch.tensor([0.6, 0.7, 0.3], device=self.device)
        return albedo, s.l_n[idx]

    def _cylinder_surface(self, p: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.s
        p0, p1 = s.c_p0[idx], s.c_p1[idx]
        axis = p1 - p0
        axis = axis / torch.linalg.norm(axis, dim=1, keepdim=True)
        rel = p - p0
        t = (rel * axis).sum(1, keepdim=True)
        radial = rel - t * axis
        normal = radial / torch.clamp(torch.linalg.norm(radial, dim=1, keepdim=True), min=1e-12)
        # Bark: noise stretched along the axis (world-anchored, so consistent across views).
        stretched = p * 70.0 - 55.0 * t * axis
        albedo = s.c_albedo[idx] * (0.65 + 0.7 * value_noise(stretched, seed=51, octaves=2))[:, None]
        return albedo, normal
