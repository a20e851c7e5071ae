"""HeuristicTable: the exact distance of every node TO every target, built at startup.

Thesis section 3.6: Dijkstra runs once per final target in the startup phase (OB100), where
there is no cycle monitoring, and A* then uses the table as its heuristic. Distances are
computed on the reversed routing graph (distance *to* the target, which differs from the
distance *from* it on directed plants) with ``scipy.sparse.csgraph.dijkstra``, a few targets
at a time to bound the float64 working set, and stored as float32 rounded *down*, so rounding
can never make the heuristic overestimate. Unreachable is ``inf``.

Rows for targets that were not in the table are computed on first use: ``row(target)``
queues the target and returns None, and the block computes at most one queued row per cycle
at its own position in the task (put it before the A* blocks), so the cost lands on one
cycle per new target and is reported in ``rows_computed_in_cycle`` and ``late_row_ms``;
prefetch them with ``targets=`` where the budget matters.

The table belongs to one topology. Assigning a plant with another fingerprint to ``plant``
while running is rejected: ``error`` says why and routing stays on ``served_plant`` (the old
one); the next start builds the table for the new plant. A new edge could be a shortcut the
table does not know, and A* would then no longer be optimal.
"""

from __future__ import annotations

from collections.abc import Iterable
from time import perf_counter

import numpy as np
from scipy.sparse.csgraph import dijkstra

from plc_runtime import CycleContext, FunctionBlock, Output
from topology import Plant

CHUNK = 64  # targets per dijkstra call: bounds the float64 intermediate to 64 x n


def distances_to(plant: Plant, targets: list[int]) -> np.ndarray:
    """float32 matrix (len(targets) x plant.n): exact distance of every node to each target,
    rounded down to float32."""
    reverse = plant.csr.T.tocsr()
    out = np.empty((len(targets), plant.n), dtype=np.float32)
    indices = [plant.idx(t) for t in targets]
    for start in range(0, len(indices), CHUNK):
        exact = dijkstra(reverse, directed=True, indices=indices[start : start + CHUNK])
        rounded = exact.astype(np.float32)
        over = rounded > exact
        rounded[over] = np.nextafter(rounded[over], np.float32(0))
        out[start : start + CHUNK] = rounded
    return out


class HeuristicTable(FunctionBlock):
    error = Output(None, doc="why a topology change was rejected, None if none was")
    rows_computed_in_cycle = Output(0, doc="rows computed on first use since start")
    late_row_ms = Output(0.0, doc="time the last first-use row took, ms")

    def __init__(self, plant: Plant, targets: Iterable[int] | None = None) -> None:
        super().__init__()
        self.plant = plant
        self.targets = list(targets) if targets is not None else None
        self.build_time_s = 0.0
        self._built_for: Plant | None = None
        self._rows: dict[int, int] = {}
        self._matrix = np.empty((0, 0), dtype=np.float32)
        self._late: dict[int, np.ndarray] = {}
        self._queued: list[int] = []

    @property
    def nbytes(self) -> int:
        return self._matrix.nbytes + sum(r.nbytes for r in self._late.values())

    @property
    def fingerprint(self) -> str | None:
        return self._built_for.fingerprint if self._built_for else None

    def startup(self, ctx: CycleContext) -> None:
        plant = self.plant
        targets = self.targets if self.targets is not None else plant.targets
        for t in targets:
            plant.idx(t)  # unknown target: a clear error in startup, not a silent gap
        begin = perf_counter()
        _ = plant.index, plant.ids, plant.neighbors  # adjacency for the blocks that route on it
        self._matrix = distances_to(plant, list(targets))
        self.build_time_s = perf_counter() - begin
        self._rows = {t: i for i, t in enumerate(targets)}
        self._late, self._queued = {}, []
        self._built_for = plant

    def cycle(self, ctx: CycleContext) -> None:
        if self.plant is not self._built_for:
            self._reject_or_adopt(self.plant)
        if self._queued:
            target = self._queued.pop(0)
            begin = perf_counter()
            self._late[target] = distances_to(self._built_for, [target])[0]
            self.late_row_ms = (perf_counter() - begin) * 1e3
            self.rows_computed_in_cycle += 1

    def _reject_or_adopt(self, plant: Plant) -> None:
        built = self._built_for
        if plant.fingerprint == built.fingerprint:
            self._built_for = plant  # the same topology in a new object
            return
        self.error = (
            f"topology change rejected: the heuristic table was built for {built.name} "
            f"(fingerprint {built.fingerprint}), the new plant has fingerprint {plant.fingerprint}; "
            "routing stays on the old topology until a restart rebuilds the table "
            "(a new edge could make it overestimate)"
        )

    @property
    def served_plant(self) -> Plant:
        """The topology the table was built for (what routing must use until a restart)."""
        return self._built_for if self._built_for is not None else self.plant

    def row(self, target: int) -> np.ndarray | None:
        """Distances of every node index to ``target``; None while a first-use row is queued."""
        i = self._rows.get(target)
        if i is not None:
            return self._matrix[i]
        late = self._late.get(target)
        if late is not None:
            return late
        if self._built_for is None:
            # outside a runtime: its startup builds the table (for a single row of exact
            # distances without one, distances_to(plant, [target]))
            raise RuntimeError(
                "the heuristic table is built at startup: add it to a runtime's task and "
                "start the runtime first (or use distances_to(plant, targets))"
            )
        self._built_for.idx(target)
        if target not in self._queued:
            self._queued.append(target)
        return None

    def has_row(self, target: int) -> bool:
        """Are the distances to ``target`` at hand (without queueing a row)?"""
        return target in self._rows or target in self._late

    def distance(self, node: int, target: int) -> float | None:
        """Exact distance node -> target (ids), None while the row is being computed."""
        row = self.row(target)
        return None if row is None else float(row[self._built_for.idx(node)])
