"""SafeIntervalSearch: the earliest conflict-free path in time, turns included (SIPP).

Safe-interval path planning (Phillips & Likhachev 2011) searches over (node, safe interval)
instead of (node, time step): a node's *safe intervals* are the gaps between the other
vehicles' windows on it (:class:`TimeWindowTable`), and arriving earlier in an interval is
never worse than arriving later, because a vehicle can always wait. So each state is reached
once at its earliest time, and the search stays as small as a plain A* times the few
intervals per node, however fine the clock.

That holds while cost is time. With arc weights (below) a later arrival can have paid less
weight, and the earlier one may still catch an interval the later one misses, so neither
may replace the other: each state then keeps every label (arrival, weight paid on top of
the time) that no other label beats on both, and the search is a multi-label A*. Without
weights no label pays any, and one label per state survives, the earliest, as in plain
SIPP.

``labels="cheapest"`` keeps one label per state, the cheapest, as plain SIPP keeps the
earliest: the search is no larger than plain SIPP's, but a cheaper label that arrives
later replaces an earlier one that alone could catch the next free interval, so it may
return a dearer plan than the least, or none where one exists. The time-window traffic
uses it all the same: on the kiva map with highways its vehicles finished 436-522 tasks
at 140 vehicles where the exact search's finished 376-387 (docs/benchmarks.md), because
its searches stay as small as without weights and rounds end sooner; a vehicle whose
search finds nothing waits for the next round, as any vehicle without a plan.

The state here also holds the arc the vehicle arrived by, because turning costs time (the
vehicles turn on the spot: a turn of 45-135 degrees takes ``turn_90``, a sharper one
``turn_180``, as the simulated AGV does) and the time to turn depends on where it came from.
A move u -> v sets off no earlier than the arrival at u plus the turn, no later than the end
of u's interval, along a segment the table allows at that time (no head-on, no overtaking),
into a safe interval of v.

When does a vehicle's window on v begin? With ``claim="departure"`` (the default) when it
sets off towards v, as the controller releases a node before the vehicle drives to it. That
is what execution by order needs (:class:`PassOrder`): a vehicle then waits only for
visits whose planned departure comes strictly before its own, so waits never form a
cycle. With ``claim="arrival"`` the window begins on arrival: a vehicle may set off
towards a node at the moment another leaves it, so a ring of vehicles may move round in
lockstep, which the unit-time grid model of multi-agent path finding allows, but which
vehicles that can be delayed cannot execute by order (each would wait for the one ahead). Travel time is length / min(speed, segment limit).

Cost is time, plus an optional congestion term per arc: ``weights[arc]`` >= 1 multiplies the
arc's travel time in the cost only (path heat). With all weights 1 the search returns the
earliest possible arrival, which tests check against a brute-force time-expanded search.
The heuristic is the exact distance to the goal over the top speed: a lower bound on time.
``allowed[arc]`` False keeps the search off an arc: a vehicle held to a given route (it may
only wait), or to a corridor round it.

A single-vehicle area's nodes share their safe intervals (the table keeps their windows
under the area's key), and a move from one of its nodes to another stays in the interval
the vehicle is in: it is in the area all the while, so it may not wait on the segment for a
later interval, between which and its own another vehicle has the area. With departure
claims that follows from the shared intervals alone (the move must set off inside both);
with arrival claims the search checks it.

``until`` makes the plan *windowed*, as rolling-horizon planners do: conflicts are resolved
only before that time, and from then on the vehicle meets nobody (the table's windows are cut
there) but the vehicles that stand where they are for good (a node window booked for good,
begun before the cut-off: a vehicle out of service), which stay in the way like a
blockade. Only the part of such a plan that starts
before ``until`` may be booked; the rest is a route to be planned again. It keeps a search
from failing, or exploring the whole plant, because of where others will be long after the
plan is replaced anyway. Past the cut-off the search does not explore either: from the
first states there a plan goes on down the distances to the goal
(:meth:`SafeIntervalSearch.descent`), round the vehicles that stand for good where a
shortest way allows, and the search returns the cheapest plan of that shape. Across the
99 x 138 warehouse a 30 s cut-off takes a sixteenth of the expansions a search
(bench/windowed_search.py). Where those vehicles close every shortest way, the search
explores on past the cut-off, as round a blockade, and goes the long way round: without
them, every plan would wait for the cut-off and then drive through a vehicle that never
leaves (rejected as a plan that only waits, the vehicle would be stranded for good). The
goal is the exception (its area with it): a vehicle standing on it now is no reason to find
no path to it, so past the cut-off it is free as before.

The search runs in bounded steps (:meth:`step`, ``budget`` expansions or their worth),
like the A* block, and publishes only a complete plan. A goal is reached when the vehicle can stay there for
``hold_s`` seconds (inf: for good, the last interval of the node).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from blocks.routing.heuristic import distances_to
from topology import Plant

from .time_windows import TimeWindowTable

# A step down the distances past the cut-off costs about a sixth of an expansion (3
# against 16 us on the 1000-vehicle warehouse), which asks the time-window table; budgets
# count this many to an expansion
DESCENT_STEPS_PER_EXPANSION = 4

COS_45 = math.cos(math.radians(45))
COS_135 = math.cos(math.radians(135))


class TurnTimes(NamedTuple):
    """Seconds to turn on the spot: 45-135 degrees, and sharper (a U-turn)."""

    turn_90: float = 1.0
    turn_180: float = 2.0

    def between(
        self, before: tuple[float, float] | None, after: tuple[float, float] | None
    ) -> float:
        if before is None or after is None:
            return 0.0
        cos = before[0] * after[0] + before[1] * after[1]
        if cos <= COS_135 + 1e-12:
            return self.turn_180
        return self.turn_90 if cos <= COS_45 + 1e-12 else 0.0


AGV_TURNS = TurnTimes()  # the simulated AGV's defaults


@dataclass(frozen=True)
class TimedPlan:
    """A vehicle's path in time: node ids with the time it arrives at and leaves each."""

    vehicle: int
    nodes: tuple[int, ...]
    arrive: tuple[float, ...]
    depart: tuple[float, ...]  # the last one is the end of the stay at the goal (inf: stays)
    cost: float
    # when each node's window begins: the departure towards it (CLAIM_ON_DEPARTURE, the
    # start node from the start time), or the arrival (None)
    claim: tuple[float, ...] | None = None

    @property
    def arrival(self) -> float:
        return self.arrive[-1]

    @property
    def claims(self) -> tuple[float, ...]:
        """The start of each node's window: the order of visits at a node."""
        return self.arrive if self.claim is None else self.claim

    def node_windows(self) -> list[tuple[int, float, float]]:
        return list(zip(self.nodes, self.claims, self.depart, strict=True))

    def segment_windows(self) -> list[tuple[int, int, float, float]]:
        return [
            (self.nodes[i], self.nodes[i + 1], self.depart[i], self.arrive[i + 1])
            for i in range(len(self.nodes) - 1)
        ]

    def book(self, table: TimeWindowTable) -> None:
        """Put the plan's windows into ``table`` (replacing the vehicle's old ones)."""
        table.book(self.vehicle, self.node_windows(), self.segment_windows())


