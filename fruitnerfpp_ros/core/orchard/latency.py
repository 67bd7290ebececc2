"""How long a live row count lags the robot: per segment, from being passed to its count being published.

The row mode of ``fruit_counter`` writes ``RUN_DIR/row/events.jsonl``: one JSON record per keyframe, per segment
``queued`` (the robot has passed it; again, with a higher version, when it passes it on the way back), ``training``,
``trained`` and per ``published`` row count, each with its wall time ``time_unix_s``. :func:`segment_latencies`
turns them into the figures of issue #12: for each segment the time from its first ``queued`` (the robot passed the
tree) to the first publication holding its count, and from its last ``queued`` (both sides seen) to the publication
of that version's count.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterable, NamedTuple

from fruitnerfpp_ros.errors import OrchardError

__all__ = ['SegmentLatency', 'read_events', 'segment_latencies']


class SegmentLatency(NamedTuple):
    """One segment's lag behind the robot (seconds; None: not published before the events end).

    Attributes:
        segment: the segment (cell) index.
        passed_s: wall time it was first queued, seconds after the first keyframe.
        first_count_s: from then to the first publication holding a count of it.
        last_passed_s: wall time its last version was queued, seconds after the first keyframe.
        final_count_s: from then to the publication of that version's count.
        versions: how many versions were queued; training_s: summed training time of the versions trained.
    """

    segment: int
    passed_s: float
    first_count_s: float | None
    last_passed_s: float
    final_count_s: float | None
    versions: int
    training_s: float


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """The records of an ``events.jsonl`` (a torn last line, from a node killed while writing, is left out)."""
    lines = Path(path).read_text().splitlines()
    out = []
    for number, line in enumerate(lines, start=1):
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError as err:
            if number < len(lines):
                raise OrchardError(f'{path}:{number}: not a JSON record: {err}') from err
    return out


def segment_latencies(events: Iterable[dict[str, Any]]) -> list[SegmentLatency]:
    """Per segment that was queued, in segment order: its lag from being passed to its count being published."""
    records = sorted(events, key=lambda e: float(e['time_unix_s']))
    keyframes = [float(e['time_unix_s']) for e in records if e.get('event') == 'keyframe']
    if not keyframes:
        raise OrchardError('events hold no keyframe: not a row drive')
    start = keyframes[0]
    queued: dict[int, list[tuple[float, int]]] = {}
    trained: dict[int, list[tuple[int, float]]] = {}
    pending: set[tuple[int, int]] = set()             # (segment, version) trained ok, not yet published
    published: dict[tuple[int, int], float] = {}
    for e in records:
        t, kind = float(e['time_unix_s']), e.get('event')
        if kind == 'queued':
            queued.setdefault(int(e['segment']), []).append((t, int(e['version'])))
        elif kind == 'trained':
            trained.setdefault(int(e['segment']), []).append((int(e['version']), float(e.get('seconds', 0.0))))
            if e.get('ok', True):
                pending.add((int(e['segment']), int(e['version'])))
        elif kind == 'published':
            for key in pending:
                published.setdefault(key, t)
            pending.clear()
    out = []
    for segment in sorted(queued):
        first_t = queued[segment][0][0]
        last_t, last_version = queued[segment][-1]
        counted = sorted(t for (s, _), t in published.items() if s == segment)
        final = published.get((segment, last_version))
        out.append(SegmentLatency(segment, first_t - start, counted[0] - first_t if counted else None,
                                  last_t - start, None if final is None else final - last_t,
                                  len(queued[segment]), sum(s for _, s in trained.get(segment, []))))
    return out
