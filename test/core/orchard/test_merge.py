"""Every fruit once: a fruit straddling a cut is counted by both segments and kept once."""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.orchard.config import MergeConfig
from fruitnerfpp_ros.core.orchard.merge import SegmentFruits, cloud_support, merge_segments
from fruitnerfpp_ros.core.orchard.row_frame import RowFrame
from fruitnerfpp_ros.core.orchard.segments import Segment

FRAME = RowFrame(np.array([0.0, 0.0]), np.array([1.0, 0.0]))
#: Two segments cut at s = 1 with a 0.5 m margin: trusted up to 0.3 m beyond the cut.
SEGMENTS = [Segment(0, (0.0, 1.0), (-0.3, 1.3), (-0.5, 1.5), (0, 1, 2)),
            Segment(1, (1.0, 2.0), (0.7, 2.3), (0.5, 2.5), (2, 3, 4))]


def _fruits(segment: int, centers: list[list[float]]) -> SegmentFruits:
    c = np.array(centers, np.float64)
    return SegmentFruits(segment, c, np.full(len(c), 0.07), np.full(len(c), 50), np.arange(1, len(c) + 1))


def test_a_fruit_straddling_the_cut_is_counted_once() -> None:
    a = _fruits(0, [[0.2, 0.1, 1.0], [1.01, 0.0, 1.2], [1.25, -0.2, 0.9], [1.45, 0.0, 1.0], [0.5, 2.0, 1.0]])
    b = _fruits(1, [[0.98, 0.01, 1.21], [1.6, 0.1, 1.1], [0.6, 0.0, 1.0]])
    row = merge_segments(FRAME, SEGMENTS, [a, b])
    # kept: 0.2 (a), the straddling fruit once (a's copy: the pair's middle lies in a's stretch), 1.25 (a only), 1.6
    # (b); dropped: 1.45 and 0.6 (outside their segment's trusted stretch), l = 2 (off the row)
    assert len(row) == 4
    assert np.allclose(row.along, [0.2, 1.01, 1.25, 1.6])
    assert row.segments.tolist() == [0, 0, 0, 1] and row.local_ids.tolist() == [1, 2, 3, 2]
    assert row.matched.tolist() == [False, True, False, False]
    assert row.dropped_untrusted == 2 and row.dropped_off_row == 1


def test_the_copy_of_the_segment_holding_the_pair_is_kept() -> None:
    a = _fruits(0, [[1.04, 0.0, 1.0]])
    b = _fruits(1, [[1.08, 0.0, 1.0]])
    row = merge_segments(FRAME, SEGMENTS, [a, b])
    assert len(row) == 1 and row.segments.tolist() == [1] and np.allclose(row.centers[0], [1.08, 0.0, 1.0])


def test_two_touching_fruits_at_the_cut_stay_two() -> None:
    a = _fruits(0, [[0.98, 0.0, 1.0], [1.055, 0.0, 1.0]])
    b = _fruits(1, [[0.985, 0.01, 1.0], [1.05, 0.0, 1.01]])
    row = merge_segments(FRAME, SEGMENTS, [a, b], MergeConfig(match_diameters=1.0))
    assert len(row) == 2 and row.matched.all()


def test_a_failed_segment_leaves_a_gap_and_the_rest_counts() -> None:
    a = _fruits(0, [[0.5, 0.0, 1.0], [1.2, 0.0, 1.0]])
    row = merge_segments(FRAME, SEGMENTS, [a, None])
    assert len(row) == 2 and not row.matched.any()
    empty = merge_segments(FRAME, SEGMENTS, [None, None])
    assert len(empty) == 0 and empty.centers.shape == (0, 3)


