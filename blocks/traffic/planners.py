"""Planners of one's own for the time-window traffic: who finds one vehicle's plan in time.

A planning round of :class:`TimeWindowTraffic` plans its vehicles one after another, each
through the free windows the vehicles planned before it left (prioritised planning). The
built-in planner, ``sipp``, is safe-interval path planning (:class:`SafeIntervalSearch`).
A planner of one's own takes its place for every vehicle under a name
(:func:`register_planner`, then ``[time_windows] planner`` or
``cfg.time_windows.planner``), so a new search, a different cost or a route-first rule can
be tried on the whole fleet program: its vehicles, links, faults, orders and monitor.

A planner is called with a :class:`PlanRequest` (where the vehicle sets off and when, its
goal, the round's windows so far, the open arcs) and is a generator: it yields after each
unit of its work (an expansion, say), so the round advances it a bounded number of units
per scan, like the built-in search, and returns a :class:`TimedPlan` or None (no plan: the
vehicle stands until the next round).

What the program trusts it with is converted and checked before anything is booked
(:func:`vetted`): the plan must start where and when the request says and end at the goal,
be at most :func:`max_steps` long, use open arcs only, be no faster than the vehicle (speed
limits and turns included), and its windows up to the round's horizon must keep the
table's rules against every vehicle planned before it. A plan that breaks one, a planner
that raises, returns something else or uses up :func:`work_limit` units, is refused (counted, with the first reason, in the summary's
``traffic.refused_plans``) and its vehicle stands as if no plan was found; the fleet runs
on. The release rule and the reservations hold whatever a plan says, as for the built-in
planner: no plan can put two vehicles on one node or make them meet head-on.
"""

from __future__ import annotations

import heapq
import math
import numbers
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field, replace
from itertools import islice

import numpy as np

from plc_runtime.registry import register
from topology import Plant

from .sipp import ArcGeometry, TimedPlan, TurnTimes, time_route
from .time_windows import TimeWindowTable, Window, WindowConflict

BUILT_IN = ("sipp",)
# a plugged planner's units of work for one plan, at least; more on large plants
WORK_LIMIT_MIN = 100_000
WORK_LIMIT_PER_NODE = 50
EPS_S = 1e-6  # times compared with this slack: sums of floats


class WindowView:
    """The round's windows, to read: what a planner may ask the table (booking is the
    round's, after the plan is checked)."""

    def __init__(self, table: TimeWindowTable) -> None:
        self._table = table

    @property
    def gap(self) -> float:
        """The safety gap in seconds between two vehicles' windows."""
        return self._table.gap

    def node_windows(self, node: int) -> tuple[Window, ...]:
        return self._table.node_windows(node)

    def segment_windows(self, a: int, b: int) -> tuple[Window, ...]:
        return self._table.segment_windows(a, b)

    def safe_intervals(
        self, node: int, vehicle: int | None = None, until: float = math.inf
    ) -> list[tuple[float, float]]:
        return self._table.safe_intervals(node, vehicle, until)

    def stands(self, node: int, vehicle: int | None = None) -> bool:
        """Does a vehicle other than ``vehicle`` stand on ``node`` (or its area) until
        further notice: a window of its there that never ends?"""
        return any(
            w.end == math.inf and w.vehicle != vehicle for w in self._table.node_windows(node)
        )

    def earliest_entry(
        self,
        a: int,
        b: int,
        earliest: float,
        travel: float,
        vehicle: int | None = None,
        latest: float = math.inf,
    ) -> float | None:
        return self._table.earliest_entry(a, b, earliest, travel, vehicle, latest=latest)


