"""Error hierarchy of fruitnerfpp_ros.

Every error the package raises on bad input derives from :class:`FruitNerfError`, so the CLI can print one clear
line and nodes can log and keep spinning. Messages name the offending file, topic or parameter.
"""

__all__ = [
    'FruitNerfError',
    'ConfigError',
    'DatasetError',
    'SynthError',
    'TrainingError',
    'CheckpointError',
    'ExportError',
    'ClusteringError',
    'EvaluationError',
    'BagError',
    'ConversionError',
    'SegmentationError',
    'OrchardError',
]


class FruitNerfError(Exception):
    """Base of every error raised by fruitnerfpp_ros on bad input or state."""


class ConfigError(FruitNerfError):
    """A configuration file or parameter is malformed, unknown or out of range."""


class DatasetError(FruitNerfError):
    """A transforms.json dataset (images, masks, poses) is missing, malformed or inconsistent."""


class SynthError(FruitNerfError):
    """The synthetic orchard generator was given impossible settings."""


class TrainingError(FruitNerfError):
    """Training cannot start or continue."""


class CheckpointError(TrainingError):
    """A checkpoint or run directory is missing, corrupt or incompatible."""


class ExportError(FruitNerfError):
    """The fruit point cloud could not be exported."""


class ClusteringError(FruitNerfError):
    """Clustering input is malformed."""


class EvaluationError(FruitNerfError):
    """Evaluation input (counts, ground truth) is missing or malformed."""


class BagError(FruitNerfError):
    """A rosbag2 recording is missing, corrupt or lacks required topics."""


class ConversionError(FruitNerfError):
    """A ROS message cannot be converted (unknown encoding, wrong size, NaN pose...)."""


class SegmentationError(FruitNerfError):
    """Instance masks cannot be computed: a segmenter's package or checkpoint is missing, or its output is unusable."""


class OrchardError(FruitNerfError):
    """A row cannot be cut, counted per tree or georeferenced: no row axis, a bad planting map or datum, no GNSS."""