class ArcGeometry:
    """Per arc of a plant: unit direction (None for a zero-length arc) and speed limit.
    Built once per plant and shared by every search on it."""

    def __init__(self, plant: Plant) -> None:
        src, dst, _ = plant.arcs
        xy = plant.positions
        delta = xy[dst] - xy[src]
        norm = np.hypot(delta[:, 0], delta[:, 1])
        self.direction: list[tuple[float, float] | None] = [
            (float(dx / n), float(dy / n)) if n > 0 else None
            for (dx, dy), n in zip(delta.tolist(), norm.tolist(), strict=True)
        ]
        self.max_speed = plant.arc_max_speed.tolist()
        self.ids: list[int] = plant.ids.tolist()
        self._arcs = len(self.direction)
        # per set of turn times: arc_in * arcs + arc_out -> seconds. Int keys and float
        # values, so the garbage collector never has to scan this cache, however large
        self._turns: dict[TurnTimes, dict[int, float]] = {}

    def turn(self, turns: TurnTimes, arc_in: int, arc_out: int) -> float:
        """Seconds to turn from arriving along ``arc_in`` to leaving along ``arc_out``
        (indices), computed once per pair: a search asks for the same pairs again and again."""
        cache = self._turns.get(turns)
        if cache is None:
            cache = self._turns[turns] = {}
        key = arc_in * self._arcs + arc_out
        out = cache.get(key)
        if out is None:
            out = cache[key] = turns.between(self.direction[arc_in], self.direction[arc_out])
        return out