@dataclass(frozen=True)
class PlanRequest:
    """One vehicle to plan in a round."""

    vehicle: int
    start: int  # the node id its plan starts at (the last one it is committed to)
    goal: int  # the node id it is bound for
    start_s: float  # when it may set off from ``start``: the plan's first arrival time
    heading: tuple[float, float] | None  # the unit vector it faces at ``start``
    speed: float  # its top speed in m/s (an arc's speed limit may be lower)
    turns: TurnTimes  # seconds it stands to turn
    hold_s: float  # how long a plan keeps its goal after arriving (its last departure)
    horizon_s: float  # steps claimed before this time are booked and released
    until_s: float  # the round resolves conflicts up to this time, and no further
    plant: Plant
    windows: WindowView  # the round's windows so far: every vehicle planned before it
    allowed: Sequence[bool]  # per arc (``plant.arcs`` order): may it drive along it now
    to_goal: np.ndarray  # exact distance in m from each node (by index) to the goal
    weights: Sequence[float] | None  # cost factor per arc (highways); None: all 1
    geometry: ArcGeometry = field(repr=False)

    def travel_s(self, a: int, b: int) -> float | None:
        """The shortest time to drive from node ``a`` to node ``b`` (ids) along an open
        arc, at top speed or the arc's limit; None: no open arc."""
        best = None
        for arc in self.plant.arc_index.get((a, b), ()):
            if self.allowed[arc]:
                length = float(self.plant.arcs[2][arc])
                t = length / min(self.speed, self.geometry.max_speed[arc])
                best = t if best is None else min(best, t)
        return best

    def shortest_route(
        self, avoid_standing: bool = True
    ) -> Generator[None, None, list[int] | None]:
        """The shortest route over the open arcs from ``start`` to ``goal`` (node ids), by
        distance: A* with the exact distances as its estimate, yielding after each node it
        expands (``route = yield from request.shortest_route()``); None if there is none.
        ``avoid_standing``: no way through a node where another vehicle stands until
        further notice (a window of its that never ends), which no timing could pass."""
        plant, allowed, h = self.plant, self.allowed, self.to_goal
        start, goal = plant.idx(self.start), plant.idx(self.goal)
        ids, windows, vehicle = plant.ids, self.windows, self.vehicle
        best = {start: 0.0}
        parent: dict[int, int] = {}
        frontier = [(float(h[start]), 0.0, start)]
        while frontier:
            _, g, node = heapq.heappop(frontier)
            if node == goal:
                route = [node]
                while route[-1] in parent:
                    route.append(parent[route[-1]])
                return [int(ids[n]) for n in reversed(route)]
            if g > best[node]:
                continue
            yield
            for nxt, arc, length in plant.neighbors[node]:
                if not allowed[arc] or g + length >= best.get(nxt, math.inf):
                    continue
                if avoid_standing and nxt != goal and windows.stands(int(ids[nxt]), vehicle):
                    continue
                best[nxt], parent[nxt] = g + length, node
                heapq.heappush(frontier, (g + length + float(h[nxt]), g + length, nxt))
        return None

    def timed(self, route: Sequence[int]) -> Generator[None, None, TimedPlan | None]:
        """The earliest timing of ``route`` (node ids from ``start``) through the free
        windows, waiting where it must (``plan = yield from request.timed(route)``; its
        work is counted as a unit per node of the route, yielded after the timing); None if
        the route cannot be driven through them (a node taken for good, say) or has more
        than :func:`max_steps` nodes. Route first, then schedule."""
        route = [int(n) for n in islice(route, max_steps(self.plant) + 1)]
        if not route or route[0] != self.start or len(route) > max_steps(self.plant):
            return None
        pairs = list(zip(route, route[1:], strict=False))
        seconds = [self.travel_s(a, b) for a, b in pairs]
        if any(s is None for s in seconds):
            return None
        directions = [self._direction(a, b) for a, b in pairs]
        plan = time_route(
            self.windows._table,
            self.vehicle,
            route,
            [s * self.speed for s in seconds],
            directions,
            self.start_s,
            speed=self.speed,
            heading=self.heading,
            turns=self.turns,
            hold_s=self.hold_s,
        )
        for _ in route:
            yield
        return plan

    def _direction(self, a: int, b: int) -> tuple[float, float] | None:
        arcs = self.plant.arc_index.get((a, b))
        return self.geometry.direction[arcs[0]] if arcs else None


PlannerRun = Generator[None, None, TimedPlan | None]
PluggedPlanner = Callable[[PlanRequest], PlannerRun]
PLUGGED: dict[str, PluggedPlanner] = {}


def register_planner(name: str, planner: PluggedPlanner, replace: bool = False) -> None:
    """Make ``planner`` the time-window traffic's planner under ``name``
    (``[time_windows] planner``, or ``cfg.time_windows.planner``, in this process). It is
    called with a :class:`PlanRequest` per vehicle and round, and is a generator that
    yields after each unit of its work and returns a :class:`TimedPlan` (or None). A name
    already registered is taken again only with ``replace=True``."""
    register(PLUGGED, "planner", BUILT_IN, name, planner, replace)