def test_the_copies_of_a_fruit_at_the_edge_of_the_overlap_are_counted_once() -> None:
    """The trusted stretches overlap on 0.7..1.3; a fruit at an end of it has one copy inside and one just outside
    (the segments place it a few millimetres apart): both trusted by their own segment, they are one fruit."""
    a = _fruits(0, [[1.297, 0.0, 1.0], [0.696, 0.1, 1.0]])
    b = _fruits(1, [[1.305, 0.0, 1.0], [0.703, 0.1, 1.0]])
    row = merge_segments(FRAME, SEGMENTS, [a, b])
    assert len(row) == 2 and row.matched.all()
    far = merge_segments(FRAME, SEGMENTS, [a, _fruits(1, [[1.45, 0.0, 1.0]])])  # beyond the reach: another fruit
    assert len(far) == 3 and not far.matched.any()


def test_a_fruit_one_segment_split_in_two_is_counted_once() -> None:
    """a counts two halves of the fruit at the cut (3 cm apart), b counts it once: the pair takes one half, and the
    other half, within a diameter of both copies, is the same fruit. Before, it stayed: a double across the cut."""
    a = _fruits(0, [[0.99, 0.0, 1.0], [1.02, 0.01, 1.01], [0.4, 0.0, 1.0]])
    b = _fruits(1, [[1.005, 0.0, 1.0], [1.8, 0.0, 1.0]])
    row = merge_segments(FRAME, SEGMENTS, [a, b])
    assert len(row) == 3 and np.allclose(row.along[[0, 2]], [0.4, 1.8])
    assert 0.99 <= row.along[1] <= 1.02 and row.matched.tolist() == [False, True, False]
    mirrored = merge_segments(FRAME, SEGMENTS, [_fruits(0, [[1.005, 0.0, 1.0]]), _fruits(1, a.centers[:2].tolist())])
    assert len(mirrored) == 1 and mirrored.matched.all()


def test_a_touching_fruit_the_neighbour_missed_still_counts() -> None:
    """Two fruits' centres are at least a diameter apart: a's second fruit, 7.5 cm (over one 7 cm diameter) from
    the pair, is not a piece of it, though b missed it."""
    a = _fruits(0, [[0.98, 0.0, 1.0], [1.055, 0.0, 1.0]])
    b = _fruits(1, [[0.985, 0.01, 1.0]])
    row = merge_segments(FRAME, SEGMENTS, [a, b])
    assert len(row) == 2 and row.matched.sum() == 1


def test_a_touching_fruit_beyond_the_neighbours_trusted_stretch_still_counts() -> None:
    """Two touching fruits (7 and 6 cm, centres 6.5 cm apart) at the end of the overlap: both segments count the
    first, a pair; the second lies beyond a's trusted stretch (1.3), so only b's copy is trusted. a's own, untrusted
    copy says a saw a second fruit there: b's is no piece of the pair (the live row's perfect count lost it so)."""
    a = _fruits(0, [[1.27, 0.0, 1.0], [1.335, 0.0, 1.0]])
    a = a._replace(diameters=np.array([0.07, 0.06]))
    b = a._replace(segment=1)
    row = merge_segments(FRAME, SEGMENTS, [a, b])
    assert np.allclose(row.along, [1.27, 1.335]) and row.matched.tolist() == [True, False]
    assert row.dropped_untrusted == 1


def test_a_neighbours_copy_larger_than_a_fruit_leaves_both_fruits() -> None:
    """b's copy is 1.5 fruit diameters across: b may have merged a's two fruits (7 cm apart) into it."""
    a = _fruits(0, [[0.99, 0.0, 1.0], [1.05, 0.01, 1.01], [0.4, 0.0, 1.0]])
    b = _fruits(1, [[1.02, 0.0, 1.0], [1.8, 0.0, 1.0]])
    b = b._replace(diameters=np.array([0.105, 0.07]))
    assert len(merge_segments(FRAME, SEGMENTS, [a, b])) == 4
    assert len(merge_segments(FRAME, SEGMENTS, [a, b._replace(diameters=np.array([0.07, 0.07]))])) == 3


def _with_support(fruits: SegmentFruits, where: list[list[float]]) -> SegmentFruits:
    """The segment's fruit cloud: a shell of points 3 cm around each of ``where``, thinned as the jobs thin it."""
    sphere = np.random.default_rng(0).normal(size=(200, 3))
    shell = 0.03 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True)
    points = np.concatenate([np.asarray(c) + shell for c in where]) if where else np.zeros((0, 3))
    return fruits._replace(support=cloud_support(points, 0.014))


