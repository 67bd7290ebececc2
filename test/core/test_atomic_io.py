"""Atomic writes: parent folders created, nothing left behind when the writer fails."""

from pathlib import Path

import pytest

from fruitnerfpp_ros.core.atomic_io import atomic_path, atomic_write_text, trim_torn_line


def test_write_creates_parents_and_replaces(tmp_path: Path) -> None:
    target = tmp_path / 'a' / 'b' / 'counts.json'
    atomic_write_text(target, 'one')
    atomic_write_text(target, 'two', fsync=True)
    assert target.read_text() == 'two'
    assert [p.name for p in target.parent.iterdir()] == ['counts.json']


def test_failed_writer_keeps_previous_file(tmp_path: Path) -> None:
    target = tmp_path / 'cloud.ply'
    target.write_text('previous')
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text('half')
        raise RuntimeError('writer died')
    assert target.read_text() == 'previous'
    assert [p.name for p in tmp_path.iterdir()] == ['cloud.ply']


def test_a_torn_last_line_is_cut_and_whole_lines_stay(tmp_path: Path) -> None:
    log = tmp_path / 'metrics.jsonl'
    assert trim_torn_line(log) == 0
    log.write_bytes(b'{"step": 1}\n{"step": 2}\n{"step": 3, "lo')
    assert trim_torn_line(log) == len(b'{"step": 3, "lo')
    assert log.read_bytes() == b'{"step": 1}\n{"step": 2}\n'
    assert trim_torn_line(log) == 0 and log.read_bytes() == b'{"step": 1}\n{"step": 2}\n'
    log.write_bytes(b'{"st')
    assert trim_torn_line(log) == 4 and log.read_bytes() == b''
