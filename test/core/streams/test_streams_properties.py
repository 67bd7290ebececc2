"""Property-based tests of the time synchroniser and the TF buffer on arbitrary (also backwards) stamp streams."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fruitnerfpp_ros.core.geometry import transform_from_quaternion
from fruitnerfpp_ros.core.streams.tf_buffer import TfBuffer, TfLookupError
from fruitnerfpp_ros.core.streams.time_sync import ApproximateTimeSynchronizer

PROPERTIES = settings(max_examples=200, deadline=None)
STAMPS = st.one_of(st.integers(-10**3, 10**3), st.integers(-2**62, 2**62))


@PROPERTIES
@given(st.integers(1, 3), st.integers(0, 50), st.integers(1, 5),
       st.lists(st.tuples(st.integers(0, 2), STAMPS), max_size=60))
def test_sync_sets_lie_within_the_slop_and_every_item_is_accounted_for(
        n_inputs: int, slop: int, queue_size: int, adds: list[tuple[int, int]]) -> None:
    names = [f'in{i}' for i in range(n_inputs)]
    sync: ApproximateTimeSynchronizer[int] = ApproximateTimeSynchronizer(names, slop, queue_size)
    added = [0] * n_inputs
    emitted: list[tuple] = []
    for k, (index, stamp) in enumerate(adds):
        index %= n_inputs
        added[index] += 1
        for synced in sync.add(index, stamp, k):
            stamps = [adds[item][1] for item in synced.items]
            assert max(stamps) - min(stamps) <= slop
            assert [adds[item][0] % n_inputs for item in synced.items] == list(range(n_inputs))
            emitted.append(synced.items)
        assert all(n <= queue_size for n in sync.pending().values())
    items = [item for synced in emitted for item in synced]
    assert len(items) == len(set(items))  # no item is used twice
    for i, name in enumerate(sync.names):  # added = matched + dropped unmatched + overflowed + still waiting
        assert added[i] == sync.matched + sync.unmatched[name] + sync.overflow[name] + sync.pending()[name]


def _rotation(angle: float) -> np.ndarray:
    return transform_from_quaternion([angle, 0.0, 1.0], [0.0, 0.0, np.sin(angle / 2), np.cos(angle / 2)])


@PROPERTIES
@given(st.lists(st.tuples(st.sampled_from(['base', 'cam', 'arm']), st.integers(-5 * 10**10, 5 * 10**10),
                          st.floats(-3, 3)), min_size=1, max_size=30),
       st.lists(st.integers(-6 * 10**10, 6 * 10**10), min_size=1, max_size=10))
def test_tf_lookups_are_rigid_invertible_and_chain(updates: list[tuple[str, int, float]], queries: list[int]) -> None:
    """map -> base -> cam, base -> arm with stamps in any order (jumps back included): any lookup is a rigid
    transform or a TfLookupError; target<-source inverts source<-target; a chain composes its links."""
    tf = TfBuffer(cache_ns=10 * 10**9)
    parents = {'base': 'map', 'cam': 'base', 'arm': 'base'}
    tf.set_transform('base', 'cam', 0, _rotation(0.3), static=True)
    for child, stamp, angle in updates:
        tf.set_transform(parents[child], child, stamp, _rotation(angle), static=False)
    for stamp in queries:
        try:
            T = tf.lookup('map', 'cam', stamp)
            T_back = tf.lookup('cam', 'map', stamp)
            T_map_base = tf.lookup('map', 'base', stamp)
        except TfLookupError:
            continue
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
        assert np.allclose(T @ T_back, np.eye(4), atol=1e-9)
        assert np.allclose(T, T_map_base @ tf.lookup('base', 'cam', stamp), atol=1e-9)


def test_a_transform_older_than_the_cache_starts_the_edge_over() -> None:
    """Before: after a jump back in time (a bag played again) every new transform fell outside the cache window of
    the old time line and was dropped at once, so no lookup on the new time line could ever succeed."""
    tf = TfBuffer(cache_ns=10 * 10**9)
    tf.set_transform('map', 'base', 100 * 10**9, _rotation(0.1))
    tf.set_transform('map', 'base', 5 * 10**9, _rotation(0.2))   # 95 s earlier: a new time line
    tf.set_transform('map', 'base', 6 * 10**9, _rotation(0.4))
    assert np.allclose(tf.lookup('map', 'base', int(5.5 * 10**9)), _rotation(0.3), atol=1e-9)