def plugged_planner(name: str) -> PluggedPlanner | None:
    """The planner registered under ``name``; None for the built-in one."""
    return PLUGGED.get(name)


def planner_names() -> tuple[str, ...]:
    """The built-in planner, then those registered in this process."""
    return (*BUILT_IN, *PLUGGED)


def work_limit(plant: Plant) -> int:
    """The units of work one plugged plan may take before it is refused: a planner that
    never returns would keep every later vehicle of the round without a plan."""
    return max(WORK_LIMIT_MIN, WORK_LIMIT_PER_NODE * plant.n)


class PluggedSearch:
    """A plugged planner's run for one vehicle, advanced like the built-in search: ``step``
    runs up to ``budget`` units; ``done``, then ``plan`` (None: no plan) and ``refused``
    (why the program would not take what it did)."""

    def __init__(self, planner: PluggedPlanner, request: PlanRequest, limit: int) -> None:
        self.vehicle = request.vehicle
        self.request = request
        self.limit = limit
        self.expansions = 0
        self.done = False
        self.plan: TimedPlan | None = None
        self.refused: str | None = None
        self._run: PlannerRun | None = None
        try:  # a copy: what it does to its request is not what its plan is checked against
            run = planner(replace(request))
        except Exception as err:  # the planner's own fault, not the fleet's
            self._refuse(f"the planner raised {type(err).__name__}: {err}")
            return
        if not isinstance(run, Generator):
            self._refuse(f"the planner returned {type(run).__name__}, not a generator")
            return
        self._run = run

    @property
    def work(self) -> int:
        return self.expansions

    def step(self, budget: int | None = None) -> bool:
        """Advance by up to ``budget`` units (None: to the end); True once done."""
        run = self._run
        while not self.done and run is not None and (budget is None or budget > 0):
            try:
                next(run)
            except StopIteration as stop:
                self._finish(stop.value)
                break
            except Exception as err:
                self._refuse(f"the planner raised {type(err).__name__}: {err}")
                break
            self.expansions += 1
            if budget is not None:
                budget -= 1
            if self.expansions >= self.limit:
                reason = f"the planner took {self.limit} units of work without a plan"
                try:
                    run.close()
                except Exception as err:  # it ignored the close, or its clean-up raised
                    reason += f" (and on closing raised {type(err).__name__}: {err})"
                self._refuse(reason)
        return self.done

    def _finish(self, plan: object) -> None:
        self.done = True
        if plan is None:
            return
        if not isinstance(plan, TimedPlan):
            self._refuse(f"the planner returned {type(plan).__name__}, not a TimedPlan or None")
            return
        self.plan = plan

    def _refuse(self, reason: str) -> None:
        self.done, self.plan, self._run = True, None, None
        self.refused = f"vehicle {self.vehicle}: {reason}"


def vetted(
    plan: TimedPlan,
    request: PlanRequest,
    booked_until: float,
    frontier_from: float,
    table: TimeWindowTable,
) -> tuple[TimedPlan | None, str | None]:
    """A plugged planner's ``plan`` for ``request`` as the program books it (plain ints and
    floats, its windows claimed on departure), or None with what is wrong: its shape, its
    start and end, its arcs, its times (no faster than the vehicle drives and turns), and
    its windows claimed before ``booked_until`` (the frontier's from ``frontier_from``,
    where the vehicle waits until it sets off) against ``table``. The values are converted
    first and the converted plan is checked, so what is checked is what is booked."""
    try:
        plain = _plain(plan, request)
    except Exception as err:  # its fields are the planner's: whatever they do is its fault
        return None, f"a malformed plan ({type(err).__name__}: {err})"
    if isinstance(plain, str):
        return None, plain
    return _checked(plain, request, booked_until, frontier_from, table)


