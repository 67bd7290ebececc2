"""What ``fruitnerfpp orchard`` counts: a transforms.json dataset as it is, or a rosbag2 collected into
``RUN/keyframes`` through the node's keyframe collector (the same path as ``fruitnerfpp replay``), with the GNSS
fixes of ``gnss.json`` beside the dataset or of the bag's ``gnss_topic``."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fruitnerfpp_ros.errors import BagError

__all__ = ['RowSource', 'prepare_source']

_COLLECTED = 'collection.json'


class RowSource(NamedTuple):
    """The row's keyframes and GNSS.

    Attributes:
        dataset_dir: transforms.json dataset (keyframes in drive order).
        fixes: GNSS fixes (None: none recorded).
        antenna: the antenna in the camera optical frame from gnss.json (None: not given there).
        n_keyframes: keyframes in the dataset.
    """

    dataset_dir: Path
    fixes: list[Any] | None
    antenna: np.ndarray | None
    n_keyframes: int


def prepare_source(source: Path, out: Path, settings: Any, row: Any) -> RowSource:
    """The dataset to count (collected from a bag when ``source`` is one) and its GNSS fixes.

    Raises:
        BagError: no such source, or nothing collected from the bag.
        OrchardError: the bag lacks ``row.gnss_topic``.
    """
    from fruitnerfpp_ros.core.data.transforms_format import read_transforms
    from fruitnerfpp_ros.core.orchard.gnss import GNSS_JSON, fixes_from_bag, read_gnss_json

    if (source / 'transforms.json').is_file():
        fixes, antenna = read_gnss_json(source / GNSS_JSON) if (source / GNSS_JSON).is_file() else (None, None)
        return RowSource(source, fixes, antenna, len(read_transforms(source).frames))
    if not source.exists():
        raise BagError(f'{source}: neither a transforms.json dataset nor a rosbag2')
    keyframes = out / 'keyframes'
    marker = out / _COLLECTED
    done = json.loads(marker.read_text()) if marker.is_file() else None
    if done is None or Path(done.get('bag', '')).resolve() != source.resolve():
        from fruitnerfpp_ros.nodes.bag_replay import collect_keyframes
        if keyframes.exists():
            keyframes.rename(keyframes.with_name(f'keyframes_previous_{time.time_ns()}'))
        marker.unlink(missing_ok=True)
        assembler = collect_keyframes(source, keyframes, settings)
        if len(assembler.store) == 0:
            raise BagError(f'{source}: no keyframe could be made; received {dict(assembler.status().received)}')
        out.mkdir(parents=True, exist_ok=True)
        marker.write_text(json.dumps({'bag': str(source), 'keyframes': len(assembler.store)}))
    fixes = fixes_from_bag(source, row.gnss_topic) if row.gnss_topic else None
    return RowSource(keyframes, fixes, None, len(read_transforms(keyframes).frames))
