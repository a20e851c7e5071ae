"""IncrementalAStar: A* cut into bounded per-cycle steps that publishes only complete routes.

Thesis section 4.4: the A* loop is cut open (an IF instead of a WHILE) so the time a cycle
spends on path finding depends only on the budget and the degree of the expanded nodes,
never on the length of the route or the size of the plant. The search state lives in the
block's instance data between cycles; the outputs change only when a search ends, so a
vehicle can never follow a half-computed route (thesis 4.4.2).

Per cycle the block expands up to ``budget`` nodes (default 1, exactly as in the thesis) and,
if ``budget_us`` is set, stops earlier when that much real time of the cycle is used (at
least one expansion per cycle, so a search always progresses); it never runs past the
task's deadline on a clock where time passes during a scan (the wall clock). On the virtual
clock that deadline never comes, so a search with ``budget_us`` unset does the same work in
every run, however busy the host. Open list: a binary heap with lazy deletion, ties broken
towards the deeper node and then the newest entry, so with the exact heuristic table and no
constraints the search expands exactly the nodes of the route it returns (thesis 3.5.2).
Every heuristic offered is admissible: the exact table under blockades and penalties
(which only make arcs dearer), and the Euclidean and Manhattan fallbacks scaled to the
plant's shortest segment-to-distance ratio. They are also consistent, except for the
table's float32 rounding; so a closed node is re-opened if a cheaper path to it turns up,
which keeps routes optimal and, with consistent values, never happens.
"""

from __future__ import annotations

import heapq
import math

import numpy as np

from blocks.standard import R_TRIG
from plc_runtime import CycleContext, FunctionBlock, Input, Output, Static
from topology import Plant

from .constraints import RoutingConstraints
from .heuristic import HeuristicTable

HEURISTICS = ("table", "euclidean", "manhattan", "zero")


