"""DeadlockResolver: starts the vehicles standing at nodes, in priority order, pushing
standing vehicles out of the way, and breaks the waits-for cycles that remain.

A node has one holder, so a vehicle that cannot go on waits for the holder of its next node,
and vehicles waiting for each other in a circle wait forever (the thesis' open case, 5.3.1:
the only remaining path is occupied). In lifelong operation on single-lane aisles such
circles form all the time, with queues behind them that no single back-off can clear. So
the starts of all standing vehicles are decided here, centrally, every scan, by priority
inheritance with backtracking (PIBT, Okumura et al.), in its asynchronous form:

* standing vehicles are taken most urgent first (the older recipe step, then the lower id);
  each asks for the next node of its route;
* if a standing vehicle holds that node, it inherits the asker's priority and must move
  aside to one of its own neighbours (off the asker's route if it can, else closest to its
  own goal), pushing the next one in turn; a chain that finds no room fails and the asker
  tries nothing else: it waits (a vehicle never waits for a vehicle that waits for it, so
  no circle is ever created by the chain itself);
* a node held by a driving vehicle, or one processing at a station, is waited for: it
  leaves by itself; vehicles that are offline, stale or faulty are walls;
* a node of a single-vehicle area another vehicle occupies (ReservationMatrix) is waited
  for, never pushed for: the occupant is the vehicle waited for, and pushing it inside its
  area would free nothing. Only that occupant, on its way out, may push the waiting vehicle
  aside: the waiting one cannot move on before the occupant has left, and the occupant
  can only leave through it. A start into an area is granted only while no other vehicle
  occupies it, to one vehicle per scan, and a vehicle moved aside (a push or a back-off)
  is never moved onto a node of an area: moving within its own frees nothing for those
  waiting for it, and one moved into a free area (a station's dead-end spur) would stand
  in the way of the next vehicle the station serves;
* every decision is remade from the current holds next scan; only granted starts commit.

The most urgent vehicle is never pushed (except out of the way of the occupant of the area it
waits for, which only brings its turn closer), and on a plant where every segment lies on a
cycle its chain always finds room while there are fewer vehicles than nodes, so it reaches its
goal; a vehicle's urgency grows while it has not reached its goal, so every vehicle becomes
the most urgent one in turn. Pushing cannot help where the plant has dead ends (a siding,
a corridor without a loop): a waits-for circle that remains after the pushes is broken by
backing off the least urgent vehicle that can step off the others' routes, which then does
not retake the node it left while they still need it. A circle nobody in it can leave is
reported (``unresolved``) and tried again every second (``RETRY_S``): a blockade may
clear, a vehicle may come back online, the vehicle in front of one of them on a one-way
lane may drive on and leave it room to step aside. Watched the same way are a circle whose
back-off went to a vehicle queued behind it (that makes room, but breaks nothing by
itself) and one a push was decided for (the node it was pushed to may never come free: the
vehicle driving to it may stop there). A livelock (a circle given way in too often without
progress) is reported and left alone. Every detection is recorded.

With ``pushes=False`` (time-window traffic: the plans fix who passes where first, and a
vehicle moved off its plan would break that order) it only grants the starts the controls
ask for, in priority order, and records any waits-for cycle without moving anyone.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from blocks.routing.constraints import RoutingConstraints
from blocks.routing.heuristic import HeuristicTable
from plc_runtime import CycleContext, FunctionBlock, Output
from plc_runtime.recent import RecentList
from topology import Plant

from .reservation import OUT_OF_SERVICE, ReservationMatrix
from .vehicle_control import VehicleControl

MAX_BACK_OFFS = 8  # back-offs for one cycle without progress: then it is a livelock
RETRY_S = 1.0  # a cycle nobody could leave is tried again this often
RETRY_NS = round(RETRY_S * 1e9)
MAX_CHAIN = 64  # standing vehicles one start may push in a row (bounds the scan's work)
# deadlock records kept, the newest: ~1,000 are far more than anyone reads back (the summary
# shows 100) and a fleet that deadlocks now and then for months would otherwise grow with
# each one; detected/resolved/unresolved and ``events.total`` count them all
EVENTS_KEPT = 1000


class _Ranks(dict[int, tuple]):
    """One scan's priorities, each vehicle's asked for once. Sorting the standing vehicles,
    their requests, and checking every remembered cycle for progress would otherwise ask
    for the same few hundred priorities several times a scan; they do not change within
    the resolver's scan (it moves no recipe step on)."""

    def __init__(self, priority: Callable[[int], tuple]) -> None:
        super().__init__()
        self._priority = priority

    def __missing__(self, vehicle: int) -> tuple:
        rank = self[vehicle] = self._priority(vehicle)
        return rank


