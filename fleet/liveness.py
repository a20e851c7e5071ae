"""Does a fleet configuration meet the documented liveness condition (docs/fleet-config.md)?

Safety holds on every plant; the claim that every recipe completes within a bound is only
made for configurations that meet the condition. A user whose configuration breaks it
should hear so at start, clause by clause, rather than find vehicles waiting for ever.

Also here, refused rather than warned about: a vehicle whose next recipe step needs the
function of the station it is already standing on, where that function has a single
station, would "complete" the step without moving (:func:`standing_steps`); and a vehicle
whose start leads nowhere it is needed, past one-way segments, would stand there for the
whole run (:func:`stranded_starts`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from topology import Plant

if TYPE_CHECKING:
    from .config import FleetConfig

NODES_PER_VEHICLE = 10  # at most 10 % as many vehicles as nodes, counted in whole numbers


def violations(cfg: FleetConfig) -> list[str]:
    """The clauses of the liveness condition that ``cfg`` breaks, one sentence each."""
    plant = cfg.plant
    out = []
    one_way = _one_way_segments(plant)
    if one_way:
        shown = ", ".join(f"{a}->{b}" for a, b in one_way[:3])
        more = f" and {len(one_way) - 3} more" if len(one_way) > 3 else ""
        out.append(f"one-way segments ({shown}{more})")
    cuts = articulation_points(plant)
    if cuts:
        shown = ", ".join(str(n) for n in cuts[:3])
        more = f" and {len(cuts) - 3} more" if len(cuts) > 3 else ""
        out.append(f"not 2-connected: losing node {shown}{more} disconnects the plant")
    if (crowd := _crowded(len(cfg.starts), plant.n)) is not None:
        out.append(crowd)
    needed = sorted({f for r in cfg.recipes.values() for f in r.functions})
    single = [f for f in needed if len(cfg.clusters.get(f, ())) < 2]
    if single:
        out.append(f"function(s) {', '.join(map(str, single))} offered by one station only")
    repeats = sorted({f for _v, _k, f in _repeated_functions(cfg)})
    if repeats:
        out.append(
            f"a vehicle's consecutive steps need the same function ({', '.join(map(str, repeats))})"
        )
    if any(b.until_s is None for b in cfg.blockades):
        out.append("a blockade that never reopens")
    if cfg.order_vehicles and cfg.battery.enabled and not plant.with_role("charger"):
        out.append(
            "batteries on and no charger (role 'charger'): a vehicle below the 'good' "
            "threshold takes no order and cannot recharge"
        )
    if cfg.traffic == "time_windows" and cfg.order_vehicles:
        parking = len(plant.with_role("parking")) if cfg.dispatch.park else 0
        if parking < len(cfg.order_vehicles):
            out.append(
                f"time-window traffic moves no idle vehicle aside, and {parking} parking "
                f"position(s) for {len(cfg.order_vehicles)} vehicles taking orders: an idle "
                "vehicle may stand on another's only way"
            )
    return out


def standing_steps(cfg: FleetConfig) -> list[str]:
    """Recipe steps a vehicle would complete where it stands: the same function twice in a
    row with a single station offering it. Each is a configuration error."""
    problems = []
    # a recipe that ends at an exit with a return lane drives it back to the entry: the
    # same exit again as the next recipe's first step is a whole lap, not a step
    # completed standing (within one recipe it is)
    lapped = {e.source for e in cfg.plant.edges if not e.routable}
    lapped |= {e.target for e in cfg.plant.edges if not e.routable and e.bidirectional}
    for v, k, f in _repeated_functions(cfg):
        stations = cfg.clusters.get(f, [])
        if len(stations) != 1:
            continue
        ends, steps = _recipe_ends(cfg, v)
        after_a_recipe = (k - 1) % len(steps) in ends  # (k = 0: after the last recipe)
        if not (after_a_recipe and stations[0] in lapped):
            station = stations[0]
            problems.append(
                f"vehicle {v}: step {k + 1} of its recipe sequence needs function {f} again, "
                f"and only station {station} offers it: the vehicle would complete the step "
                "without moving (put another function between the two)"
            )
    return problems


def stranded_starts(cfg: FleetConfig) -> list[str]:
    """Vehicles that can never do their work from where they start: one-way segments lead
    away from every station a step of their recipes needs (in the order the steps come,
    from any station of the step before), or, for a vehicle taking transport orders, from
    every station. Each is a configuration error: the vehicle would report no route for
    the whole run, and the run would end as if all were well."""
    plant = cfg.plant
    index = plant.index
    # recipes: return lanes count (a recipe that ends at an exit drives one back); orders:
    # only what routing drives
    recipes, orders = _Reach(plant, return_lanes=True), _Reach(plant, return_lanes=False)
    if recipes.connected and orders.connected:
        return []
    stations = {f: [index[s] for s in nodes] for f, nodes in cfg.clusters.items()}
    get_put = [index[s] for s in plant.with_role("station")]  # what an order may name
    problems = []
    for v, start in sorted(cfg.starts.items()):
        here = [index[start]]
        if v not in cfg.vehicle_recipes:
            reached = orders.reach(here)
            reached[here[0]] = False
            if get_put and not reached[get_put].any():
                problems.append(
                    f"vehicle {v}: no station can be reached from its start node {start} "
                    "(one-way segments lead away from every one): it could take no order"
                )
            continue
        steps = [f for name in cfg.vehicle_recipes[v] for f in cfg.recipes[name].functions]
        for k, f in enumerate(steps):
            reached = recipes.reach(here)
            here = [i for i in stations.get(f, ()) if reached[i]]
            if not here:
                after = f"its start node {start}" if k == 0 else f"any station of step {k}"
                problems.append(
                    f"vehicle {v}: step {k + 1} of its recipe sequence needs function {f}, "
                    f"and no station offering it can be reached from {after} (one-way "
                    "segments lead away): the vehicle could never complete it"
                )
                break
    return problems


class _Reach:
    """Which nodes each node reaches along the plant's directed segments, computed once per
    strong component (every node of one reaches the same)."""

    def __init__(self, plant: Plant, return_lanes: bool) -> None:
        n, index = plant.n, plant.index
        src, dst = [], []
        for e in plant.edges:
            if not (e.routable or return_lanes):
                continue
            src.append(index[e.source])
            dst.append(index[e.target])
            if e.bidirectional:
                src.append(index[e.target])
                dst.append(index[e.source])
        self.n = n
        self.graph = csr_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(n, n))
        count, self.label = connected_components(self.graph, directed=True, connection="strong")
        self.connected = count == 1
        self._of: dict[int, np.ndarray] = {}  # a strong component's label -> what it reaches

    def reach(self, nodes: list[int]) -> np.ndarray:
        seen = np.zeros(self.n, dtype=bool)
        for node in nodes:
            c = int(self.label[node])
            if c not in self._of:
                found = np.zeros(self.n, dtype=bool)
                order = breadth_first_order(
                    self.graph, node, directed=True, return_predecessors=False
                )
                found[order] = True
                self._of[c] = found
            seen |= self._of[c]
        return seen


def _recipe_ends(cfg: FleetConfig, vehicle: int) -> tuple[set[int], list[int]]:
    """The indices of a vehicle's steps (its recipes one after the other) that end a
    recipe, and the steps' functions."""
    steps: list[int] = []
    ends = set()
    for name in cfg.vehicle_recipes[vehicle]:
        steps += cfg.recipes[name].functions
        ends.add(len(steps) - 1)
    return ends, steps


