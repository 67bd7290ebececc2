"""Latency of a live row count from the node's events: hand-written event logs with known answers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fruitnerfpp_ros.core.orchard.latency import read_events, segment_latencies
from fruitnerfpp_ros.errors import OrchardError


def _events() -> list[dict]:
    t0 = 1000.0
    rows = [  # (seconds after t0, record)
        (0, {'event': 'keyframe'}), (5, {'event': 'keyframe'}),
        (6, {'event': 'queued', 'segment': 0, 'version': 1}),
        (6.5, {'event': 'training', 'segment': 0, 'version': 1}),
        (9, {'event': 'queued', 'segment': 1, 'version': 1}),
        (20, {'event': 'queued', 'segment': 0, 'version': 2}),           # passed again on the way back
        (66.5, {'event': 'trained', 'segment': 0, 'version': 1, 'ok': True, 'seconds': 60.0}),
        (67, {'event': 'published'}),                                      # segment 0's first count: 61 s after 6
        (67, {'event': 'training', 'segment': 1, 'version': 1}),
        (107, {'event': 'trained', 'segment': 1, 'version': 1, 'ok': False, 'seconds': 40.0}),
        (107.5, {'event': 'published'}),                                   # failed: no count of segment 1
        (108, {'event': 'training', 'segment': 0, 'version': 2}),
        (168, {'event': 'trained', 'segment': 0, 'version': 2, 'ok': True, 'seconds': 60.0}),
        (170, {'event': 'published'}),                                     # version 2: 150 s after 20
    ]
    return [{'time_unix_s': t0 + t, **r} for t, r in rows]


def test_latency_runs_from_passing_a_segment_to_the_publication_holding_its_count() -> None:
    zero, one = segment_latencies(reversed(_events()))     # the order of the records does not matter
    assert zero.segment == 0 and zero.passed_s == 6.0 and zero.first_count_s == 61.0
    assert zero.last_passed_s == 20.0 and zero.final_count_s == 150.0 and zero.versions == 2
    assert zero.training_s == 120.0
    assert one.segment == 1 and one.first_count_s is None and one.final_count_s is None and one.training_s == 40.0


def test_an_events_file_with_a_torn_last_line_reads_and_one_without_keyframes_is_refused(tmp_path: Path) -> None:
    path = tmp_path / 'events.jsonl'
    path.write_text('\n'.join(json.dumps(e) for e in _events()) + '\n{"time_unix_s": 12')
    assert len(read_events(path)) == len(_events())
    path.write_text('{"time_unix_s": 1\n' + json.dumps(_events()[0]))
    with pytest.raises(OrchardError, match=':1: not a JSON record'):
        read_events(path)
    with pytest.raises(OrchardError, match='no keyframe'):
        segment_latencies([e for e in _events() if e['event'] != 'keyframe'])
