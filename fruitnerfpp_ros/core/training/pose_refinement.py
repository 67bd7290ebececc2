"""Per-view camera pose corrections learned with the fields (robot odometry is not exact).

Each training view gets a 6-vector: a rotation (axis times angle, radians, in the camera's own frame) and a
translation (metres, in the world frame). The corrections start at zero or where the pose start put them (the
alignment's, the pass registration's: core/training/pose_start.py), train with the geometry (stages 1 and 2)
through the photometric loss, and stay fixed in stage 3. The start is applied as given; of what training adds, the
mean translation over the trained views is removed (the gauge: moving every camera by the same offset would move
the whole reconstruction away from the world frame the ground truth and the outputs live in). Held-out views learn
nothing: they keep their start (the alignment's resection on the training views' tracks, the pass registration's
move; the recorded pose without either). At the end of stage 2 the run directory gets ``refined_poses.json``
(:func:`write_refined_poses`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.geometry import rotation_angle_deg

__all__ = ['PoseRefinement', 'rotation_from_axis_angle', 'write_refined_poses']


def rotation_from_axis_angle(rotvec: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N, 3, 3] of axis-angle vectors [N, 3] (Rodrigues; exact and differentiable at 0)."""
    theta2 = (rotvec * rotvec).sum(-1, keepdim=True)[..., None]                   # [N, 1, 1]
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(-1, 3, 3)
    small = theta2 < 1e-8
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)          # sin(t) / t
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / torch.where(small, 1.0, theta2))
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(K)
    return eye + a * K + b * (K @ K)


class PoseRefinement(nn.Module):
    """Learned corrections of the camera-to-world poses of ``trained`` views.

    Args:
        trained: [V] bool, the views whose poses are refined (the training views); the others keep ``initial``.
        initial: optional [V, 6] starting corrections (the pose start's), applied as given; zeros by default.
    """

    def __init__(self, trained: torch.Tensor, initial: np.ndarray | torch.Tensor | None = None) -> None:
        super().__init__()
        self.register_buffer('trained', torch.as_tensor(trained, dtype=torch.bool).clone())
        start = torch.zeros(len(self.trained), 6) if initial is None else torch.as_tensor(initial, dtype=torch.float32)
        self.register_buffer('start', start.clone())
        self.correction = nn.Parameter(start.clone())

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args, **kwargs) -> None:
        # a checkpoint from before the start was kept apart (session 39) put every correction under the gauge
        if prefix + 'start' not in state_dict and prefix + 'correction' in state_dict:
            state_dict[prefix + 'start'] = torch.zeros_like(state_dict[prefix + 'correction'])
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def forward(self, T_world_camera: torch.Tensor) -> torch.Tensor:
        """The corrected poses [V, 4, 4] of the recorded ones [V, 4, 4]."""
        mask = self.trained[:, None].to(T_world_camera.dtype)
        start = self.start.to(T_world_camera.dtype)
        correction = self.correction.to(T_world_camera.dtype) * mask + start * (1.0 - mask)
        learned = (correction[:, 3:] - start[:, 3:]) * mask
        shift = correction[:, 3:] - mask * learned.sum(0) / mask.sum().clamp_min(1.0)
        out = T_world_camera.clone()
        out[:, :3, :3] = T_world_camera[:, :3, :3] @ rotation_from_axis_angle(correction[:, :3])
        out[:, :3, 3] = T_world_camera[:, :3, 3] + shift
        return out


def write_refined_poses(path: Path, recorded: torch.Tensor, refined: torch.Tensor, file_paths: list[str],
                        trained: torch.Tensor) -> Path:
    """Write the recorded and refined poses of every view as JSON (what the odometry got wrong, per image).

    Args:
        path: output file.
        recorded, refined: [V, 4, 4] camera-to-world poses, OpenGL camera axes (as transforms.json), metres.
        file_paths: the V images, as transforms.json names them.
        trained: [V] bool, the views that were refined (held-out views keep their start).
    """
    recorded = recorded.detach().double().cpu().numpy()
    refined = refined.detach().double().cpu().numpy()
    angles = rotation_angle_deg(recorded[:, :3, :3], refined[:, :3, :3])
    shifts = np.linalg.norm(refined[:, :3, 3] - recorded[:, :3, 3], axis=-1)
    views = [{'index': i, 'file_path': name, 'refined': bool(trained[i]), 'rotation_deg': round(float(a), 4),
              'translation_m': round(float(s), 5), 'transform_matrix': refined[i].tolist()}
             for i, (name, a, s) in enumerate(zip(file_paths, angles, shifts))]
    report = {'version': 1, 'frame': 'camera-to-world, OpenGL camera axes, metres (as transforms.json)',
              'max_rotation_deg': round(float(angles.max()), 4) if len(views) else 0.0,
              'max_translation_m': round(float(shifts.max()), 5) if len(views) else 0.0, 'views': views}
    return atomic_write_text(path, json.dumps(report, indent=1))
