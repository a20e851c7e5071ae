"""DeadlockResolver: finds vehicles waiting for each other in a circle, and breaks the circle.

The thesis leaves one case open (5.3.1): when the only remaining path is occupied, two
vehicles can wait for each other forever. Every scan this block builds the waits-for graph
(each waiting vehicle points at the vehicle holding the node it waits for; one edge per
vehicle, so cycles are found by walking, O(vehicles)) and resolves every cycle at once,
deterministically: the vehicles of the cycle and those queued behind them are tried from
the lowest priority up (priority: the older step goes first, then the lower id); the first
that has a free neighbour node backs off to it, which frees its node for the others. A
vehicle that is idle (no goal) and blocks a waiting vehicle is moved aside the same way.
A cycle nobody in it can leave is reported (``unresolved``) and retried every scan: a
blockade may clear, a vehicle may come back online. Every detection is recorded.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from plc_runtime import CycleContext, FunctionBlock, Output
from topology import Plant

from .constraints import RoutingConstraints
from .reservation import ReservationMatrix
from .vehicle_control import VehicleControl

IDLE_PUSH_AFTER_NS = 1_000_000_000
MAX_BACK_OFFS = 12  # per cycle of vehicles that makes no progress: then it is a livelock


@dataclass(frozen=True)
class DeadlockEvent:
    time_s: float
    vehicles: tuple[int, ...]  # the cycle, in waits-for order
    backed_off: int | None  # None: nobody could move (unresolved)
    to_node: int | None


class DeadlockResolver(FunctionBlock):
    detected = Output(0, doc="waits-for cycles found")
    resolved = Output(0, doc="back-offs ordered (one cycle may need several)")
    unresolved = Output(0, doc="cycles nobody could leave when found (retried every scan)")
    pushes = Output(0, doc="idle vehicles moved aside for a waiting one")

    def __init__(
        self,
        plant: Plant,
        controls: Mapping[int, VehicleControl],
        reservation: ReservationMatrix,
        blockades: RoutingConstraints,
        priority: Callable[[int], tuple[int, int]],
    ) -> None:
        super().__init__()
        self.plant = plant
        self.controls = dict(controls)
        self.reservation = reservation
        self.blockades = blockades
        self.priority = priority  # smaller is more urgent
        self.events: list[DeadlockEvent] = []
        # unresolved cycles already reported, with their members' progress at the time: they
        # stay reported (stranded) until one of them reaches a new recipe step
        self._stuck: dict[frozenset[int], tuple] = {}
        # back-offs per cycle of vehicles while none of them reaches a new recipe step: a
        # plant where giving way only moves the deadlock (a dead-end corridor) is reported
        # as unresolved instead of being shuffled back and forth forever
        self._attempts: dict[frozenset[int], tuple[tuple, int]] = {}

    def cycle(self, ctx: CycleContext) -> None:
        waits = {
            v: c.waiting_for
            for v, c in self.controls.items()
            if c.state == "waiting" and c.waiting_for is not None
        }
        self._stuck = {
            key: progress
            for key, progress in self._stuck.items()
            if progress == tuple(self.priority(v) for v in sorted(key))
        }
        for ring in self._cycles(waits):
            key = frozenset(ring)
            progress = tuple(self.priority(v) for v in sorted(ring))
            if key in self._stuck:
                continue  # reported already; nothing has changed for them
            seen_before = key in self._attempts and self._attempts[key][0] == progress
            if not seen_before:
                self.detected += 1
            seen, tries = self._attempts.get(key, (progress, 0))
            tries = tries if seen == progress else 0
            victim, node = (
                self._back_off_candidate(ring, waits) if tries < MAX_BACK_OFFS else (None, None)
            )
            if victim is None:
                self.unresolved += 1
                self.events.append(DeadlockEvent(ctx.time, tuple(ring), None, None))
                self._stuck[key] = progress
                continue
            self._attempts[key] = (progress, tries + 1)
            vacated = self.controls[victim].current
            self.controls[victim].back_off(
                ctx, node, self._needed_by(set(ring) - {victim}, vacated)
            )
            self.resolved += 1
            self.events.append(DeadlockEvent(ctx.time, tuple(ring), victim, node))
            for v in ring:
                waits.pop(v, None)
        self._push_idle(ctx, waits)

    def stranded(self) -> list[int]:
        """Vehicles in a waits-for cycle nobody could break (for the summary)."""
        return sorted({v for ring in self._stuck for v in ring})

    @staticmethod
    def _cycles(waits: Mapping[int, int]) -> list[list[int]]:
        """Cycles of the functional graph v -> waits[v], each listed once, deterministic."""
        done: set[int] = set()
        rings = []
        for start in sorted(waits):
            path, seen = [], {}
            v = start
            while v in waits and v not in done and v not in seen:
                seen[v] = len(path)
                path.append(v)
                v = waits[v]
            if v in seen:
                rings.append(path[seen[v] :])
            done.update(path)
        return rings

    def _back_off_candidate(
        self, ring: list[int], waits: Mapping[int, int]
    ) -> tuple[int | None, int | None]:
        """Lowest priority first, preferring a vehicle that can step off the others' routes
        (a siding) over one that would only retreat along them (and meet them again)."""
        members = set(ring)
        behind = {v for v, blocker in waits.items() if blocker in members and v not in members}
        order = sorted(members | behind, key=self.priority, reverse=True)
        fallback = None
        for v in order:
            others = self._planned_nodes(members - {v})
            node = self._free_neighbour(v, avoid=others)
            if node is not None:
                return v, node
            if fallback is None:
                node = self._free_neighbour(v)
                if node is not None:
                    fallback = (v, node)
        return fallback or (None, None)

    def _planned_nodes(self, vehicles: set[int]) -> set[int]:
        index = self.plant.index
        return {index[n] for v in vehicles for n in self.controls[v].planned}

    def _needed_by(self, vehicles: set[int], node: int | None) -> Callable[[], int | None]:
        """The first of ``vehicles`` that still plans to pass ``node`` (an id), or None."""

        def needed() -> int | None:
            for v in sorted(vehicles):
                c = self.controls[v]
                if node in c.planned or c.current == node:
                    return v
            return None

        return needed

    def _free_neighbour(self, vehicle: int, avoid: set[int] = frozenset()) -> int | None:
        control = self.controls[vehicle]
        if control.released or control.current is None or control.hold:
            return None  # it is driving already, or processing: not a vehicle to move now
        here = self.plant.index[control.current]
        res = self.reservation
        wanted = res.wants.get(vehicle)
        options = []
        for there, arc, _length in self.plant.neighbors[here]:
            if self.blockades.blocked[arc] or there == wanted or there in avoid:
                continue
            if res.holder_of(there) is None:
                # prefer a node nobody waits for, then the lowest id: deterministic
                waited = any(w == there for w in res.wants.values())
                options.append((waited, int(self.plant.ids[there])))
        return min(options)[1] if options else None

    def _push_idle(self, ctx: CycleContext, waits: Mapping[int, int]) -> None:
        for v, blocker in sorted(waits.items()):
            if not self._idle(blocker):
                continue
            if ctx.time_ns - self.controls[v].wait_since_ns < IDLE_PUSH_AFTER_NS:
                continue
            self._make_room(ctx, blocker, {self.plant.index[self.controls[v].current]}, depth=4)

    def _idle(self, vehicle: int) -> bool:
        c = self.controls.get(vehicle)
        return c is not None and c.goal is None and c.state == "idle"

    def _make_room(self, ctx: CycleContext, vehicle: int, avoid: set[int], depth: int) -> bool:
        """Move an idle vehicle to a free neighbour; if it has none, move an idle neighbour
        out of its way first (a chain of at most ``depth``), so it can follow next scan."""
        here = self.plant.index[self.controls[vehicle].current]
        node = self._free_neighbour(vehicle, avoid=avoid)
        if node is not None:
            self.controls[vehicle].back_off(ctx, node)
            self.pushes += 1
            return True
        if depth == 0:
            return False
        for there, arc, _length in self.plant.neighbors[here]:
            other = self.reservation.holder_of(there)
            if there in avoid or self.blockades.blocked[arc] or other is None:
                continue
            if self._idle(other) and self._make_room(ctx, other, avoid | {here}, depth - 1):
                return True
        return False
