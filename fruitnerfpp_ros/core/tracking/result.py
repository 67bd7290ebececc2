"""The tracker's count: one fruit per confirmed track, written as the pipeline's ``counts.json``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fruitnerfpp_ros.core.config_io import config_to_mapping

__all__ = ['TrackedFruit', 'TrackCount', 'COUNTS_FORMAT_VERSION']

#: The ``counts.json`` format version (the same as ``core.pipeline.COUNTS_FORMAT_VERSION``, which this torch-free
#: module cannot import cheaply; a test keeps the two equal).
COUNTS_FORMAT_VERSION = 1


@dataclass(frozen=True)
class TrackedFruit:
    """One counted fruit: a track with at least ``min_hits`` detections.

    Attributes:
        id: fruit id, starting at 1, in order of first sighting.
        center: [3] the track's triangulated centre, metres, world frame.
        diameter_m: median over its detections of the blob size times depth over focal length, metres.
        n_detections: frames in which the track was matched to a blob.
        first_frame: index (in transforms.json) of the frame of its first detection.
        last_frame: index (in transforms.json) of the frame of its last detection.
    """

    id: int
    center: np.ndarray
    diameter_m: float
    n_detections: int
    first_frame: int
    last_frame: int

    def to_json(self) -> dict[str, Any]:
        return {'id': int(self.id), 'center': [float(v) for v in self.center], 'diameter': float(self.diameter_m),
                'n_detections': int(self.n_detections), 'first_frame': int(self.first_frame),
                'last_frame': int(self.last_frame)}


@dataclass(frozen=True)
class TrackCount:
    """The count of the tracking-by-detection baseline.

    Attributes:
        fruits: the counted tracks, ids 1..count.
        n_tracks: tracks started (counted or not).
        n_frames: frames processed.
        stats: figures for reports (seconds, detections, matches per stage, ...).
    """

    fruits: list[TrackedFruit]
    n_tracks: int
    n_frames: int
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.fruits)

    def centers(self) -> np.ndarray:
        """[count, 3] fruit centres (m)."""
        return np.array([f.center for f in self.fruits], np.float64).reshape(-1, 3)

    def to_json(self, config: Any = None, *, source: str = '') -> dict[str, Any]:
        """The ``counts.json`` document (as ``core.pipeline.counts_to_json`` writes it, with the tracker's config
        under ``track_config``): ``fruitnerfpp eval`` scores it unchanged."""
        return {'version': COUNTS_FORMAT_VERSION, 'total': self.count, 'fruits': [f.to_json() for f in self.fruits],
                'source': source, 'method': 'tracking',
                'track_config': config_to_mapping(config) if config is not None else None,
                'stats': {'n_tracks': self.n_tracks, 'n_frames': self.n_frames, **self.stats}}
