"""bench/trunk_probe.py's geometry: peaks of several segments joined into trunks, crowns held over their trunks."""

from __future__ import annotations

import numpy as np

from test.bench_scripts import load_bench_script

probe = load_bench_script('trunk_probe')


def test_peaks_seen_by_two_segments_are_one_trunk_and_a_lone_peak_is_none() -> None:
    peaks = np.array([[0, 0.00, 0.00, 5.0], [1, 0.02, 0.00, 4.0],    # one trunk, two segments
                      [1, 0.50, 0.01, 6.0], [2, 0.52, -0.01, 6.0],   # a second
                      [2, 0.90, 0.40, 9.0]])                          # one segment only: no trunk
    trunks = probe.trunks_from_peaks(peaks)
    np.testing.assert_allclose(trunks[np.argsort(trunks[:, 0])], [[0.01, 0.0], [0.51, 0.0]], atol=1e-9)


def test_crowns_over_their_trunks_take_back_the_fruit_of_each_tree() -> None:
    """Two overlapping crowns of different size, fruit on their shells: each fruit goes to the crown it hangs on,
    also where the small crown's fruit lie nearer to the big tree's trunk than to their own."""
    rng = np.random.default_rng(3)
    trunks = np.array([[0.0, 0.0], [0.55, 0.0]])
    centres, radii = np.array([[0.0, 0.0, 1.0], [0.55, 0.0, 0.8]]), np.array([0.4, 0.25])
    fruit, tree = [], []
    for k in range(2):
        d = rng.normal(size=(40, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        fruit.append(centres[k] + radii[k] * d)
        tree += [k] * 40
    fruit, truth = np.concatenate(fruit), np.array(tree)
    labels = probe.crowns_on_trunks(fruit, trunks)
    nearest = np.argmin(np.linalg.norm(fruit[:, None, :2] - trunks[None], axis=2), axis=1)
    assert (labels == truth).mean() >= 0.97 > (nearest == truth).mean()  # the nearest trunk gets some wrong
