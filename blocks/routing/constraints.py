"""Run-time routing constraints shared by the routing blocks: blockades and penalties per arc.

A permanent blockade (a segment closed for longer, thesis level 3) removes arcs from routing;
a penalty (a segment occupied by another vehicle, thesis 5.3.1) makes them expensive but not
impossible, so a route still exists when the occupied segment is the only way. Both are
numpy arrays indexed by arc id: checking one is O(1) inside an A* step, and changing them
at run time needs no rebuild. Neither can make a precomputed distance table overestimate:
they only ever make true costs larger.
"""

from __future__ import annotations

import math
from collections.abc import Hashable

import numpy as np

from topology import Plant


def highway_weights(plant: Plant, factor: float) -> np.ndarray:
    """Per arc, the factor its cost is multiplied by: ``factor`` against its lane's
    preferred direction (a highway edge's 'to' -> 'from' arc), 1 elsewhere. ValueError
    unless ``factor`` is a finite number >= 1."""
    if not (math.isfinite(factor) and factor >= 1):
        raise ValueError(f"highway_factor must be a finite number >= 1, got {factor!r}")
    return np.where(plant.against_highway, float(factor), 1.0)


def highway_penalty(plant: Plant, factor: float) -> np.ndarray:
    """Per arc, the extra cost on top of its length that :func:`highway_weights` makes."""
    _, _, length = plant.arcs
    return (highway_weights(plant, factor) - 1.0) * length


class RoutingConstraints:
    """Closed segments and extra costs, shared by every route search.

    A segment may be closed by several at once, each under its own name (``by``: an
    operator, each entry of a blockade schedule): it stays closed until every one that
    closed it has reopened it, so a schedule's end never reopens what an operator or an
    overlapping entry still keeps closed. :meth:`unblock` without ``by`` is the operator's
    override: it reopens the segment whoever closed it."""

    OPERATOR = "operator"

    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.blocked = np.zeros(plant.n_arcs, dtype=bool)
        self.penalty = np.zeros(plant.n_arcs, dtype=np.float64)
        self.epoch = 0  # counts blockade changes: routes planned before a change are stale
        self._closed_by: dict[int, set[Hashable]] = {}  # closed arc -> who keeps it closed

    def block(self, a: int, b: int, both_ways: bool = True, by: Hashable = OPERATOR) -> None:
        """Close the segment a -> b (and b -> a) for ``by``; TopologyError if there is no
        such segment."""
        arcs = self.plant.arcs_between(a, b, both_ways)
        for arc in arcs:
            self._closed_by.setdefault(arc, set()).add(by)
        if not self.blocked[arcs].all():
            self.blocked[arcs] = True
            self.epoch += 1

    def unblock(self, a: int, b: int, both_ways: bool = True, by: Hashable | None = None) -> None:
        """Reopen the segment a -> b (and b -> a): ``by`` no longer keeps it closed (it
        opens once nobody does), or, without ``by``, whoever closed it."""
        arcs = self.plant.arcs_between(a, b, both_ways)
        opened = []
        for arc in arcs:
            holders = self._closed_by.get(arc)
            if holders is not None:
                if by is None:
                    holders.clear()
                else:
                    holders.discard(by)
                if holders:
                    continue
                del self._closed_by[arc]
            opened.append(arc)
        if self.blocked[opened].any():
            self.blocked[opened] = False
            self.epoch += 1

    def closed_by(self, a: int, b: int) -> set[Hashable]:
        """Who keeps the segment between a and b closed, either way (empty: it is open)."""
        index = self.plant.arc_index
        arcs = [*index.get((a, b), ()), *index.get((b, a), ())]
        return set().union(*(self._closed_by.get(arc, ()) for arc in arcs))

    def penalize(self, a: int, b: int, extra: float, both_ways: bool = False) -> None:
        """Set the extra cost of a -> b (default one direction: the one an oncoming vehicle uses)."""
        if isinstance(extra, bool) or not isinstance(extra, int | float | np.number):
            raise TypeError(f"penalty must be a number, got {extra!r} ({type(extra).__name__})")
        if not (math.isfinite(extra) and extra >= 0):
            raise ValueError(
                f"penalty must be a finite number >= 0 (a blockade is block()), got {extra!r}"
            )
        self.penalty[self.plant.arcs_between(a, b, both_ways)] = extra

    def clear(self) -> None:
        self._closed_by.clear()
        self.blocked[:] = False
        self.penalty[:] = 0.0
        self.epoch += 1

    def blocked_segments(self) -> list[tuple[int, int]]:
        src, dst, _ = self.plant.arcs
        ids = self.plant.ids
        return [(int(ids[src[a]]), int(ids[dst[a]])) for a in np.flatnonzero(self.blocked)]
