"""PNG writers for datasets: RGB images, 16-bit instance-id masks, 8-bit fruit masks (one copy for every writer).

Encoded in memory with OpenCV at a fixed compression level (the same array gives byte-identical files) and written
atomically (temporary file + rename) with Python's own file I/O, so an interrupted writer never leaves half a PNG
and a full disk is an error (``cv2.imwrite`` reports a file the disk cut short as written).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_bytes
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['write_rgb_png', 'write_uint16_png', 'write_mask_png']

_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]


def _imwrite(path: str | Path, image: np.ndarray) -> None:
    path = Path(path)
    ok, encoded = cv2.imencode('.png', image, _PNG_PARAMS)
    if not ok:
        raise DatasetError(f'cannot encode image {path} ({image.shape}, {image.dtype})')
    try:
        atomic_write_bytes(path, encoded.tobytes())
    except OSError as err:
        raise DatasetError(f'cannot write image {path}: {err}') from err


def write_rgb_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write an RGB [H, W, 3] uint8 image as PNG.

    Raises:
        DatasetError: the file cannot be written.
    """
    _imwrite(path, np.ascontiguousarray(rgb[..., ::-1]))


def write_uint16_png(path: str | Path, ids: np.ndarray) -> None:
    """Write [H, W] ids (0 = background) as a 16-bit single-channel PNG.

    Raises:
        DatasetError: the file cannot be written.
    """
    _imwrite(path, np.asarray(ids).astype(np.uint16))


def write_mask_png(path: str | Path, mask: np.ndarray) -> None:
    """Write a boolean [H, W] mask as an 8-bit PNG (255 = true, 0 = false).

    Raises:
        DatasetError: the file cannot be written.
    """
    _imwrite(path, np.where(mask, 255, 0).astype(np.uint8))
