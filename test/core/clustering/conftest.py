"""Clustering tests: fast_hdbscan's numba JIT is warmed once per session, not per test."""

from __future__ import annotations

import pytest


@pytest.fixture(scope='session', autouse=True)
def hdbscan_jit() -> float:
    """Compile / load fast_hdbscan's kernels once (20-80 s on a cold disk cache, about 1 s after)."""
    from fruitnerfpp_ros.core.clustering.hdbscan_cluster import warm_up
    return warm_up()