class SafeIntervalSearch:
    """One vehicle's search from ``start`` (at ``start_time``, facing ``heading``, a unit
    vector or None) to ``goal`` through the free windows of ``table``."""

    def __init__(
        self,
        plant: Plant,
        table: TimeWindowTable,
        vehicle: int,
        start: int,
        goal: int,
        start_time: float,
        *,
        speed: float,
        heading: tuple[float, float] | None = None,
        turns: TurnTimes = AGV_TURNS,
        hold_s: float = math.inf,
        to_goal: np.ndarray | None = None,
        weights: Sequence[float] | None = None,
        allowed: Sequence[bool] | None = None,
        claim: str = "departure",
        geometry: ArcGeometry | None = None,
        until: float = math.inf,
        labels: str = "pareto",
    ) -> None:
        if claim not in ("departure", "arrival"):
            raise ValueError(f"claim must be 'departure' or 'arrival', got {claim!r}")
        self.claim = claim
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a positive number of m/s, got {speed!r}")
        self.plant, self.table, self.vehicle = plant, table, vehicle
        self.start, self.goal, self.start_time = start, goal, float(start_time)
        self.speed, self.turns, self.hold_s = float(speed), turns, float(hold_s)
        self.until = float(until)
        if labels not in ("pareto", "cheapest"):
            raise ValueError(f"labels must be 'pareto' or 'cheapest', got {labels!r}")
        self.cheapest_only = labels == "cheapest"
        self.geometry = geometry or ArcGeometry(plant)
        # read, not copied: one list serves every search of a planning round
        self.weights = weights
        self.allowed = allowed
        row = to_goal if to_goal is not None else distances_to(plant, [goal])[0]
        # distances in m, read per node as the search reaches it (a search touches few of
        # a large plant's nodes: converting the whole row would cost more than the search)
        self._row = np.asarray(row, dtype=np.float64)
        self._safe: dict[int, list[tuple[float, float]]] = {}
        self._seconds: dict[int, float] = {}
        self._heading = heading
        self._goal = plant.idx(goal)
        # past the cut-off, whoever stands for good on the goal (its area) is no obstacle
        self._goal_key = table.resources.get(goal, goal)
        # labels, by id: the state (node index, arc in, interval), cost, arrival, and the
        # label it came from with the time it set off from there (None: the start)
        self._labels: list[tuple[tuple[int, int, int], float, float, tuple[int, float] | None]] = []
        self._alive: list[bool] = []
        # state -> its labels alive (a tuple of ints: the collector stops tracking it)
        self._at: dict[tuple[int, int, int], tuple[int, ...]] = {}
        self._open: list[tuple[float, float, int]] = []  # (f, g, label)
        self.expansions = 0
        self.descended = 0  # steps tried down the distances past the cut-off
        self._tails: dict[int, Tail] = {}  # label past the cut-off -> its way on
        self._stuck: set[int] = set()  # nodes with no way down the distances (indices)
        self.done = False
        self.plan: TimedPlan | None = None
        self.reason: str | None = None  # why there is no plan
        self._begin()

    # ----- the search ----------------------------------------------------------------------
    def _begin(self) -> None:
        s = self.plant.idx(self.start)
        for k, (lo, hi) in enumerate(self._intervals(s)):
            if lo - 1e-9 <= self.start_time <= hi + 1e-9:
                self._label((s, -1, k), 0.0, self.start_time, None, self._h(s))
                return
        self._finish(
            None, f"node {self.start} is booked by another vehicle at {self.start_time:g} s"
        )

    @property
    def work(self) -> int:
        """What a budget counts: expansions, and steps down the distances past the cut-off
        at DESCENT_STEPS_PER_EXPANSION to one."""
        return self.expansions + self.descended // DESCENT_STEPS_PER_EXPANSION

    def step(self, budget: int | None = None) -> bool:
        """Work up to about ``budget`` (:attr:`work`: one state's expansion or walk down the
        distances may overrun it; None: until the search ends); True once done."""
        begin = self.work
        while self._open and not self.done and (budget is None or self.work - begin < budget):
            _, g, label = heapq.heappop(self._open)
            if not self._alive[label]:
                continue  # beaten by a label found since it was pushed
            self.expansions += 1
            state, _, t, _ = self._labels[label]
            node, arc, k = state
            interval_end = self._intervals(node)[k][1]
            if node == self._goal and interval_end >= t + self.hold_s - 1e-9:
                self._finish(label, None)
                break
            if t >= self.until:
                # past the cut-off: popped by its lower bound, it is costed whole down the
                # distances and pushed again; popped at that cost, nothing can beat it
                tail = self._tails.get(label)
                if tail is not None:
                    self._finish(label, None, tail)
                    break
                tail = self.descent(node, arc, t)
                if tail is not None:
                    self._tails[label] = tail
                    whole = g + tail.arrive[-1] - t + tail.extra
                    heapq.heappush(self._open, (whole, whole, label))
                    continue
            self._expand(label, node, arc, t, g, k, interval_end)
        if not self._open and not self.done:
            self._finish(None, f"no conflict-free path from {self.start} to {self.goal}")
        return self.done

    def _expand(
        self, label: int, node: int, arc_in: int, t: float, g: float, k: int, leave_by: float
    ) -> None:
        geometry, ids, turns = self.geometry, self.geometry.ids, self.turns
        allowed, table, h = self.allowed, self.table, self._h
        # inside a single-vehicle area the vehicle stays in it from node to node: it may
        # only go on within the area's safe interval it is in (k), never into a later one,
        # which would put it in the area while another vehicle is there (with departure
        # claims the shared intervals already ensure it: see the module's notes)
        areas = table.resources
        area = areas.get(ids[node]) if areas else None
        for v, arc, length in self.plant.neighbors[node]:
            if allowed is not None and not allowed[arc]:
                continue
            travel = length / min(self.speed, geometry.max_speed[arc])
            if arc_in < 0:
                set_off = t + turns.between(self._heading, geometry.direction[arc])
            else:
                set_off = t + geometry.turn(turns, arc_in, arc)
            if set_off > leave_by + 1e-9:
                continue
            # the window at v opens when it sets off towards v (or when it arrives)
            claim_delay = 0.0 if self.claim == "departure" else travel
            within = area is not None and areas.get(ids[v]) == area
            for j, (lo, hi) in enumerate(self._intervals(v)):
                if lo > leave_by + claim_delay + 1e-9:
                    break
                if hi < set_off + travel - 1e-9 or (within and j != k):
                    continue
                depart = table.earliest_entry(
                    ids[node],
                    ids[v],
                    max(set_off, lo - claim_delay),
                    travel,
                    self.vehicle,
                    latest=min(leave_by, hi - travel),
                    until=self.until,
                )
                if depart is None:
                    continue
                arrive = depart + travel
                extra = (self.weights[arc] - 1.0) * travel if self.weights is not None else 0.0
                cost = g + (arrive - t) + extra
                self._label((v, arc, j), cost, arrive, (label, depart), cost + h(v))

    def _label(self, state, cost: float, arrive: float, parent, f: float) -> None:
        """Keep a label for ``state`` unless one there arrived as early and paid as little
        weight on top of its time; drop the ones it beats on both. (Not cost against
        arrival: the later of two labels of equal cost paid less weight, and where the
        way on must wait anyway, its wait costs less.) With ``labels="cheapest"``: unless
        the one label there cost as little, which it then replaces."""
        labels, alive = self._labels, self._alive
        kept = []
        if self.cheapest_only:
            for other in self._at.get(state, ()):
                if labels[other][1] <= cost + 1e-12:
                    return
                alive[other] = False
        else:
            extra = cost - arrive
            for other in self._at.get(state, ()):
                _, c, a, _ = labels[other]
                if c - a <= extra + 1e-9 and a <= arrive + 1e-9:
                    return
                if extra <= c - a and arrive <= a:
                    alive[other] = False
                else:
                    kept.append(other)
        label = len(labels)
        labels.append((state, cost, arrive, parent))
        alive.append(True)
        kept.append(label)
        self._at[state] = tuple(kept)
        heapq.heappush(self._open, (f, cost, label))

    def _intervals(self, node: int) -> list[tuple[float, float]]:
        out = self._safe.get(node)
        if out is None:
            at = self.geometry.ids[node]
            lasting = self.table.resources.get(at, at) != self._goal_key
            out = self._safe[node] = self.table.safe_intervals(
                at, self.vehicle, self.until, lasting
            )
        return out

    def _walled(self, node: int) -> bool:
        """Is ``node`` (an index) closed past the cut-off: another vehicle stands there for
        good from before it (never the goal, nor its area)?"""
        table, at = self.table, self.geometry.ids[node]
        return table.resources.get(at, at) != self._goal_key and table.stands_for_good(
            at, self.vehicle, self.until
        )

    def _h(self, node: int) -> float:
        """The heuristic in seconds: the distance to the goal at top speed."""
        out = self._seconds.get(node)
        if out is None:
            out = self._seconds[node] = self._row[node].item() / self.speed
        return out

    def descent(self, node: int, arc_in: int, t: float) -> Tail | None:
        """The way on from ``node`` (reached at ``t`` along ``arc_in``) past the cut-off,
        where the vehicle meets nobody but those that stand for good: down the distances to
        the goal, straight on where a shortest way allows it, round those vehicles where
        another shortest way does. None where the allowed arcs and those vehicles leave no
        shortest way (a blockade the distances do not know): the search then goes on as
        before the cut-off.

        This is what makes a windowed search cheap: it ends soon after the cut-off instead
        of exploring, turn by turn, the many equally short ways to a far goal. Past the
        cut-off a plan takes this one way, turns and arc weights paid: cheaper ways on
        (fewer turns, lighter arcs) are not looked for, since the plan is made again
        before it gets there.

        The way is followed depth first, the least turn first at each node: where every
        shortest way on from a node is closed, it turns back to the node before and tries
        its next one. A node with no way down from it (from any heading) is remembered, so
        all the walks of a search that end nowhere take one step per node together, not
        one walk for every state."""
        if node == self._goal:
            return None  # it could not stay there (or it would have been done): search on
        stuck = self._stuck
        if node in stuck:
            return None
        # the nodes of the way so far: [node, arc in, arrival, set-off from the node
        # before, weight paid so far, its shortest ways on (least turn first), next to try]
        way = [[node, arc_in, t, t, 0.0, self._down(node, arc_in), 0]]
        on_way = {node}  # a zero-length arc is a shortest way both ways: never back
        geometry, weights, speed = self.geometry, self.weights, self.speed
        while way:
            top = way[-1]
            here, _, t, _, extra, options, i = top
            while i < len(options) and (options[i][1] in stuck or options[i][1] in on_way):
                i += 1
            if i == len(options):
                stuck.add(here)  # no way down from here
                on_way.discard(here)
                way.pop()
                continue
            top[6] = i + 1
            turn, v, arc, length = options[i]
            travel = length / min(speed, geometry.max_speed[arc])
            if weights is not None:
                extra += (weights[arc] - 1.0) * travel
            set_off = t + turn
            if v == self._goal:
                nodes = [step[0] for step in way[1:]] + [v]
                arrive = [step[2] for step in way[1:]] + [set_off + travel]
                depart = [step[3] for step in way[1:]] + [set_off]
                return Tail(nodes, arrive, depart, extra)
            on_way.add(v)
            way.append([v, arc, set_off + travel, set_off, extra, self._down(v, arc), 0])
        return None

    def _down(self, node: int, arc_in: int) -> list[tuple[float, int, int, float]]:
        """The shortest ways on from ``node`` (reached along ``arc_in``) that are open past
        the cut-off: (turn, next node, arc, length), the least turn first (in the plant's
        order where turns tie)."""
        row = self._row
        here = row[node].item()
        if not math.isfinite(here):
            return []  # no way to the goal at all
        self.descended += 1
        geometry, allowed, out = self.geometry, self.allowed, []
        for v, arc, length in self.plant.neighbors[node]:
            if allowed is not None and not allowed[arc]:
                continue
            # on a shortest way, but for the rounding of the distances to float32
            # (a relative 1.2e-7 each)
            if abs(here - length - row[v].item()) > 1e-6 * max(1.0, here):
                continue
            if self._walled(v):
                continue  # a vehicle stands there for good
            if arc_in < 0:
                turn = self.turns.between(self._heading, geometry.direction[arc])
            else:
                turn = geometry.turn(self.turns, arc_in, arc)
            out.append((turn, v, arc, length))
        out.sort(key=lambda option: option[0])  # stable: the plant's order where turns tie
        return out

    def _finish(self, label: int | None, reason: str | None, tail: Tail | None = None) -> None:
        """Done: the plan to ``label`` (and on along ``tail``), or no plan for ``reason``."""
        self.done, self.reason = True, reason
        self._open = []
        if label is None:
            return
        _, cost, end, _ = self._labels[label]
        nodes, arrive, depart = [], [], []
        leave = end + self.hold_s if tail is None else tail.depart[0]
        while label is not None:
            state, _, t, link = self._labels[label]
            nodes.append(int(self.plant.ids[state[0]]))
            arrive.append(t)
            depart.append(leave)
            label, leave = (None, 0.0) if link is None else link
        nodes.reverse()
        arrive.reverse()
        depart.reverse()
        if tail is not None:
            ids = self.geometry.ids
            nodes += [ids[n] for n in tail.nodes]
            arrive += tail.arrive
            depart += [*tail.depart[1:], tail.arrive[-1] + self.hold_s]
            cost += tail.arrive[-1] - end + tail.extra
        claim = None
        if self.claim == "departure":
            claim = (arrive[0], *depart[:-1])
        self.plan = TimedPlan(self.vehicle, tuple(nodes), tuple(arrive), tuple(depart), cost, claim)