def _repeated_functions(cfg: FleetConfig) -> Iterator[tuple[int, int, int]]:
    """(vehicle, step index, function) where a step needs the function of the step before,
    counting from the last step of a round to the first of the next when rounds repeat."""
    for v, names in cfg.vehicle_recipes.items():
        steps = [f for name in names for f in cfg.recipes[name].functions]
        cyclic = cfg.rounds != 1
        for k, f in enumerate(steps):
            if k == 0 and not cyclic:
                continue
            if steps[k - 1] == f:  # k == 0: the last step of the round before
                yield v, k, f


def _crowded(n_vehicles: int, n_nodes: int) -> str | None:
    """The clause on the share of vehicles, if broken: said with the plant size the fleet
    needs, which helps where "at most N vehicles" would tell a small plant "at most 0"."""
    if n_vehicles * NODES_PER_VEHICLE <= n_nodes:
        return None
    vehicles = f"{n_vehicles} vehicle{'s' if n_vehicles != 1 else ''}"
    return (
        f"{vehicles} on {n_nodes} nodes, more than 1 vehicle per {NODES_PER_VEHICLE} nodes "
        f"(at least {n_vehicles * NODES_PER_VEHICLE} nodes for {vehicles})"
    )


def _one_way_segments(plant: Plant) -> list[tuple[int, int]]:
    arcs = plant.arc_index
    return sorted((a, b) for (a, b) in arcs if (b, a) not in arcs)


def articulation_points(plant: Plant) -> list[int]:
    """Nodes whose removal disconnects the (undirected) plant graph; iterative Tarjan.
    Built from the arcs, not the length matrix, whose sum would drop segments of length 0."""
    n = plant.n
    src, dst, _ = plant.arcs
    ones = np.ones(2 * len(src), dtype=np.int8)
    adj = csr_matrix((ones, (np.concatenate([src, dst]), np.concatenate([dst, src]))), shape=(n, n))
    indptr, indices = adj.indptr, adj.indices
    disc = np.full(n, -1)
    low = np.zeros(n, dtype=np.int64)
    cut = np.zeros(n, dtype=bool)
    timer = 0
    for root in range(n):
        if disc[root] >= 0:
            continue
        disc[root] = low[root] = timer
        timer += 1
        children = 0
        stack = [(root, -1, int(indptr[root]))]
        while stack:
            node, parent, i = stack[-1]
            if i < indptr[node + 1]:
                stack[-1] = (node, parent, i + 1)
                nxt = int(indices[i])
                if nxt == parent or nxt == node:
                    continue
                if disc[nxt] < 0:
                    disc[nxt] = low[nxt] = timer
                    timer += 1
                    if node == root:
                        children += 1
                    stack.append((nxt, node, int(indptr[nxt])))
                else:
                    low[node] = min(low[node], disc[nxt])
            else:
                stack.pop()
                if parent >= 0:
                    low[parent] = min(low[parent], low[node])
                    if parent != root and low[node] >= disc[parent]:
                        cut[parent] = True
        if children > 1:
            cut[root] = True
    return [int(plant.ids[i]) for i in np.flatnonzero(cut)]
