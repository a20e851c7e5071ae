"""ReservationMatrix: which vehicle holds which node, and so which segments are occupied.

The thesis (5.3) keeps an occupancy matrix of segments for t0 and t_next, built from the
positions every vehicle broadcasts, and replans when the next segment is taken by an
oncoming vehicle. Reports give no position inside a segment, so this block reserves
nodes: a vehicle holds the node it last reported (t0) and every node released to it and not
yet passed (t_next, up to the release horizon). A node has at most one holder, and a
vehicle is only ever between nodes it holds, so:

* two vehicles never occupy one node at once (the holder is the only one there), and
* two vehicles never drive one segment head-on (each would hold both of its ends).

A vehicle follows another closely: it may enter a node as soon as the one ahead reports it
has left that node's crossing zone (the ``clear`` bit of its status), while that one still
drives the segment beyond, holding the node at its end. The segment matrix (``segments``: who is on which segment, in
which direction) and the per-arc penalties for the A* block are derived from the holds.
Holds follow the reports, but only along what a vehicle was given: a report of a held node
passes every held node before it. A report of anything else (a jump, a node held by
another vehicle, ``clear`` where nothing was released beyond) is never applied to any
vehicle's holds: :meth:`plausible` says why, and the vehicle's control treats the vehicle
as suspect. A vehicle's first report, while it holds nothing, takes its start node if the
node is free. Only an operator who has looked can move a suspect vehicle's holds to where
it really is (:meth:`relocate`).

Single-vehicle areas (plant key ``area``: a transfer station and the node in front of it, a
corridor) hold at most one vehicle in all of their nodes. A vehicle **occupies** an area
while it holds one of its nodes, or has reported one and not yet reached the next node
(``cleared``: it drives the segment out of the area). A node of an area is taken (released,
granted, claimed) by a vehicle only if it occupies the area already or nobody does; the
vehicle it then waits for is the occupant (:meth:`blocker`), so the waits-for graph runs
through areas. A vehicle's true position is always between nodes it holds, or on the
segment from its ``cleared`` node to its first held node, so a vehicle never truly stands
or drives in an area another vehicle occupies, segments into and out of the area included.
Every node's area index is computed once (``area_of``), and who occupies which area is
updated when a vehicle's holds change, so each check is a lookup. Only a start report or an
operator's relocation can put a second vehicle into an occupied area (that is where they
really are); both may then move on inside it, and nobody else enters until both have left.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from blocks.routing.constraints import highway_penalty
from plc_runtime import CycleContext, FunctionBlock, Output
from topology import Plant

FREE = -1

# the states of a vehicle out of service (never heard from, silent, faulty, suspect): it
# stands where it is and makes no way, whatever it holds, until it is back
OUT_OF_SERVICE = frozenset(("offline", "stale", "fault", "suspect"))

NO_AREA = -1


class ReservationMatrix(FunctionBlock):
    occupied_nodes = Output(0, doc="nodes held by a vehicle")
    refused_reports = Output(0, doc="reports not along the reporting vehicle's holds (ignored)")

    def __init__(
        self,
        plant: Plant,
        vehicles: Iterable[int],
        occupied_penalty: float = 0.0,
        oncoming_penalty: float | None = None,
        contraflow_penalty: float = 0.0,
        highway_factor: float = 1.0,
        starts: Mapping[int, int] | None = None,
    ) -> None:
        """``starts``: vehicle -> the node id it is configured to start on, held for it
        from the start, so that the node it may stand on is never released to another
        vehicle before its first report (nor after a forged first report elsewhere,
        which is then implausible)."""
        super().__init__()
        self.plant = plant
        self.vehicles = sorted(vehicles)
        self.holder = np.full(plant.n, FREE, dtype=np.int64)
        self.holds: dict[int, list[int]] = {v: [] for v in self.vehicles}  # node indices, in order
        self.wants: dict[int, int | None] = dict.fromkeys(self.vehicles)  # node index waited for
        self.intent: dict[int, int | None] = dict.fromkeys(self.vehicles)  # next planned node
        self.cleared: dict[int, int | None] = dict.fromkeys(self.vehicles)  # reported, not held
        # node index -> the standing vehicle told to wait for it (set by the resolver each scan)
        self.awaited: dict[int, int] = {}
        self.moving_on: set[int] = set()  # standing vehicles told to move, waiting for the node
        # vehicles out of service (offline, stale, fault, suspect): their holds stay, but
        # whatever they hold, they make no way (set by each vehicle's control every scan)
        self.out_of_service: set[int] = set()
        # single-vehicle areas: node index -> area index (NO_AREA: none; a list, as single
        # elements are read faster from it than from an array), and per area the vehicles
        # occupying it (normally at most one)
        self.area_names = list(plant.areas)
        self.area_of = [NO_AREA] * plant.n
        for a, name in enumerate(self.area_names):
            for n in plant.areas[name]:
                self.area_of[plant.index[n]] = a
        self.occupants: list[set[int]] = [set() for _ in self.area_names]
        self._presence: dict[int, frozenset[int]] = {v: frozenset() for v in self.vehicles}
        for v, node_id in sorted((starts or {}).items()):
            node = plant.index[node_id]
            if v in self.holds and self.holder[node] == FREE:
                self.holds[v].append(node)
                self.holder[node] = v
        self._awaited_area: dict[int, int] = {}  # area index -> the standing vehicle awaiting it
        src, dst, length = plant.arcs
        longest = float(length.max()) if len(length) else 1.0
        # An oncoming vehicle on the next segment is the thesis' "very high extra weight":
        # any detour is preferred. Nodes merely occupied now cost nothing extra by default:
        # by the time a vehicle gets there they have usually moved on (and queueing behind
        # is the thesis' level 1); a penalty makes routes avoid crowded areas instead.
        self.occupied_penalty = occupied_penalty
        self.oncoming_penalty = (
            oncoming_penalty if oncoming_penalty is not None else 1000 * longest * plant.n
        )
        # Every vehicle's planned route, as arcs, counted per arc: a vehicle planning against
        # the planned flow of others will meet them head-on in a single-lane aisle, so each
        # opposing route costs ``contraflow_penalty`` per arc (a route along the flow is free)
        self.contraflow_penalty = contraflow_penalty
        # the plant's highways: an arc against its lane's preferred direction costs
        # ``highway_factor`` times its length, i.e. this much more, whoever else is about
        self.highway_penalty = highway_penalty(plant, highway_factor)
        self.flow = np.zeros(len(src) + 1, dtype=np.float64)  # last: no reverse arc
        arc_of = {(int(u), int(v)): arc for arc, (u, v) in enumerate(zip(src, dst, strict=True))}
        self._arc_of = arc_of
        self._reverse = np.array(
            [arc_of.get((int(v), int(u)), len(src)) for u, v in zip(src, dst, strict=True)],
            dtype=np.int64,
        )
        self._planned: dict[int, list[int]] = {v: [] for v in self.vehicles}
        self._planned_nodes: dict[int, list[int]] = {v: [] for v in self.vehicles}
        order = np.argsort(dst, kind="stable")
        self._in_arcs_order = order
        self._in_arcs_start = np.searchsorted(dst[order], np.arange(plant.n + 1))

    def cycle(self, ctx: CycleContext) -> None:
        self.occupied_nodes = int((self.holder != FREE).sum())

    # ----- holds --------------------------------------------------------------------------
    def plausible(self, vehicle: int, node: int, clear: bool = False) -> str | None:
        """Why a report of node index ``node`` cannot be applied, or None if it can: the
        held node, a node released to it (passing those before), the node it has already
        left, or, holding nothing yet, a free node (its start position)."""
        held = self.holds[vehicle]
        ids = self.plant.ids
        if node in held:
            if clear and held.index(node) == len(held) - 1:
                return f"clear of node {ids[node]}, but nothing was released beyond it"
            return None
        if self.cleared[vehicle] == node or (not held and self.holder[node] == FREE):
            return None
        other = int(self.holder[node])
        where = f"holds {', '.join(str(ids[n]) for n in held)}" if held else "holds nothing"
        if other != FREE:
            return f"reports node {ids[node]}, held by vehicle {other} ({where})"
        return f"reports node {ids[node]}, never released to it ({where})"

    def refuse(self) -> None:
        """A report that was not :meth:`plausible` was seen (and not applied)."""
        self.refused_reports += 1

    def report(self, vehicle: int, node: int, clear: bool = False) -> bool:
        """The vehicle reported node index ``node`` as its current node (the last one it
        reached); ``clear``: it has left that node's crossing zone, so the node is free for
        the next vehicle although it is still the one reported. A report that is not
        :meth:`plausible` changes nothing, is counted, and returns False."""
        if self.plausible(vehicle, node, clear) is not None:
            self.refuse()
            return False
        held = self.holds[vehicle]
        if node in held:
            k = held.index(node) + (1 if clear else 0)
            for passed in held[:k]:
                self.holder[passed] = FREE
            del held[:k]
            self.cleared[vehicle] = node if k and held[0] != node else None
        elif not held:
            held.append(node)  # its start position
            self.holder[node] = vehicle
            self.cleared[vehicle] = None
        self._sync_areas(vehicle)
        return True

    def relocate(self, vehicle: int, node: int, cleared: int | None = None) -> str | None:
        """An operator confirmed where the vehicle really is: at node index ``node``, or,
        with ``cleared``, on its way there from the node index ``cleared`` it has left. Its
        holds move to ``node`` if that is free (or its own). Returns why not, or None."""
        other = int(self.holder[node])
        if other != FREE and other != vehicle:
            return f"node {self.plant.ids[node]} is held by vehicle {other}"
        if cleared is not None and (other := self._on_segment(cleared, node, vehicle)):
            ids = self.plant.ids
            return f"vehicle {other} is on the segment {ids[cleared]}-{ids[node]}"
        for n in self.holds[vehicle]:
            self.holder[n] = FREE
        self.holds[vehicle][:] = [node]
        self.holder[node] = vehicle
        self.cleared[vehicle] = cleared
        self._sync_areas(vehicle)
        return None

    def _on_segment(self, a: int, b: int, vehicle: int) -> int | None:
        """Another vehicle than ``vehicle`` between node indices ``a`` and ``b`` (either
        way): released from one into the other, or clear of one on its way to the other;
        None if there is none. (A relocation onto that segment would put the two on it
        together, head-on or nose to tail.)"""
        pair = {a, b}
        for other, held in self.holds.items():
            if other == vehicle or not held:
                continue
            steps = zip([self.cleared[other], *held], held, strict=False)  # (one less)
            if any({x, y} == pair for x, y in steps):
                return other
        return None

    def holder_of(self, node: int) -> int | None:
        h = int(self.holder[node])
        return None if h == FREE else h

    def area_blocker(self, vehicle: int, node: int) -> int | None:
        """Another vehicle occupying the single-vehicle area of node index ``node``, unless
        ``vehicle`` occupies it itself (it may go on inside it); None: the area is its own,
        free, or ``node`` is in none. The lowest id if several (deterministic)."""
        a = self.area_of[node]
        if a == NO_AREA:
            return None
        inside = self.occupants[a]
        if not inside or vehicle in inside:
            return None
        return min(inside)

    def blocker(self, vehicle: int, node: int) -> int | None:
        """The vehicle ``vehicle`` must wait for before taking node index ``node``: the
        node's holder, else the occupant of its area; None: it may take the node now."""
        h = int(self.holder[node])
        if h != FREE and h != vehicle:
            return h
        return self.area_blocker(vehicle, node)

    def may_enter(self, vehicle: int, node: int) -> tuple[bool, int | None]:
        """May ``vehicle`` be released into node index ``node`` now? (ok, blocking vehicle)."""
        b = self.blocker(vehicle, node)
        return b is None, b

    def set_awaited(self, awaited: dict[int, int]) -> None:
        """The resolver's decisions of this scan: node index -> the standing vehicle told to
        go there once its holder has left. Their areas are awaited with them."""
        self.awaited = awaited
        self.moving_on = set(awaited.values())
        self._awaited_area = {
            self.area_of[n]: v for n, v in awaited.items() if self.area_of[n] != NO_AREA
        }

    def awaited_by(self, vehicle: int, node: int) -> int | None:
        """The standing vehicle, other than ``vehicle``, waiting for node index ``node``, or
        for a node of its single-vehicle area (unless ``vehicle`` occupies that area: it may
        go on inside it, and must, to leave it)."""
        w = self.awaited.get(node)
        if w is not None and w != vehicle:
            return w
        a = self.area_of[node]
        w = self._awaited_area.get(a) if a != NO_AREA else None
        if w is None or w == vehicle or vehicle in self.occupants[a]:
            return None
        return w

    def making_way(self, vehicle: int) -> bool:
        """Is ``vehicle`` driving (released beyond its node) or told to move on? Not while
        it is out of service: one that fell silent or stalled mid-route keeps the nodes
        ahead of it, and whoever waits for them must replan in time, not wait for ever."""
        if vehicle in self.out_of_service:
            return False
        return len(self.holds[vehicle]) > 1 or vehicle in self.moving_on

    def claim(self, vehicle: int, node: int) -> None:
        """Node index ``node`` is released to ``vehicle``. Every caller checked
        :meth:`blocker` first; a claim against it is a programming error, not a wait."""
        h = int(self.holder[node])
        if h != FREE and h != vehicle:
            raise RuntimeError(f"node {self.plant.ids[node]} is held by vehicle {h}")
        other = self.area_blocker(vehicle, node)
        if other is not None:
            name = self.area_names[self.area_of[node]]
            raise RuntimeError(
                f"node {self.plant.ids[node]}: area {name!r} is occupied by vehicle {other}"
            )
        self.holder[node] = vehicle
        self.holds[vehicle].append(node)
        self._sync_areas(vehicle)

    def _sync_areas(self, vehicle: int) -> None:
        """Update which areas ``vehicle`` occupies from its holds and the node it has
        cleared (a few nodes: bounded work)."""
        if not self.area_names:
            return
        area_of = self.area_of
        now = {area_of[n] for n in self.holds[vehicle]}
        cleared = self.cleared[vehicle]
        if cleared is not None:
            now.add(area_of[cleared])
        now.discard(NO_AREA)
        before = self._presence[vehicle]
        if now == before:
            return
        for a in before - now:
            self.occupants[a].discard(vehicle)
        for a in now - before:
            self.occupants[a].add(vehicle)
        self._presence[vehicle] = frozenset(now)

    def held_by(self, vehicle: int) -> list[int]:
        return list(self.holds[vehicle])

    # ----- the matrix and penalties -------------------------------------------------------------
    def segments(self) -> list[tuple[int, int, int]]:
        """(from id, to id, vehicle) for every segment a vehicle is on or released into."""
        ids = self.plant.ids
        out = []
        for v, held in self.holds.items():
            for a, b in zip(held, held[1:], strict=False):
                out.append((int(ids[a]), int(ids[b]), v))
        return out

    def plan(self, vehicle: int, nodes: list[int]) -> None:
        """The node indices ``vehicle`` plans to drive, from where it is: its share of the
        planned flow. A vehicle passing a node only shortens its route from the front, and
        then only the arcs it passed leave the flow: a route of a hundred arcs is not
        counted out and in again at every node."""
        arcs, before = self._planned[vehicle], self._planned_nodes[vehicle]
        passed = len(before) - len(nodes)
        if passed >= 0 and before[passed:] == nodes:
            gone = self._arcs_along(before[: passed + 1])
            del arcs[: len(gone)]
        else:
            gone, arcs[:] = arcs[:], self._arcs_along(nodes)
            for arc in arcs:
                self.flow[arc] += 1
        for arc in gone:
            self.flow[arc] -= 1
        self._planned_nodes[vehicle] = nodes

    def _arcs_along(self, nodes: list[int]) -> list[int]:
        arc_of = self._arc_of
        return [
            arc
            for a, b in zip(nodes, nodes[1:], strict=False)
            if (arc := arc_of.get((a, b))) is not None
        ]

    def in_arcs(self, node: int) -> np.ndarray:
        return self._in_arcs_order[self._in_arcs_start[node] : self._in_arcs_start[node + 1]]

    def penalties_for(
        self, vehicle: int, out: np.ndarray, oncoming: tuple[int, int] | None = None
    ) -> np.ndarray:
        """Fill ``out`` (one value per arc) with the extra costs ``vehicle`` should plan with:
        every arc against another vehicle's planned route costs ``contraflow_penalty`` more
        per such route, every arc into a node another vehicle holds ``occupied_penalty`` more,
        and the
        segment ``oncoming`` (from, to indices) the thesis' very high extra weight; and
        every arc against a highway its ``highway_penalty``."""
        out[:] = self.highway_penalty
        if self.contraflow_penalty > 0:
            out += self.contraflow_penalty * self.flow[self._reverse]
            own = self._reverse[self._planned[vehicle]]
            out[own[own < len(out)]] -= self.contraflow_penalty
        if self.occupied_penalty > 0:
            taken = np.flatnonzero((self.holder != FREE) & (self.holder != vehicle))
            for node in taken:
                out[self.in_arcs(int(node))] += self.occupied_penalty
        if oncoming is not None:
            ids = self.plant.ids
            for arc in self.plant.arc_index.get((int(ids[oncoming[0]]), int(ids[oncoming[1]])), []):
                out[arc] += self.oncoming_penalty
        return out
