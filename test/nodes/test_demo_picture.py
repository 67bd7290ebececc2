"""The instance-cloud picture written by `fruitnerfpp demo` (for the README)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from fruitnerfpp_ros.cli.demo import render_instance_cloud


def test_instance_cloud_picture_colours_each_fruit(tmp_path: Path) -> None:
    xyz = np.array([[0.0, 0.0, 0.0]] * 50 + [[1.0, 1.0, 1.0]] * 50 + [[0.5, 0.5, 0.5]] * 5)
    labels = np.array([1] * 50 + [2] * 50 + [0] * 5)
    image = cv2.imread(str(render_instance_cloud(xyz, labels, tmp_path / 'c.png', size=100)))
    assert image.shape == (100, 204, 3)
    front = image[:, :100].reshape(-1, 3)
    colours = {tuple(c) for c in front if not (c == 255).all() and not (c == 0).all()}
    assert len(colours) >= 3  # two fruit colours + grey noise (+ label text)
    assert (110, 110, 110) in colours
