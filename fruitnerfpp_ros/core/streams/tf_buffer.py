"""A small TF buffer (tf2_ros is not on PyPI): stores /tf and /tf_static, composes chains, interpolates in time.

ROS-free: it holds 4x4 transforms; ``nodes.conversions.add_tf_message`` feeds it ``tf2_msgs/TFMessage`` messages.

Every child frame has one parent (the TF tree). Static edges hold one transform; dynamic edges keep a time
series (bounded by ``cache_ns``) and are interpolated to the requested stamp with
:func:`fruitnerfpp_ros.core.geometry.interpolate_transform`. A transform older than an edge's whole cache means
the clock jumped back (a bag played again): that edge's history starts over from it, as tf2 clears its buffer on
a time jump, instead of dropping every transform of the new time line.
"""

from __future__ import annotations

import bisect
import numpy as np

from fruitnerfpp_ros.core.geometry import interpolate_transform, invert_transform
from fruitnerfpp_ros.errors import ConversionError

__all__ = ['TfLookupError', 'TfFutureError', 'TfBuffer']


class TfLookupError(ConversionError):
    """A transform cannot be looked up (unknown frame, disconnected tree, stamp outside the cache)."""


class TfFutureError(TfLookupError):
    """The transform is not known *yet* at the requested stamp (newer data may still arrive)."""


class _Edge:
    def __init__(self, parent: str) -> None:
        self.parent = parent
        self.static: np.ndarray | None = None
        self.stamps: list[int] = []
        self.transforms: list[np.ndarray] = []


class TfBuffer:
    """Transforms between frames at given stamps.

    Args:
        cache_ns: how long dynamic transforms are kept, nanoseconds (relative to the newest one of each edge).
        tolerance_ns: a stamp this close outside an edge's time range still uses the nearest transform.
    """

    def __init__(self, cache_ns: int = 30_000_000_000, tolerance_ns: int = 1_000_000) -> None:
        self.cache_ns = int(cache_ns)
        self.tolerance_ns = int(tolerance_ns)
        self._edges: dict[str, _Edge] = {}

    @property
    def frames(self) -> list[str]:
        """Every frame name known (parents and children)."""
        return sorted(set(self._edges) | {e.parent for e in self._edges.values()})

    def set_transform(self, parent: str, child: str, stamp_ns: int, T_parent_child: np.ndarray,
                      *, static: bool = False) -> None:
        """Store ``T_parent_child`` (4x4) valid at ``stamp_ns`` (always, when ``static``)."""
        parent, child = parent.lstrip('/'), child.lstrip('/')
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent:
            edge = self._edges[child] = _Edge(parent)
        T = np.asarray(T_parent_child, dtype=np.float64)
        if static:
            edge.static = T
            return
        if edge.stamps and stamp_ns < edge.stamps[-1] - self.cache_ns:  # the clock jumped back: a new time line
            edge.stamps, edge.transforms = [], []
        i = bisect.bisect_left(edge.stamps, stamp_ns)
        if i < len(edge.stamps) and edge.stamps[i] == stamp_ns:
            edge.transforms[i] = T
        else:
            edge.stamps.insert(i, int(stamp_ns))
            edge.transforms.insert(i, T)
        cut = bisect.bisect_left(edge.stamps, edge.stamps[-1] - self.cache_ns)
        if cut:
            del edge.stamps[:cut], edge.transforms[:cut]

    def _edge_transform(self, child: str, edge: _Edge, stamp_ns: int) -> np.ndarray:
        if edge.static is not None:
            return edge.static
        stamps = edge.stamps
        if stamp_ns > stamps[-1] + self.tolerance_ns:
            raise TfFutureError(f'tf {edge.parent}->{child}: no transform yet at {stamp_ns} ns '
                                f'(newest {stamps[-1]} ns)')
        if stamp_ns < stamps[0] - self.tolerance_ns:
            raise TfLookupError(f'tf {edge.parent}->{child}: {stamp_ns} ns is older than the cache '
                                f'(oldest {stamps[0]} ns)')
        i = bisect.bisect_left(stamps, stamp_ns)
        if i == 0:
            return edge.transforms[0]
        if i >= len(stamps):
            return edge.transforms[-1]
        if stamps[i] == stamp_ns:
            return edge.transforms[i]
        fraction = (stamp_ns - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
        return interpolate_transform(edge.transforms[i - 1], edge.transforms[i], fraction)

    def _chain_to_root(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self._edges:
            chain.append(self._edges[chain[-1]].parent)
            if len(chain) > 64:
                raise TfLookupError(f'tf: loop in the tree above {frame!r}')
        return chain

    def _T_ancestor_frame(self, chain: list[str], stop: int, stamp_ns: int) -> np.ndarray:
        T = np.eye(4)
        for child in reversed(chain[:stop]):
            T = T @ self._edge_transform(child, self._edges[child], stamp_ns)
        return T

    def lookup(self, target: str, source: str, stamp_ns: int) -> np.ndarray:
        """``T_target_source`` at ``stamp_ns`` (maps points in ``source`` into ``target``).

        Raises:
            TfFutureError: a dynamic edge has no data at the stamp yet.
            TfLookupError: unknown frame, frames in different trees, or a stamp older than the cache.
        """
        target, source = target.lstrip('/'), source.lstrip('/')
        known = self.frames
        for frame in (target, source):
            if frame not in known:
                raise TfLookupError(f'tf: unknown frame {frame!r}; known frames: {", ".join(known) or "none"}')
        up_source, up_target = self._chain_to_root(source), self._chain_to_root(target)
        common = next((f for f in up_source if f in up_target), None)
        if common is None:
            raise TfLookupError(f'tf: {target!r} and {source!r} are not connected '
                                f'(roots {up_target[-1]!r} and {up_source[-1]!r})')
        T_common_source = self._T_ancestor_frame(up_source, up_source.index(common), stamp_ns)
        T_common_target = self._T_ancestor_frame(up_target, up_target.index(common), stamp_ns)
        return invert_transform(T_common_target) @ T_common_source