class Tail(NamedTuple):
    """A plan's steps past the cut-off (node indices, arrival and set-off times), and the
    weight paid on top of their time."""

    nodes: list[int]
    arrive: list[float]
    depart: list[float]  # set-off from the node before each
    extra: float


def plan_path(
    plant: Plant,
    table: TimeWindowTable,
    vehicle: int,
    start: int,
    goal: int,
    start_time: float,
    **kw,
) -> TimedPlan | None:
    """The whole search at once (tests, benchmarks, the startup phase)."""
    search = SafeIntervalSearch(plant, table, vehicle, start, goal, start_time, **kw)
    search.step(None)
    return search.plan


def time_route(
    table: TimeWindowTable,
    vehicle: int,
    nodes: Sequence[int],
    lengths: Sequence[float],
    directions: Sequence[tuple[float, float] | None],
    start_time: float,
    *,
    speed: float,
    heading: tuple[float, float] | None = None,
    turns: TurnTimes = AGV_TURNS,
    hold_s: float = math.inf,
) -> TimedPlan | None:
    """The earliest timing of a route that is given, not searched (a return lane, which
    routing may not use): the safe-interval search restricted to the route's node sequence,
    states (step, safe interval), departure claims. ``lengths[i]`` and ``directions[i]``
    describe the segment nodes[i] -> nodes[i + 1]. None if the route cannot be driven
    through the table's free windows (then the vehicle waits for the next planning round)."""
    last = len(nodes) - 1
    safe = [table.safe_intervals(n, vehicle) for n in nodes]
    start = next(
        (k for k, (lo, hi) in enumerate(safe[0]) if lo - 1e-9 <= start_time <= hi + 1e-9), None
    )
    if start is None:
        return None
    arrival = {(0, start): start_time}
    parent: dict[tuple[int, int], tuple[tuple[int, int], float] | None] = {(0, start): None}
    frontier = [(start_time, 0, start)]
    while frontier:
        t, i, k = heapq.heappop(frontier)
        if t > arrival[(i, k)]:
            continue
        leave_by = safe[i][k][1]
        if i == last:
            if leave_by >= t + hold_s - 1e-9:
                return _route_plan(vehicle, nodes, (i, k), arrival, parent, hold_s)
            continue
        travel = lengths[i] / speed
        before = heading if i == 0 else directions[i - 1]
        set_off = t + turns.between(before, directions[i])
        if set_off > leave_by + 1e-9:
            continue
        for j, (lo, hi) in enumerate(safe[i + 1]):
            if lo > leave_by + 1e-9:
                break
            if hi < set_off + travel - 1e-9:
                continue
            depart = table.earliest_entry(
                nodes[i],
                nodes[i + 1],
                max(set_off, lo),
                travel,
                vehicle,
                latest=min(leave_by, hi - travel),
            )
            if depart is None:
                continue
            state = (i + 1, j)
            if depart + travel < arrival.get(state, math.inf) - 1e-12:
                arrival[state] = depart + travel
                parent[state] = ((i, k), depart)
                heapq.heappush(frontier, (depart + travel, i + 1, j))
    return None


def _route_plan(vehicle, nodes, state, arrival, parent, hold_s: float) -> TimedPlan:
    arrive, depart = [], []
    leave = arrival[state] + hold_s
    while state is not None:
        arrive.append(arrival[state])
        depart.append(leave)
        link = parent[state]
        state, leave = (None, 0.0) if link is None else link
    arrive.reverse()
    depart.reverse()
    return TimedPlan(
        vehicle,
        tuple(nodes),
        tuple(arrive),
        tuple(depart),
        arrive[-1] - arrive[0],
        (arrive[0], *depart[:-1]),
    )
