"""TimeWindowTraffic: plan every vehicle in time, execute the plans by order.

The time-window mode of the fleet's traffic (seed 004's planner, made robust to vehicles
that do not keep to their times). Planning runs in **rounds**, as rolling-horizon planners
do: a round takes every vehicle's state as it is, books what cannot change any more, plans
the vehicles that have somewhere to go one after another through the free windows left
(prioritised safe-interval planning), and then replaces all plans at once:

1. **Committed** (booked first, for every vehicle): the nodes it holds in the
   ReservationMatrix, i.e. where it is and what it was released. Holds are exclusive, so
   these windows never conflict. A vehicle with nowhere to go (no goal, at its goal,
   processing, held by an operator, stale, faulty, suspect) stays on its holds for good; a
   vehicle about to plan keeps its last held node (the frontier) a little longer than it
   needs to reach it, so that nobody is planned across its nose before it can turn away.
2. **Planned**, most urgent first (the program's priority: the oldest task, a vehicle at a
   station first; a vehicle whose plan failed in the last round before every other): a
   :class:`SafeIntervalSearch` from the frontier, at the time the vehicle is estimated to
   reach it, to its goal, where it may stay. A route given by the job (a return lane) is
   timed along its nodes instead (:func:`time_route`). Only the first ``horizon_s`` of a
   plan are booked: beyond it, nothing is released before the next round.
3. **Swap**: a fresh :class:`PassOrder` from the round's plans, all labelled by the one
   consistent table of this round (committed visits with the round's start time), so the
   order is acyclic; each vehicle's control gets its route.

While a round is being planned nothing new is released (vehicles drive on over what they
hold), so the committed part stays exact; a round's search work is spread over scans by
``budget`` expansions per scan, like the A* block. A new round starts every ``replan_s``
seconds, and sooner when a vehicle needs one: a new goal, a plan that ended at the horizon
or did not match its route, a blockade closed or cleared.

The controls release a node only when :meth:`gate` allows it: it is the next step of the
vehicle's plan, inside the horizon, and every visit planned there before its own has
passed (the vehicle reported the node after it). The ReservationMatrix still checks every
release (one holder per node), so the safety of the reactive mode holds whatever a plan
says; execution by order adds that no vehicle waits for one that waits for it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from blocks.routing.constraints import RoutingConstraints
from blocks.routing.heuristic import HeuristicTable
from plc_runtime import CycleContext, FunctionBlock, Output
from topology import Plant

from .pass_order import PassOrder
from .reservation import ReservationMatrix
from .sipp import ArcGeometry, SafeIntervalSearch, TimedPlan, TurnTimes, time_route
from .time_windows import TimeWindowTable, WindowConflict

WALLS = ("offline", "stale", "fault", "suspect")


@dataclass
class _Entry:
    """One vehicle in a round: what it holds, and where it wants to go."""

    vehicle: int
    committed: list[int]  # node ids held, in driving order (the last is the frontier)
    reach_s: float  # estimated time it reaches the frontier
    heading: tuple[float, float] | None
    goal: int | None  # None: it stays
    fixed: list[int] | None = None  # a given route after the frontier (a return lane)


class TimeWindowTraffic(FunctionBlock):
    rounds = Output(0, doc="planning rounds completed")
    planning = Output(False, doc="a round is being planned: nothing new is released")
    plans = Output(0, doc="vehicle plans made")
    failed = Output(0, doc="vehicle plans not found (the vehicle waits for the next round)")
    expansions = Output(0, doc="search expansions in the last scan")
    booked = Output(0, doc="windows in the table of the current plans")

    def __init__(
        self,
        plant: Plant,
        heuristic: HeuristicTable,
        reservation: ReservationMatrix,
        blockades: RoutingConstraints,
        priority: Callable[[int], tuple],
        *,
        speed: float,
        turns: TurnTimes,
        gap_s: float = 0.5,
        horizon_s: float = 20.0,
        replan_s: float = 2.0,
        budget: int = 200,
    ) -> None:
        super().__init__()
        if not (math.isfinite(horizon_s) and horizon_s > 0):
            raise ValueError(f"horizon_s must be a positive number of seconds, got {horizon_s!r}")
        if not (math.isfinite(replan_s) and replan_s > 0):
            raise ValueError(f"replan_s must be a positive number of seconds, got {replan_s!r}")
        if plant.areas:
            raise ValueError(
                f"plant {plant.name!r} has single-vehicle areas, which time-window traffic "
                "does not plan yet"
            )
        if budget < 1:
            raise ValueError(f"budget must be at least 1 expansion per scan, got {budget!r}")
        self.plant = plant
        self.heuristic = heuristic
        self.reservation = reservation
        self.blockades = blockades
        self.priority = priority
        self.speed, self.turns = float(speed), turns
        self.gap_s, self.horizon_s, self.replan_s = float(gap_s), float(horizon_s), replan_s
        self.budget = int(budget)
        # how long a plan keeps its goal: until the next round at least, which books the
        # vehicle standing there for good if it stays (a vehicle that only keeps its goal
        # for the rest of time pushes every later plan around it)
        self.goal_hold_s = 2 * replan_s
        # how long a vehicle about to plan keeps its frontier past its arrival there, before
        # anyone planned earlier may cross it: long enough to turn away
        self.frontier_hold_s = turns.turn_180 + gap_s
        self.controls: Mapping = {}  # vehicle -> VehicleControl, set by the program
        self.geometry = ArcGeometry(plant)
        self.table = TimeWindowTable(gap_s)  # the current plans' windows
        self.order = PassOrder()
        self._lengths = _segment_lengths(plant)
        # the current plans: vehicle -> booked step nodes, the step of its frontier (the
        # last one released), the goal the plan leads to, and its whole route
        self._steps: dict[int, list[int]] = {}
        self._front: dict[int, int] = {}
        self._goal: dict[int, int | None] = {}
        self._route: dict[int, list[int]] = {}
        self._late: set[int] = set()  # vehicles whose plan failed: planned first next round
        self._due_ns = 0
        self._began_ns = 0
        self._min_gap_ns = round(replan_s * 1e9 / 4)
        self._allowed: list[bool] = []
        self._epoch = blockades.epoch
        self._wanted = False
        # the round being planned
        self._t0 = 0.0
        self._next_table: TimeWindowTable | None = None
        self._queue: list[_Entry] = []
        self._entries: dict[int, _Entry] = {}
        self._search: SafeIntervalSearch | None = None
        self._made: dict[int, TimedPlan | None] = {}

    # ----- what the controls ask ---------------------------------------------------------
    def gate(self, vehicle: int, node: int) -> tuple[bool, int | None]:
        """May ``vehicle`` be released into ``node`` (an id) now? (ok, the vehicle it waits
        for; None when it waits for a plan: a round is running, or its plan ends before)."""
        if self.planning:
            return False, None
        steps = self._steps.get(vehicle)
        if steps is None:
            self._wanted = True
            return False, None
        step = self._front[vehicle] + 1
        if step >= len(steps) or steps[step] != node:
            self._wanted = True  # the horizon is reached, or the route changed
            return False, None
        blocker = self.order.blocker(vehicle, step)
        return blocker is None, blocker

    def released(self, vehicle: int, node: int) -> None:
        """The control released ``node``, the step after its frontier."""
        if vehicle in self._steps:
            self._front[vehicle] += 1

    def reached(self, vehicle: int, node: int, clear: bool = False) -> None:
        """The vehicle reported ``node``: the steps of its plan before it are passed, and
        that node's too once it is ``clear`` of it (it left the crossing: the next vehicle
        may close up, as the ReservationMatrix lets it)."""
        steps = self._steps.get(vehicle)
        if steps is None:
            return
        first = max(self.order.progress(vehicle) - 1, 0)
        for step in range(first, min(self._front[vehicle], len(steps) - 1) + 1):
            if steps[step] == node:
                passed = step if clear and step < self._front[vehicle] else step - 1
                if passed >= 0:
                    self.order.passed(vehicle, passed)
                return

    # ----- the scan ----------------------------------------------------------------------
    def cycle(self, ctx: CycleContext) -> None:
        self.expansions = 0
        if not self.planning and self._round_due(ctx):
            self._begin(ctx)
        if self.planning:
            self._plan(ctx)

    def _round_due(self, ctx: CycleContext) -> bool:
        if ctx.time_ns >= self._due_ns:
            return True
        if ctx.time_ns < self._began_ns + self._min_gap_ns:
            return False  # rounds on demand, but not back to back
        if self._wanted or self._epoch != self.blockades.epoch:
            return True
        for v, c in self.controls.items():
            if self._moving_goal(c) is not None and self._goal.get(v, -1) != c.goal:
                return True  # a new goal
        return False

    @staticmethod
    def _moving_goal(control) -> int | None:
        """Where a vehicle wants to drive now; None: it stays where it is."""
        if control.state in WALLS or control.suspect or control.hold or control.goal is None:
            return None
        if control.frontier == control.goal and control.fixed_route is None:
            return None  # there (a route that passed its goal and comes back is dropped)
        return control.goal

    # ----- a round -----------------------------------------------------------------------
    def _begin(self, ctx: CycleContext) -> None:
        self.planning = True
        self._wanted = False
        self._epoch = self.blockades.epoch
        self._due_ns = ctx.time_ns + round(self.replan_s * 1e9)
        self._began_ns = ctx.time_ns
        self._allowed = (~self.blockades.blocked).tolist()
        self._t0 = t0 = ctx.time
        table = self._next_table = TimeWindowTable(self.gap_s)
        self._entries, self._made, self._search = {}, {}, None
        movers = []
        for v, c in self.controls.items():
            held = self.reservation.holds[v]
            if c.current is None or not held:
                continue
            committed = [int(self.plant.ids[n]) for n in held]
            reach, heading = self._drive(committed, t0)
            entry = _Entry(v, committed, reach, heading, self._moving_goal(c))
            if entry.goal is not None and c.fixed_route is not None:
                fixed = list(c.fixed_route)
                front = committed[-1]
                entry.fixed = fixed[fixed.index(front) + 1 :] if front in fixed else None
                if not entry.fixed:
                    entry.goal = None
            self._entries[v] = entry
            if entry.goal is None:
                ends = [math.inf] * len(committed)
            else:
                movers.append(entry)
                # kept a little past its arrival: it needs time to turn away
                ends = [reach] * (len(committed) - 1) + [reach + self.frontier_hold_s]
            table.book(
                v,
                [(n, t0, end) for n, end in zip(committed, ends, strict=True)],
                [(a, b, t0, reach) for a, b in zip(committed, committed[1:], strict=False)],
            )
        late = self._late
        self._queue = sorted(
            movers, key=lambda e: (e.vehicle not in late, self.priority(e.vehicle))
        )
        self._late = set()

    def _drive(self, nodes: list[int], t0: float) -> tuple[float, tuple[float, float] | None]:
        """Estimated arrival at the last of ``nodes`` (driving from the first at ``t0``) and
        the heading it arrives with (None: standing, unknown)."""
        t, heading = t0, None
        xy = self.plant.positions
        index = self.plant.index
        for a, b in zip(nodes, nodes[1:], strict=False):
            t += self._lengths.get((a, b), 0.0) / self.speed
            d = xy[index[b]] - xy[index[a]]
            norm = float(np.hypot(d[0], d[1]))
            if norm > 0:
                heading = (float(d[0] / norm), float(d[1] / norm))
        return t, heading

    def _plan(self, ctx: CycleContext) -> None:
        budget = self.budget
        while budget > 0:
            if self._search is None:
                if not self._queue:
                    self._swap(ctx)
                    return
                entry = self._queue.pop(0)
                if entry.fixed is not None:
                    self._book(entry, self._time_fixed(entry))
                    budget -= len(entry.fixed)
                    continue
                self._search = self._start_search(entry)
            search = self._search
            before = search.expansions
            search.step(budget)
            used = search.expansions - before
            budget -= max(used, 1)
            self.expansions += used
            if search.done:
                self._search = None
                self._book(self._entries[search.vehicle], search.plan)

    def _start_search(self, entry: _Entry) -> SafeIntervalSearch:
        goal = entry.goal
        row = self.heuristic.row(goal) if self.heuristic.has_row(goal) else None
        return SafeIntervalSearch(
            self.plant,
            self._next_table,
            entry.vehicle,
            entry.committed[-1],
            goal,
            entry.reach_s,
            speed=self.speed,
            heading=entry.heading,
            turns=self.turns,
            to_goal=row,
            hold_s=self.goal_hold_s,
            allowed=self._allowed,
            geometry=self.geometry,
        )

    def _time_fixed(self, entry: _Entry) -> TimedPlan | None:
        nodes = [entry.committed[-1], *entry.fixed]
        xy, index = self.plant.positions, self.plant.index
        lengths, directions = [], []
        for a, b in zip(nodes, nodes[1:], strict=False):
            lengths.append(self._lengths.get((a, b), 0.0))
            d = xy[index[b]] - xy[index[a]]
            norm = float(np.hypot(d[0], d[1]))
            directions.append((float(d[0] / norm), float(d[1] / norm)) if norm > 0 else None)
        return time_route(
            self._next_table,
            entry.vehicle,
            nodes,
            lengths,
            directions,
            entry.reach_s,
            speed=self.speed,
            heading=entry.heading,
            turns=self.turns,
            hold_s=self.goal_hold_s,
        )

    def _book(self, entry: _Entry, plan: TimedPlan | None) -> None:
        """Book the committed part and the plan up to the horizon together."""
        v = entry.vehicle
        self._made[v] = None
        if plan is None:
            self.failed += 1
            self._late.add(v)
            self._stand(entry)
            return
        t0, committed = self._t0, entry.committed
        claims = plan.claims
        last = 1
        while last + 1 < len(plan.nodes) and claims[last + 1] <= t0 + self.horizon_s:
            last += 1
        nodes = [(n, t0, entry.reach_s) for n in committed[:-1]]
        nodes.append((committed[-1], t0, plan.depart[0]))
        nodes += [(plan.nodes[i], claims[i], plan.depart[i]) for i in range(1, last + 1)]
        segments = [
            (a, b, t0, entry.reach_s) for a, b in zip(committed, committed[1:], strict=False)
        ]
        segments += [
            (plan.nodes[i], plan.nodes[i + 1], plan.depart[i], plan.arrive[i + 1])
            for i in range(last)
        ]
        self._next_table.book(v, nodes, segments)
        self._made[v] = plan
        self.plans += 1

    def _stand(self, entry: _Entry) -> None:
        """No plan: the vehicle stands on what it holds until the next round, so book that
        for good, and the vehicles planned after it go round it instead of waiting for it.
        Those planned before it in this round may already cross its frontier later on: the
        pass order then makes them wait for it (it plans first next round)."""
        committed, t0 = entry.committed, self._t0
        try:
            self._next_table.book(
                entry.vehicle,
                [(n, t0, math.inf) for n in committed],
                [(a, b, t0, entry.reach_s) for a, b in zip(committed, committed[1:], strict=False)],
            )
        except WindowConflict:
            pass  # its short windows stay booked

    def _swap(self, ctx: CycleContext) -> None:
        """The round is complete: its plans replace the old ones, all at once."""
        t0 = self._t0
        self.table = self._next_table
        self._next_table = None
        order = self.order = PassOrder()
        self._steps, self._front, self._goal, self._route = {}, {}, {}, {}
        for v, entry in self._entries.items():
            plan = self._made.get(v)
            committed = entry.committed
            labels = [t0] * len(committed)
            steps = list(committed)
            if plan is not None:
                claims = plan.claims
                for i in range(1, len(plan.nodes)):
                    if claims[i] > t0 + self.horizon_s and i > 1:
                        break
                    steps.append(plan.nodes[i])
                    labels.append(claims[i])
            order.set_plan(v, steps, labels)
            self._steps[v] = steps
            self._front[v] = len(committed) - 1
            self._goal[v] = entry.goal
            # what it has left since the round began (it drove on over its holds)
            held = {int(self.plant.ids[n]) for n in self.reservation.holds[v]}
            left = next((k for k, n in enumerate(committed) if n in held), len(committed) - 1)
            if left > 0:
                order.passed(v, left - 1)
            control = self.controls[v]
            if plan is not None:
                control.follow_plan(committed[-1], list(plan.nodes[1:]))
            elif entry.goal is None:
                control.follow_plan(committed[-1], [])  # there already: nothing to drive
        self.booked = len(self.table)
        self.planning = False
        self.rounds += 1


def _segment_lengths(plant: Plant) -> dict[tuple[int, int], float]:
    """Length of every segment by its end ids, both directions where it is driven both
    ways, return lanes included (they are timed, not searched)."""
    out: dict[tuple[int, int], float] = {}
    for e in plant.edges:
        out[(e.source, e.target)] = float(e.length)
        if e.bidirectional:
            out[(e.target, e.source)] = float(e.length)
    return out
