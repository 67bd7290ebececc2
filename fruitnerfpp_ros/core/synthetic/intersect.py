"""The tree's primitives as torch tensors on one device, and exact ray / primitive intersections.

Each ``hit_*`` method takes one ray per pair: origin ``o`` [3] (or [P, 3]), direction ``d`` [P, 3] and the
primitive index ``idx`` [P]; it returns the ray parameter t [P] of the first hit in front of the origin (in
units of ``d``), inf for a miss. Primitive kinds in a fixed order: 0 ellipsoids, 1 leaves, 2 cylinders.
"""

from __future__ import annotations

import numpy as np
import torch

from fruitnerfpp_ros.core.synthetic.primitives import Scene

__all__ = ['SceneTensors', 'NEAR_M', 'KINDS']

#: Hits closer than this to the ray origin are ignored, metres.
NEAR_M = 1e-3
#: Primitive kinds, in the order of their index ranges.
KINDS = ('ellipsoid', 'leaf', 'cylinder')


class SceneTensors:
    """Packed float32 tensors of a :class:`Scene`'s ellipsoids, leaves and cylinders on ``device``.

    Attributes:
        counts: number of primitives of each kind (ellipsoids, leaves, cylinders).
        offsets: first global primitive index of each kind (z-buffer keys use global indices).
    """

    def __init__(self, scene: Scene, device: torch.device) -> None:
        self.device = device

        def t(a: np.ndarray, dtype: torch.dtype = torch.float32) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)

        e, lv, c = scene.ellipsoids, scene.leaves, scene.cylinders
        self.e_center, self.e_rot, self.e_radii = t(e.center), t(e.rotation), t(e.radii)
        self.e_albedo, self.e_blush, self.e_amount = t(e.albedo), t(e.blush), t(e.blush_amount)
        self.e_instance = t(e.instance, torch.int64)
        self.l_center, self.l_u, self.l_v, self.l_n = t(lv.center), t(lv.axis_u), t(lv.axis_v), t(lv.normal)
        self.l_half, self.l_albedo = t(lv.half_size), t(lv.albedo)
        u_a, v_b = lv.axis_u / lv.half_size[:, :1], lv.axis_v / lv.half_size[:, 1:]
        self.l_plane = t(np.concatenate([lv.normal, np.sum(lv.normal * lv.center, 1, keepdims=True),
                                         u_a, np.sum(u_a * lv.center, 1, keepdims=True),
                                         v_b, np.sum(v_b * lv.center, 1, keepdims=True)], axis=1).reshape(-1, 12))
        self.c_p0, self.c_p1, self.c_r, self.c_albedo = t(c.p0), t(c.p1), t(c.radius), t(c.albedo)
        self.counts = (len(e.center), len(lv.center), len(c.p0))
        self.offsets = (0, self.counts[0], self.counts[0] + self.counts[1])

    @property
    def total(self) -> int:
        """Number of primitives of all kinds."""
        return sum(self.counts)

    def hit(self, kind: int, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        """First-hit t [P] of rays (o, d) with primitives ``idx`` of ``kind`` (0 ellipsoid, 1 leaf, 2 cylinder)."""
        return (self.hit_ellipsoid, self.hit_leaf, self.hit_cylinder)[kind](o, d, idx)

    def hit_ellipsoid(self, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        R, r = self.e_rot[idx], self.e_radii[idx]
        ol = torch.einsum('pji,pj->pi', R, o - self.e_center[idx]) / r
        dl = torch.einsum('pji,pj->pi', R, d) / r
        a = (dl * dl).sum(1)
        b = (ol * dl).sum(1)
        c = (ol * ol).sum(1) - 1.0
        disc = b * b - a * c
        t = (-b - torch.sqrt(torch.clamp(disc, min=0.0))) / a
        return torch.where((disc >= 0) & (t > NEAR_M), t, torch.inf)

    def hit_leaf(self, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        # One gather of the packed leaf plane [n, n.c, u/a, u.c/a, v/b, v.c/b] (12 floats per leaf).
        q = self.l_plane[idx]
        n = q[:, 0:3]
        denom = (d * n).sum(1)
        t = (q[:, 3] - (o * n).sum(-1)) / torch.where(denom.abs() < 1e-12, torch.full_like(denom, 1e-12), denom)
        p = o + t[:, None] * d
        x = (p * q[:, 4:7]).sum(1) - q[:, 7]
        y = (p * q[:, 8:11]).sum(1) - q[:, 11]
        inside = (x.abs() <= 1.0) & (y.abs() <= 1.0 - x * x)
        return torch.where(inside & (t > NEAR_M), t, torch.inf)

    def hit_cylinder(self, o: torch.Tensor, d: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        p0, p1, r = self.c_p0[idx], self.c_p1[idx], self.c_r[idx]
        axis = p1 - p0
        length = torch.linalg.norm(axis, dim=1)
        axis = axis / length[:, None]
        oc = o - p0
        d_perp = d - (d * axis).sum(1, keepdim=True) * axis
        oc_perp = oc - (oc * axis).sum(1, keepdim=True) * axis
        a = (d_perp * d_perp).sum(1)
        b = (d_perp * oc_perp).sum(1)
        c = (oc_perp * oc_perp).sum(1) - r * r
        disc = b * b - a * c
        t = (-b - torch.sqrt(torch.clamp(disc, min=0.0))) / torch.clamp(a, min=1e-20)
        s = ((oc + t[:, None] * d) * axis).sum(1)
        ok = (disc >= 0) & (a > 1e-20) & (t > NEAR_M) & (s >= 0) & (s <= length)
        return torch.where(ok, t, torch.inf)