class IncrementalAStar(FunctionBlock):
    request = Input(False, doc="a rising edge starts a search (aborting a running one)")
    start = Input(None, doc="start node id")
    goal = Input(None, doc="goal node id")
    budget = Input(1, doc="node expansions per cycle (None: bounded by budget_us only)")
    budget_us = Input(None, doc="real time per cycle in microseconds (None: expansions only)")

    busy = Output(False)
    done = Output(False, doc="a search ended: with a route, or with no_route")
    no_route = Output(False)
    route = Output((), doc="node ids start..goal of the last completed search")
    cost = Output(0.0)
    expansions = Output(0, doc="nodes expanded by the last completed search")
    cycles = Output(0, doc="cycles the last completed search took")
    error = Output(None, doc="why the last request could not be searched")
    expansions_last_cycle = Output(0)

    # search state: instance data between cycles, never visible on the outputs
    open_heap = Static([])
    g_best = Static({})
    parent = Static({})
    closed = Static(set())
    counter = Static(0)
    search_goal = Static(-1)
    search_expansions = Static(0)
    search_cycles = Static(0)

    def __init__(
        self,
        plant: Plant,
        table: HeuristicTable | None = None,
        heuristic: str = "table",
        constraints: RoutingConstraints | None = None,
    ) -> None:
        super().__init__()
        if heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, got {heuristic!r}")
        if heuristic == "table" and table is None:
            raise ValueError(
                "heuristic 'table' needs a HeuristicTable (or choose euclidean/manhattan/zero)"
            )
        self.plant = plant
        self.table = table
        self.heuristic = heuristic
        self.constraints = constraints
        self.trigger = R_TRIG()
        self._h_row: np.ndarray | None = None

    # ----- startup and the scan --------------------------------------------------------
    def startup(self, ctx: CycleContext) -> None:
        """Build the adjacency structures now: in the startup phase, not in the first cycle
        (for a 1e4-node plant that is tens of milliseconds)."""
        plant = self._plant()
        _ = plant.index, plant.ids, plant.neighbors
        if self.heuristic in ("euclidean", "manhattan"):
            _ = plant.positions, plant.heuristic_scale

    def cycle(self, ctx: CycleContext) -> None:
        self.expansions_last_cycle = 0
        if self.trigger(ctx, CLK=self.request):
            self._begin()
        if not self.busy:
            return
        self.search_cycles += 1
        if self.heuristic == "table" and self._h_row is None:
            # the goal the search started with: the input may have changed since the edge
            self._h_row = self.table.row(int(self._plant().ids[self.search_goal]))
            if self._h_row is None:
                return  # the table computes this goal's row first (one cycle)
        self._expand(ctx)

    def _plant(self) -> Plant:
        return self.table.served_plant if self.table is not None else self.plant

    def _begin(self) -> None:
        """Reset the search; the outputs show 'busy' and no route until it ends."""
        self.busy, self.done, self.no_route, self.error = True, False, False, None
        self.route, self.cost, self.expansions, self.cycles = (), 0.0, 0, 0
        self.open_heap, self.g_best, self.parent, self.closed = [], {}, {}, set()
        self.search_expansions = self.search_cycles = self.counter = 0
        self._h_row = None
        plant = self._plant()
        for name in ("start", "goal"):
            node = getattr(self, name)
            if (
                isinstance(node, bool)
                or not isinstance(node, int | np.integer)
                or node not in plant.index
            ):
                self._finish_without_route(f"unknown {name} node {node!r}")
                return
        start = plant.index[self.start]
        self.search_goal = plant.index[self.goal]
        self.g_best[start] = 0.0
        self.open_heap.append((0.0, -0.0, 0, start))

    def _expand(self, ctx: CycleContext) -> None:
        plant = self._plant()
        neighbors = plant.neighbors
        blocked = self.constraints.blocked if self.constraints is not None else None
        penalty = self.constraints.penalty if self.constraints is not None else None
        h = self._heuristic(plant)
        heap, g_best, parent, closed = self.open_heap, self.g_best, self.parent, self.closed
        goal = self.search_goal
        limit = self.budget if self.budget is not None else math.inf
        stop_at = None if self.budget_us is None else ctx.elapsed_ns() + self.budget_us * 1000
        n = 0
        while n < limit:
            if n and (ctx.expired() or (stop_at is not None and ctx.elapsed_ns() >= stop_at)):
                break
            if not heap:
                self.expansions_last_cycle = n
                self._finish_without_route(None)
                return
            _f, neg_g, _tie, u = heapq.heappop(heap)
            if u in closed or -neg_g > g_best[u]:
                continue  # lazy deletion: a stale entry (expanded already, or a cheaper one is queued)
            closed.add(u)
            n += 1
            self.search_expansions += 1
            if u == goal:
                self.expansions_last_cycle = n
                self._publish(plant, u)
                return
            g_u = g_best[u]
            for v, arc, length in neighbors[u]:
                if blocked is not None and blocked[arc]:
                    continue
                g_v = g_u + length + (penalty[arc] if penalty is not None else 0.0)
                if g_v < g_best.get(v, math.inf):
                    h_v = h(v)
                    if h_v == math.inf:
                        continue  # the goal cannot be reached from v at all
                    # A cheaper path to an expanded node re-opens it: the float32 table is
                    # admissible but, rounded, not exactly consistent, and optimality must hold.
                    closed.discard(v)
                    g_best[v] = g_v
                    parent[v] = u
                    self.counter += 1
                    heapq.heappush(heap, (g_v + h_v, -g_v, -self.counter, v))
        self.expansions_last_cycle = n
        if not heap:
            self._finish_without_route(None)  # nothing left to expand: known now, not next cycle

    def _heuristic(self, plant: Plant):
        if self.heuristic == "table":
            row = self._h_row
            return lambda v: float(row[v])
        if self.heuristic == "zero":
            return lambda v: 0.0
        pos = plant.positions
        gx, gy = pos[self.search_goal]
        scale = plant.heuristic_scale[self.heuristic]
        if self.heuristic == "euclidean":
            return lambda v: scale * math.hypot(pos[v, 0] - gx, pos[v, 1] - gy)
        return lambda v: scale * (abs(pos[v, 0] - gx) + abs(pos[v, 1] - gy))

    # ----- results ----------------------------------------------------------------------
    def _publish(self, plant: Plant, goal: int) -> None:
        path = [goal]
        while path[-1] in self.parent:
            path.append(self.parent[path[-1]])
        ids = plant.ids
        self.route = tuple(int(ids[i]) for i in reversed(path))
        self.cost = float(self.g_best[goal])
        self.expansions, self.cycles = self.search_expansions, self.search_cycles
        self.busy, self.done, self.no_route = False, True, False
        self._release_search()

    def _finish_without_route(self, error: str | None) -> None:
        self.route, self.cost = (), 0.0
        self.expansions, self.cycles = self.search_expansions, self.search_cycles
        self.busy, self.done, self.no_route, self.error = False, True, True, error
        self._release_search()

    def _release_search(self) -> None:
        self.open_heap, self.g_best, self.parent, self.closed = [], {}, {}, set()