def _plain(plan: TimedPlan, request: PlanRequest) -> TimedPlan | str:
    """``plan`` in plain ints and floats, its windows claimed on departure (the release
    rule orders visits by them, whatever the plan said); a str: what is wrong."""
    if not isinstance(plan.vehicle, numbers.Integral) or plan.vehicle != request.vehicle:
        return f"a plan for vehicle {plan.vehicle!r}, not {request.vehicle}"
    limit = max_steps(request.plant)
    # at most one more than allowed is read: a field may be a generator without end
    nodes, arrive, depart = (
        tuple(islice(f, limit + 1)) for f in (plan.nodes, plan.arrive, plan.depart)
    )
    if len(nodes) > limit:
        return f"a plan of more than {limit} nodes"
    if not nodes or not len(nodes) == len(arrive) == len(depart):
        return "nodes, arrive and depart must be of one length, at least 1"
    if not all(isinstance(n, numbers.Integral) and not isinstance(n, bool) for n in nodes):
        return "its nodes must be node ids (integers)"
    if not all(_number(t) for t in (*arrive, *depart)):
        return "its times must be numbers"
    nodes = tuple(int(n) for n in nodes)
    arrive = tuple(float(t) for t in arrive)
    depart = tuple(float(t) for t in depart)
    claim = (arrive[0], *depart[:-1])
    return TimedPlan(int(plan.vehicle), nodes, arrive, depart, 0.0, claim=claim)


def _checked(
    plan: TimedPlan,
    request: PlanRequest,
    booked_until: float,
    frontier_from: float,
    table: TimeWindowTable,
) -> tuple[TimedPlan | None, str | None]:
    nodes, arrive, depart = plan.nodes, plan.arrive, plan.depart
    if nodes[0] != request.start:
        return None, f"it starts at node {nodes[0]}, not at {request.start} where the vehicle is"
    if nodes[-1] != request.goal:
        return None, f"it ends at node {nodes[-1]}, not at the goal {request.goal}"
    if not all(math.isfinite(t) for t in (*arrive, *depart[:-1])):
        return None, "its times must be finite (only the last departure may be inf)"
    if math.isnan(depart[-1]):
        return None, "its last departure must be a number"
    if abs(arrive[0] - request.start_s) > EPS_S:
        return None, f"it starts at {arrive[0]:g} s, not at {request.start_s:g} s"
    heading = request.heading
    for i, node in enumerate(nodes):
        if depart[i] < arrive[i] - EPS_S:
            return None, (
                f"it leaves node {node} at {depart[i]:g} s, before it arrives ({arrive[i]:g} s)"
            )
        if i + 1 == len(nodes):
            break
        nxt = nodes[i + 1]
        travel = request.travel_s(node, nxt)
        if travel is None:
            return None, f"step {i + 1}: no open arc from node {node} to node {nxt}"
        direction = request._direction(node, nxt)
        turn = request.turns.between(heading, direction)
        if depart[i] < arrive[i] + turn - EPS_S:
            return None, f"it turns on node {node} in {depart[i] - arrive[i]:g} s, under {turn:g} s"
        if arrive[i + 1] < depart[i] + travel - EPS_S:
            return None, (
                f"it drives {node} -> {nxt} in {arrive[i + 1] - depart[i]:g} s, "
                f"under the {travel:g} s it takes"
            )
        heading = direction
    claims = plan.claims
    last = 0
    while last + 1 < len(nodes) and claims[last + 1] < booked_until:
        last += 1
    windows = [(nodes[0], frontier_from, depart[0])]
    windows += [(nodes[i], claims[i], depart[i]) for i in range(1, last + 1)]
    segments = [(nodes[i], nodes[i + 1], depart[i], arrive[i + 1]) for i in range(last)]
    try:
        table.check(request.vehicle, windows, segments)
    except WindowConflict as err:
        return None, str(err)
    return plan, None


def check_units(plan: TimedPlan | None) -> int:
    """What checking and booking ``plan`` costs, in units of the round's budget (a unit per
    ten nodes, as the round counts the visits it books): charged to the planner's scan, so
    that one-yield planners returning long plans do not make a scan long."""
    return 0 if plan is None else -(-len(plan.nodes) // 10)


def max_steps(plant: Plant) -> int:
    """The most nodes a plugged plan may have: a plan is checked whole in one scan, so its
    length is bounded like a search's work (twice the plant's nodes: room for detours)."""
    return max(100, 2 * plant.n)


def _number(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)