@dataclass(frozen=True)
class DeadlockEvent:
    time_s: float
    vehicles: tuple[int, ...]  # the cycle, in waits-for order
    backed_off: int | None  # None: nobody could move (unresolved)
    to_node: int | None


class DeadlockResolver(FunctionBlock):
    detected = Output(0, doc="waits-for cycles found")
    resolved = Output(
        0, doc="pushes and back-offs that broke a cycle or made room behind one (may need several)"
    )
    unresolved = Output(0, doc="cycles nobody could leave (retried each second, not livelocks)")
    pushes = Output(0, doc="standing vehicles moved aside for a more urgent one")

    def __init__(
        self,
        plant: Plant,
        controls: Mapping[int, VehicleControl],
        reservation: ReservationMatrix,
        blockades: RoutingConstraints,
        priority: Callable[[int], tuple[int, int]],
        table: HeuristicTable,
        pushes: bool = True,
    ) -> None:
        super().__init__()
        self.pushes_allowed = pushes
        self.plant = plant
        self.controls = dict(controls)
        self.reservation = reservation
        self.blockades = blockades
        self.priority = priority  # smaller is more urgent
        self.table = table
        self._ids: list[int] = plant.ids.tolist()  # node id of each index, read per vehicle
        self.events: RecentList[DeadlockEvent] = RecentList(EVENTS_KEPT)
        # unresolved cycles already reported, with their members' progress at the time: not
        # reported again until one of them reaches a new recipe step or backs off
        self._stuck: dict[frozenset[int], tuple] = {}
        # back-offs per cycle of vehicles while none of them reaches a new recipe step: a
        # plant where giving way only moves the deadlock (a dead-end corridor) is reported
        # as unresolved instead of being shuffled back and forth forever
        self._attempts: dict[frozenset[int], tuple[tuple, int]] = {}
        self._last_rings: set[frozenset[int]] = set()
        # unresolved cycles that are livelocks (given way too often): not retried
        self._livelocks: set[frozenset[int]] = set()
        # cycles still there to be tried again, and when (ns)
        self._retry_at: dict[frozenset[int], int] = {}
        # one scan's decisions: vehicle -> node index it goes to (its own: it stays)
        self._next: dict[int, int] = {}
        self._reserved: dict[int, int] = {}  # node index -> the vehicle it was given to
        self._pushed: set[int] = set()
        self._standing_now: Mapping[int, int] = {}
        self._pushable: set[int] = set()
        self._requests: Mapping[int, int] = {}
        self._area_given: dict[int, int] = {}  # area index -> the vehicle given a node of it
        self._area_waits: dict[int, int] = {}  # stays for an area: vehicle -> its occupant
        self._rank = _Ranks(priority)  # this scan's priorities
        # per vehicle, its planned route (the tuple) and the node indices on it
        self._routes: dict[int, tuple[tuple, set[int]]] = {}

    def cycle(self, ctx: CycleContext) -> None:
        self._rank = rank = _Ranks(self.priority)
        standing, pushable = self._standing()
        controls, index = self.controls, self.plant.index
        requests = {}
        for v in sorted(standing, key=rank.__getitem__):
            node = controls[v].request(ctx)
            if node is not None:
                requests[v] = index[node]
        waits = self._waits(standing, requests)
        self._arbitrate(standing, pushable, requests)
        self._execute(ctx, standing, requests)
        still = {
            key: (seen, tries)
            for key, (seen, tries) in self._attempts.items()
            if seen == self._progress(key)
        }
        self._attempts = still  # (a vehicle that reached a new step starts afresh)
        self._stuck = {key: p for key, p in self._stuck.items() if key in still}
        self._livelocks &= self._stuck.keys()
        rings = self._cycles(waits)
        keys = {frozenset(ring) for ring in rings}
        self._retry_at = {key: t for key, t in self._retry_at.items() if key in keys}
        for ring in rings:
            key = frozenset(ring)
            if key not in self._last_rings:
                self._resolve(ctx, ring, waits, standing)
            elif key in self._retry_at and ctx.time_ns >= self._retry_at[key]:
                self._resolve(ctx, ring, waits, standing, again=True)
        self._last_rings = keys

    def _resolve(
        self,
        ctx: CycleContext,
        ring: list[int],
        waits: Mapping[int, int],
        standing: Mapping,
        again: bool = False,
    ) -> None:
        """A waits-for cycle has formed (or, ``again``, is still there after a retry was
        scheduled): count it, and if this scan's pushes did not break it, back off the least
        urgent vehicle that can step off the others' routes. The same vehicles in a cycle
        again without any of them reaching a new recipe step count as one detection; after
        ``MAX_BACK_OFFS`` back-offs it is a livelock: reported, and left alone.

        A cycle nobody could leave is reported once and tried again every ``RETRY_S``:
        nobody could step aside when it formed, but the vehicles around them move on (the
        one in front of a vehicle on a one-way lane drives away), and a blockade may clear.
        So is a cycle whose back-off went to a vehicle queued behind it (that makes room,
        but does not break the cycle by itself), and one a push was decided for (the node
        may never come free)."""
        key = frozenset(ring)
        if key in self._livelocks:
            return
        progress = self._progress(key)
        seen, tries = self._attempts.get(key, (None, 0))
        if seen != progress:
            self.detected += 1
            tries = 0
        moved = [v for v in ring if self._next.get(v, standing[v]) != standing[v]]
        if moved and again:
            self._attempts[key] = (progress, tries)
            self._retry_at[key] = ctx.time_ns + RETRY_NS  # breaking up by itself: watch it
            return
        victim, node = None, None
        if tries < MAX_BACK_OFFS:
            if moved:
                victim = next((m for m in moved if m in self._pushed), moved[0])
                node = self._ids[self._next[victim]]
            elif self.pushes_allowed:
                victim, node = self._back_off_candidate(ring, waits)
                if victim is not None:
                    vacated = self.controls[victim].current
                    needed = self._needed_by(set(ring) - {victim}, vacated)
                    self.controls[victim].back_off(ctx, node, needed)
        if victim is None:
            self._attempts[key] = (progress, tries)
            if key not in self._stuck:
                self.unresolved += 1
                self.events.append(DeadlockEvent(ctx.time, tuple(ring), None, None))
                self._stuck[key] = progress
            if tries >= MAX_BACK_OFFS:
                self._livelocks.add(key)
            elif self.pushes_allowed:
                self._retry_at[key] = ctx.time_ns + RETRY_NS
            return
        self._attempts[key] = (progress, tries + 1)
        self.resolved += 1
        self.events.append(DeadlockEvent(ctx.time, tuple(ring), victim, node))
        if victim in key and not moved:
            self._stuck.pop(key, None)
            self._retry_at.pop(key, None)
        else:
            # a push is only decided (its node may never come free: the vehicle driving
            # to it may stop there), or the one behind made room: watch it
            self._retry_at[key] = ctx.time_ns + RETRY_NS

    def _progress(self, vehicles: frozenset[int]) -> tuple:
        """The priorities of ``vehicles`` (in id order): they change when one of them
        reaches a new recipe step."""
        return tuple(map(self._rank.__getitem__, sorted(vehicles)))

    # ----- the starts ---------------------------------------------------------------------------
    def _standing(self) -> tuple[dict[int, int], set[int]]:
        """Vehicles standing at a node (nothing released beyond it) -> that node's index;
        and those of them that may be pushed (not arrived or processing, not on a fixed
        route)."""
        index, pushes = self.plant.index, self.pushes_allowed
        standing, pushable = {}, set()
        for v, c in self.controls.items():
            if c.released or c.current is None or c.state in OUT_OF_SERVICE:
                continue
            standing[v] = index[c.current]
            if pushes and not (c.hold or c.arrived) and c.fixed_route is None:
                pushable.add(v)  # (arrived: its sequencer sees that next scan, then holds)
        return standing, pushable

    def _waits(self, standing: Mapping[int, int], requests: Mapping[int, int]) -> dict[int, int]:
        """The waits-for graph of the standing vehicles, before this scan's decisions."""
        res, controls = self.reservation, self.controls
        waits = {}
        for v in standing:
            if v in requests:
                blocker = res.blocker(v, requests[v])  # the holder, or the area's occupant
                if blocker is not None:
                    waits[v] = blocker
            else:
                c = controls[v]
                if c.state == "waiting" and c.waiting_for is not None:
                    waits[v] = c.waiting_for  # giving way to it
        return waits

    def _arbitrate(
        self, standing: Mapping[int, int], pushable: set[int], requests: Mapping[int, int]
    ) -> None:
        self._next, self._reserved, self._pushed = {}, {}, set()
        self._area_given, self._area_waits = {}, {}
        self._standing_now, self._pushable, self._requests = standing, pushable, requests
        for v in sorted(requests, key=self._rank.__getitem__):
            if v not in self._next:
                self._start(v, [requests[v]], (v,))

    def _route_nodes(self, v: int) -> set[int]:
        """The node indices on ``v``'s planned route. Routes are long and only pushes look
        at them, so the set is made when first needed and kept while the route (a tuple,
        replaced whenever it changes) is the same."""
        planned = self.controls[v].planned
        kept = self._routes.get(v)
        if kept is None or kept[0] is not planned:
            index = self.plant.index
            kept = self._routes[v] = (planned, {index[n] for n in planned})
        return kept[1]

    def _start(self, v: int, candidates: list[int], chain: tuple) -> bool:
        """Give ``v`` the first of ``candidates`` it can have, pushing standing holders aside
        (``chain``: the vehicles waiting on this decision, the one that asked for its start
        first, ``v`` last). False: it stays."""
        res, standing = self.reservation, self._standing_now
        for node in candidates:
            if node == self._requests.get(v):
                occupant = res.area_blocker(v, node)
                if occupant is not None:
                    self._area_waits[v] = occupant  # whatever else it waits for
            if node in self._reserved:
                continue  # given to another vehicle this scan (or it stays there)
            holder = res.holder_of(node)
            if holder is not None and holder != v:
                if not self._may_follow(holder, chain):
                    continue
            elif self._area_taken(v, node) is not None:
                continue  # an area another vehicle occupies: waited for, not pushed for
            area = res.area_of[node]
            if area >= 0:
                self._area_given.setdefault(area, v)
            self._reserved[node], self._next[v] = v, node
            return True
        here = standing[v]
        self._reserved[here], self._next[v] = v, here
        return False

    def _area_taken(self, v: int, node: int) -> int | None:
        """The vehicle other than ``v`` that occupies the area of ``node``, or was given a
        node of it this scan; None when ``v`` may enter it."""
        occupant = self.reservation.area_blocker(v, node)
        if occupant is not None:
            return occupant
        area = self.reservation.area_of[node]
        given = self._area_given.get(area) if area >= 0 else None
        return None if given == v else given

    def _may_follow(self, holder: int, chain: tuple) -> bool:
        """May the last vehicle of ``chain`` go to the node ``holder`` holds, waiting for it
        to leave? Decides (pushes) a standing holder first, off the route of the vehicle
        that asked for the chain's start."""
        if holder in chain:
            return False  # it waits on this decision: waiting for it would be a circle
        standing = self._standing_now
        if holder not in standing:
            return self.controls[holder].state not in OUT_OF_SERVICE  # driving: it leaves by itself
        if len(chain) >= MAX_CHAIN:
            return holder in self._next and self._next[holder] != standing[holder]
        if holder in self._next:
            if self._next[holder] != standing[holder]:
                return True  # told to move on: follow it
            if self._area_waits.get(holder) not in chain or holder not in self._pushable:
                return False  # it stays
            # it stays, waiting for an area whose occupant is on this chain and leaves
            # through the node it stands at: it cannot move on before that one has left, so
            # it makes room (decided again, as a push)
            del self._next[holder]
        node = standing[holder]
        if holder in self._pushable:
            self._reserved[node], self._next[chain[-1]] = chain[-1], node
            aside = self._aside(holder, self._route_nodes(chain[0]))
            if self._start(holder, aside, (*chain, holder)):
                self._pushed.add(holder)
                return True
            return False  # it could not make room, and stays
        if holder in self._requests:  # on a fixed route: it may move on along it
            return self._start(holder, [self._requests[holder]], (*chain, holder))
        # processing at a station: it leaves by itself; only a vehicle on its own route waits
        return len(chain) == 1

    def _aside(self, v: int, route: set[int]) -> list[int]:
        """Where a pushed vehicle may go, best first: off the pusher's route, a free node,
        closer to its own goal, then the lower id (deterministic)."""
        c = self.controls[v]
        here = self.plant.index[c.current]
        goal = c.goal if c.goal is not None and self.table.has_row(c.goal) else None
        row = self.table.row(goal) if goal is not None else None
        res, ids = self.reservation, self._ids
        options = []
        for there, arc, _length in self.plant.neighbors[here]:
            if self.blockades.blocked[arc] or not self._may_step_aside(there):
                continue
            key = (
                there in route,
                res.holder_of(there) is not None,
                float(row[there]) if row is not None else 0.0,
                ids[there],
            )
            options.append((key, there))
        return [there for _key, there in sorted(options)]

    def _may_step_aside(self, there: int) -> bool:
        """May a vehicle be moved aside to node index ``there``? Never
        onto a node of a single-vehicle area: not into one another vehicle occupies, not
        within the one it stands in (those waiting for it wait for the whole area), and not
        into a free one either. An area is a station and its approach, typically a dead-end
        spur: a vehicle moved in there stands in the way of the next vehicle the station
        serves (a transport order's vehicle that holds the station may be right behind),
        and it can only come out through the node that vehicle then waits at."""
        return self.reservation.area_of[there] < 0

    def _execute(
        self, ctx: CycleContext, standing: Mapping[int, int], requests: Mapping[int, int]
    ) -> None:
        """Grant the starts whose node is free, and its area too; the rest wait (and are
        asked again)."""
        res, ids, controls = self.reservation, self._ids, self.controls
        res.set_awaited(
            {
                node: v
                for v, node in self._next.items()
                if node != standing[v] and res.holder_of(node) is not None
            }
        )
        for v, node in self._next.items():
            control = controls[v]
            if node == standing[v]:
                if v in requests:  # it stays: its node was given away or could not be freed
                    wanted = requests[v]
                    blocker = res.blocker(v, wanted)  # the holder, or the area's occupant
                    if blocker is None:  # given to another vehicle this scan, or its area
                        blocker = self._reserved.get(wanted)
                    if blocker is None:
                        blocker = self._area_taken(v, wanted)
                    control.wait_for(ctx, blocker, ids[wanted])
                continue
            blocker = res.blocker(v, node)  # checked at the grant: earlier grants count
            if blocker is None:
                control.grant(ctx, ids[node])
                if v in self._pushed:
                    self.pushes += 1
            elif v in requests:
                control.wait_for(ctx, blocker, ids[node])

    def stranded(self) -> list[int]:
        """Vehicles standing in a waits-for cycle nobody could break (for the summary)."""
        return sorted({v for ring in self._stuck if ring in self._last_rings for v in ring})

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
        order = sorted(members | behind, key=self._rank.__getitem__, reverse=True)
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
            if res.holder_of(there) is None and self._may_step_aside(there):
                # prefer a node nobody waits for, then the lowest id: deterministic
                waited = any(w == there for w in res.wants.values())
                options.append((waited, self._ids[there]))
        return min(options)[1] if options else None
