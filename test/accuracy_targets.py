"""Accuracy floors of the CI tests: strict, below today's figures by a margin, never an expected failure.

The tiny CPU preset counts the CI scenes (the 20-apple 48-view test tree and the small bag and live-node trees)
well above these floors (figures and commands in docs/results/accuracy_suite.md); a count of 0 always fails. The
targets above today's figures live in the accuracy suite (``fruitnerfpp bench accuracy``), not here.
"""

from __future__ import annotations

__all__ = ['MIN_F1', 'COUNT_TOLERANCE', 'assert_counted']

#: Lowest F1 (Hungarian matching within one fruit diameter) a CI count may reach.
MIN_F1 = 0.85
#: Largest relative count error a CI count may make.
COUNT_TOLERANCE = 0.2


def assert_counted(count: int, truth: int, f1: float | None = None, *, tolerance: float = COUNT_TOLERANCE,
                   min_f1: float = MIN_F1) -> None:
    """Fail unless ``count`` is non-zero and within ``tolerance`` of ``truth`` and (when given) ``f1 >= min_f1``."""
    figures = f'counted {count}, ground truth {truth}' + ('' if f1 is None else f', F1 {f1:.3f}')
    assert count > 0, f'nothing counted ({figures})'
    assert abs(count - truth) <= tolerance * truth, f'count off by more than {tolerance:.0%} ({figures})'
    assert f1 is None or f1 >= min_f1, f'F1 below {min_f1} ({figures})'
