"""Tracking-by-detection fruit counter, the accuracy benchmark's peer (issue #11): instance blobs tracked from frame
to frame with a pose-driven 3D motion model and mask-IoU / centroid association, one fruit per confirmed track.

Example::

    from fruitnerfpp_ros.core.tracking import TrackConfig, track_dataset, write_track_counts
    result = track_dataset('synth_apple', TrackConfig(max_age=8))
    write_track_counts('counts.json', result)
"""

from fruitnerfpp_ros.core.tracking.camera import PinholeView, triangulate
from fruitnerfpp_ros.core.tracking.config import TrackConfig
from fruitnerfpp_ros.core.tracking.dataset_tracking import track_dataset, write_track_counts
from fruitnerfpp_ros.core.tracking.detections import FrameDetections, detect_blobs
from fruitnerfpp_ros.core.tracking.result import TrackCount, TrackedFruit
from fruitnerfpp_ros.core.tracking.tracker import FruitTracker

__all__ = ['TrackConfig', 'FruitTracker', 'TrackCount', 'TrackedFruit', 'FrameDetections', 'detect_blobs',
           'PinholeView', 'triangulate', 'track_dataset', 'write_track_counts']
