"""Approximate-time synchroniser."""

from __future__ import annotations

import pytest

from fruitnerfpp_ros.core.streams.time_sync import ApproximateTimeSynchronizer
from fruitnerfpp_ros.errors import ConfigError

MS = 1_000_000


def test_matches_within_slop_in_any_arrival_order() -> None:
    sync = ApproximateTimeSynchronizer(['image', 'mask', 'pose'], slop_ns=5 * MS)
    assert sync.add(0, 100 * MS, 'i100') == []
    assert sync.add(2, 98 * MS, 'p98') == []
    out = sync.add(1, 101 * MS, 'm101')
    assert len(out) == 1 and out[0].items == ('i100', 'm101', 'p98') and out[0].stamp_ns == 100 * MS
    assert sync.pending() == {'image': 0, 'mask': 0, 'pose': 0}


def test_high_rate_pose_picks_the_closest() -> None:
    sync = ApproximateTimeSynchronizer(['image', 'pose'], slop_ns=20 * MS)
    for t in range(0, 200, 10):  # 100 Hz poses
        sync.add(1, t * MS, f'p{t}')
    out = sync.add(0, 103 * MS, 'i103')
    assert [s.items for s in out] == [('i103', 'p100')]
    assert sync.unmatched['pose'] == 10  # poses 0..90 can never match any more


def test_stamps_that_never_sync_are_dropped_not_hoarded() -> None:
    sync = ApproximateTimeSynchronizer(['image', 'mask'], slop_ns=1 * MS, queue_size=5)
    for k in range(50):
        assert sync.add(0, k * 100 * MS, k) == []
        assert sync.add(1, k * 100 * MS + 50 * MS, k) == []
    assert sync.matched == 0
    assert sum(sync.unmatched.values()) + sum(sync.overflow.values()) >= 98
    assert max(sync.pending().values()) <= 5


def test_queue_bound_counts_overflow() -> None:
    sync = ApproximateTimeSynchronizer(['image', 'mask'], slop_ns=0, queue_size=3)
    for k in range(10):
        sync.add(0, k, k)
    assert sync.pending()['image'] == 3 and sync.overflow['image'] == 7
    assert sync.add(1, 9, 'm')[0].items == (9, 'm')


def test_impossible_settings_raise_config_error() -> None:
    with pytest.raises(ConfigError, match='needs at least one input'):
        ApproximateTimeSynchronizer([], slop_ns=MS)
    with pytest.raises(ConfigError, match='slop_ns must be >= 0 .* got slop_ns=-1, queue_size=30'):
        ApproximateTimeSynchronizer(['image'], slop_ns=-1)
    with pytest.raises(ConfigError, match='queue_size >= 1, got slop_ns=0, queue_size=0'):
        ApproximateTimeSynchronizer(['image'], slop_ns=0, queue_size=0)
