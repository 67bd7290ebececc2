"""Contact sheet of a few rendered views: one row per view, RGB | instance ids | semantic mask."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.png_io import write_rgb_png

__all__ = ['colorize_instances', 'contact_sheet', 'write_preview', 'preview_view_indices']


def colorize_instances(ids: np.ndarray) -> np.ndarray:
    """[H, W] instance ids -> [H, W, 3] uint8 colours (a fixed hash palette; 0 = black)."""
    ids = ids.astype(np.int64)
    h = (ids * 2654435761) & 0xFFFFFFFF
    rgb = np.stack([(h >> 0) & 0xFF, (h >> 8) & 0xFF, (h >> 16) & 0xFF], axis=-1)
    rgb = 64 + (rgb * 191) // 255
    rgb[ids == 0] = 0
    return rgb.astype(np.uint8)


def preview_view_indices(n_views: int, rows: int = 3, *, two_passes: bool = False) -> list[int]:
    """View indices shown in the contact sheet: evenly spaced, or (``two_passes``, the row trajectory, whose passes
    start and end with the tree out of view) around the middle of the first pass and the middle of the second."""
    rows = min(rows, n_views)
    if two_passes and n_views >= 2:
        first = (n_views + 1) // 2
        middles = [first // 2, min(first - 1, first // 2 + max(1, first // 6)), first + (n_views - first) // 2]
        return sorted(set(middles))[:rows]
    return sorted({int(round(i * (n_views - 1) / max(rows - 1, 1))) for i in range(rows)})


def contact_sheet(rgbs: Sequence[np.ndarray], instances: Sequence[np.ndarray], labels: Sequence[str]) -> np.ndarray:
    """[rows*H, 3*W, 3] uint8 sheet, one row per view: RGB | instance | semantic, with a label on the RGB."""
    rows = []
    for rgb, inst, label in zip(rgbs, instances, labels):
        semantic = np.repeat(np.where(inst > 0, 255, 0).astype(np.uint8)[..., None], 3, axis=2)
        row = np.concatenate([rgb, colorize_instances(inst), semantic], axis=1)
        row = np.ascontiguousarray(row)
        scale = max(0.3, rgb.shape[0] / 400.0)
        cv2.putText(row, label, (3, int(14 * scale / 0.35)), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                    cv2.LINE_AA)
        rows.append(row)
    sheet = np.concatenate(rows, axis=0)
    sheet[:, rgbs[0].shape[1] - 1: rgbs[0].shape[1] + 1] = 255
    sheet[:, 2 * rgbs[0].shape[1] - 1: 2 * rgbs[0].shape[1] + 1] = 255
    return sheet


def write_preview(path: Path, rgbs: Sequence[np.ndarray], instances: Sequence[np.ndarray],
                  labels: Sequence[str]) -> None:
    """Write :func:`contact_sheet` as a PNG (parents created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_rgb_png(path, contact_sheet(rgbs, instances, labels))