def test_a_fruit_only_one_segment_counted_where_the_neighbours_cloud_is_empty_is_dropped() -> None:
    """The overlap of the trusted stretches is 0.7..1.3. a counts a fruit at 1.2 and b does not: b's views saw the
    place; where b's fruit cloud has points there (a fruit b's clustering lost), a's fruit stays; where b's cloud is
    empty there, a's fruit is a ghost of a's field, and is dropped. Fruits outside the overlap are not judged."""
    a = _fruits(0, [[0.4, 0.0, 1.0], [1.2, 0.0, 1.0], [1.0, 0.1, 1.0]])
    b = _fruits(1, [[1.002, 0.1, 1.0], [1.8, 0.0, 1.0]])
    seen = merge_segments(FRAME, SEGMENTS, [a, _with_support(b, [[1.0, 0.1, 1.0], [1.8, 0.0, 1.0], [1.2, 0.0, 1.0]])])
    assert np.allclose(seen.along, [0.4, 1.0, 1.2, 1.8], atol=0.003) and seen.dropped_unsupported == 0
    empty = merge_segments(FRAME, SEGMENTS, [a, _with_support(b, [[1.0, 0.1, 1.0], [1.8, 0.0, 1.0]])])
    assert np.allclose(empty.along, [0.4, 1.0, 1.8], atol=0.003) and empty.dropped_unsupported == 1
    assert empty.matched.tolist() == [False, True, False]                     # the pair is not judged
    from_masks = a._replace(n_points=np.array([50, 0, 50]))                 # found from a's masks, not its cloud
    assert len(merge_segments(FRAME, SEGMENTS, [from_masks, _with_support(b, [[1.0, 0.1, 1.0]])])) == 4
    unknown = merge_segments(FRAME, SEGMENTS, [a, b])                        # no support (an old result): kept
    assert len(unknown) == 4 and unknown.dropped_unsupported == 0
    assert len(merge_segments(FRAME, SEGMENTS, [a, _with_support(b, [])])) == 4    # b found nothing at all
    off = MergeConfig(support_radius_diameters=0)
    assert len(merge_segments(FRAME, SEGMENTS, [a, _with_support(b, [[1.0, 0.1, 1.0]])], off)) == 4


def test_the_support_is_judged_both_ways_and_within_a_third_of_a_diameter() -> None:
    """b's lone fruit at 0.8 lies in a's trusted stretch: a's cloud is judged too. A cloud point 1.5 cm off (0.21 of
    the 7 cm fruit) supports it; 6 cm off (0.86) does not."""
    b = _fruits(1, [[0.8, 0.0, 1.0], [1.6, 0.0, 1.0]])
    near = merge_segments(FRAME, SEGMENTS, [_with_support(_fruits(0, [[0.3, 0.0, 1.0]]), [[0.8, 0.0, 1.045]]), b])
    assert np.allclose(near.along, [0.3, 0.8, 1.6])
    far = merge_segments(FRAME, SEGMENTS, [_with_support(_fruits(0, [[0.3, 0.0, 1.0]]), [[0.8, 0.0, 1.09]]), b])
    assert np.allclose(far.along, [0.3, 1.6]) and far.dropped_unsupported == 1


def test_cloud_support_keeps_one_point_per_occupied_voxel() -> None:
    points = np.array([[0.001, 0.001, 0.001], [0.009, 0.002, 0.003], [0.011, 0.0, 0.0], [-0.001, 0.0, 0.0]])
    support = cloud_support(points, 0.01)
    expected = [(-0.005, 0.005, 0.005), (0.005, 0.005, 0.005), (0.015, 0.005, 0.005)]
    assert sorted(map(tuple, np.round(support, 4))) == expected
    assert cloud_support(np.zeros((0, 3)), 0.01).shape == (0, 3)
