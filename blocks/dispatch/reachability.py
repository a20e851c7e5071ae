"""Which nodes can reach a station now, with the segments that are closed right now, and
on the plant as built.

The heuristic table holds distances on the whole plant, blockades ignored (it must never
overestimate). The dispatcher must not give a vehicle an order it cannot drive, and must
notice when a blockade cuts a station off, so it keeps, per station, the set of nodes from
which the station is reachable over open segments: one breadth-first search per station
on the reversed graph, done again only when the blockades change (arrays in, arrays out).
The same sets with every segment open tell an order no vehicle could ever drive (it is
refused for good) from one a blockade holds up (it waits for the segment to reopen).
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order

from blocks.routing.constraints import RoutingConstraints
from topology import Plant


class Reachability:
    def __init__(self, plant: Plant, blockades: RoutingConstraints, targets: Iterable[int]) -> None:
        self.plant = plant
        self.blockades = blockades
        self.targets = sorted(set(targets))
        self._epoch: int | None = None
        self._reach: dict[int, np.ndarray] = {}

    def _refresh(self) -> None:
        if self._epoch == self.blockades.epoch:
            return
        self._epoch = self.blockades.epoch
        self._reach = self._sets(~self.blockades.blocked)

    def _sets(self, open_: np.ndarray) -> dict[int, np.ndarray]:
        src, dst, _ = self.plant.arcs
        n = self.plant.n
        # reversed: an arc u -> v lets v be reached from u, so search from the target backwards
        reverse = sp.csr_array((np.ones(int(open_.sum())), (dst[open_], src[open_])), shape=(n, n))
        sets = {}
        for t in self.targets:
            mask = np.zeros(n, dtype=bool)
            mask[breadth_first_order(reverse, self.plant.idx(t), return_predecessors=False)] = True
            sets[t] = mask
        return sets

    def reaches(self, node: int, target: int) -> bool:
        """Can a vehicle at ``node`` (an id) drive to ``target`` over open segments?"""
        self._refresh()
        return bool(self._reach[target][self.plant.idx(node)])

    def reached_from(self, nodes: np.ndarray, target: int, on_plant: bool = False) -> bool:
        """Can a vehicle at any of ``nodes`` (node indices, not ids) drive to ``target``,
        over the segments open now (``on_plant``: with every segment open)? One array
        lookup for the whole fleet."""
        if on_plant:
            sets = self._built
        else:
            self._refresh()
            sets = self._reach
        return bool(sets[target][nodes].any())

    @cached_property
    def _built(self) -> dict[int, np.ndarray]:
        return self._sets(np.ones(self.plant.n_arcs, dtype=bool))

    def reaches_on_plant(self, node: int, target: int) -> bool:
        """Could a vehicle at ``node`` drive to ``target`` with every segment open?"""
        return bool(self._built[target][self.plant.idx(node)])
