"""TimeWindowTraffic: plan every vehicle in time, execute the plans by order.

The time-window mode of the fleet's traffic (seed 004's planner, made robust to vehicles
that do not keep to their times). Planning runs in **rounds**, as rolling-horizon planners
do: a round takes every vehicle's state as it is, books what cannot change any more, plans
the vehicles that have somewhere to go one after another through the free windows left
(prioritised safe-interval planning), and then replaces all plans at once:

1. **Committed** (booked first, for every vehicle): the nodes it holds in the
   ReservationMatrix (where it is and what it was released), and the next few steps of its
   current plan, which it may still be released while this round is planned (up to a
   segment closed since). A plan that still leads to the same goal over open segments and
   is booked at least ``3/4 horizon_s`` ahead is kept whole instead and not searched
   again, so a round costs what the plans running out cost, not the fleet's size. No committed step may depend on a plan not made yet: one
   that follows a vehicle's frontier at its node is dropped, with the steps after it. Each node's
   committed visits keep their order, and their windows are laid one after the other from
   now (the holder first), so they never conflict. A vehicle with nowhere to go (no goal,
   at its goal, processing, held by an operator, stale, faulty, suspect) stays on its holds
   for good; a vehicle about to plan keeps its last committed node (the frontier) a little
   longer than it needs to reach it, so that nobody is planned across its nose before it
   can turn away.
2. **Planned**, most urgent first (the program's priority: the oldest task, a vehicle at a
   station first; a vehicle whose plan failed in the last round before every other): a
   :class:`SafeIntervalSearch` from the frontier, at the time the vehicle is estimated to
   reach it, to its goal, where it may stay. A route given by the job (a return lane) is
   timed along its nodes instead (:func:`time_route`). Only the steps that start within
   ``horizon_s`` are booked; beyond them nothing is released before the next round. With
   ``window_s`` set, plans are windowed too: conflicts are resolved only up to the round's
   cut-off (``window_s`` ahead, and past every committed window), but a vehicle out of
   service (silent, stalled, suspect), which stands for good, stays in the way past it
   too, so plans go round it as round a blockade instead of waiting for the cut-off to
   drive through it; any other vehicle is expected gone by then. A vehicle
   without a plan stands at its frontier, booked for good where nobody was planned
   across it already. When its plan fails
   because vehicles planned before it cross its frontier before it can get away, they
   give way: their plans are dropped and made again after its own (:meth:`_yield_to`).
   No search enters a dead end another vehicle is bound for (:meth:`_close_pockets`).
3. **Swap**: a fresh :class:`PassOrder` from the round's windows: committed visits in the
   order they had, planned ones by the time they claim the node. Each vehicle's control
   gets its route from wherever it has been released to meanwhile. A vehicle that took a
   node out of turn while the round was planned (an overtake, under the old order), or
   onto which a search planned another vehicle in the free time before its committed
   window, would find that other visit ordered before its own: that plan is cut short
   before the node (:meth:`_cut_before_holders`), so no visit is ever ordered before a
   vehicle already on its node.

A round takes on about as many searches as its budget gets through in ``replan_s``, so
that it lasts about that long, not as long as it takes to search the whole fleet: where
more vehicles want a search, plans that still lead to their goal are kept whole instead
(:meth:`_keep_beyond`).

A round's work is spread over scans, like the A* block's, ``budget`` units per scan: the
searches an expansion a unit; reading what the vehicles are committed to, laying it out
(one pass in topological order), booking it, and putting the new plans in a fresh pass
order :data:`VISITS_PER_UNIT` visits a unit. The new order then replaces the old one in
one step. Until the layout is fixed nobody is released a node it
was not released before; then the vehicles drive on within their committed steps, by the
old order, while the searches run. A new round
starts every ``replan_s`` seconds, and sooner when a vehicle needs one: a new goal, a plan
that ended at the horizon or did not match its route, a blockade closed or cleared.

Why no vehicle ever waits for one that waits for it: a vehicle waits only for a visit
ordered before its own at that node, whose vehicle leaves that node (claims its next step)
by the end of its window there, which ends before the waiting one's window starts. So every
wait points to a vehicle whose next step is labelled strictly earlier than the waiter's,
and labels cannot decrease round a circle.

Overtaking (the seed's swap at a node): a vehicle may take a node before vehicles planned
there earlier while none of them has come near it, if it can leave the node again at once
(its next step is its turn). It then waits for nobody while on the node, so those it
overtook wait for a vehicle that waits for nothing, and no circle of waits forms.

The controls release a node only when :meth:`gate` allows it: it is the next step of the
vehicle's plan, inside the horizon, and every visit planned there before its own has
passed (the vehicle reported the node after it), or it may overtake them. The ReservationMatrix still checks every
release (one holder per node), so the safety of the reactive mode holds whatever a plan
says; execution by order adds that no vehicle waits for one that waits for it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from blocks.routing.constraints import RoutingConstraints, highway_weights
from blocks.routing.heuristic import HeuristicTable, distances_to
from plc_runtime import CycleContext, FunctionBlock, Output
from topology import Plant
from topology.dead_ends import NO_POCKET, dead_end_pockets, pocket_entries

from .pass_order import PassOrder
from .path_heat import heat_weights, usage_along_distances
from .planners import (
    PlanRequest,
    PluggedSearch,
    WindowView,
    check_units,
    planner_names,
    plugged_planner,
    vetted,
    work_limit,
)
from .reservation import OUT_OF_SERVICE, ReservationMatrix
from .sipp import ArcGeometry, SafeIntervalSearch, TimedPlan, TurnTimes, time_route
from .time_windows import TimeWindowTable

# who a round plans first, among vehicles whose plan did not fail last round: "release",
# the seed's rule (the program's priority: the oldest task first); "nearest_goal", the
# vehicle with the least way left to its goal first, the program's priority breaking ties
PLAN_ORDERS = ("release", "nearest_goal")


# the label of every held node: first at its node (the vehicle is there). Held visits of one
# node or area are ordered by what follows the label in the layout's sort (only in an area
# can two vehicles hold nodes: an operator put one there)
HELD = -1e18
EXTEND = 2  # steps of its old plan a vehicle may still be released while a round is planned
# a round takes on at least this many searches, however dear the searches have been
MIN_SEARCHES = 8
# the estimate of a search's work before any search ended (expansions, walks counted)
FIRST_WORK_ESTIMATE = 100.0
# a round's set-up and swap, per unit of the budget: committed or planned visits read, laid
# out, booked or put in the pass order (about 2.5 us each in CPython, a search expansion
# about 25), so that a scan of set-up costs about as much as one of searches
VISITS_PER_UNIT = 10


@dataclass
class _Entry:
    """One vehicle in a round: what it is committed to, and where it wants to go."""

    vehicle: int
    committed: list[int]  # held node ids, then the old plan's next steps (the last: frontier)
    labels: list[float]  # their place in the pass order (held nodes first at theirs)
    ends: list[float]  # when it is expected to leave each (inf: it stays)
    offset: int  # the old plan's step index of committed[0]; -1: no old plan
    held: int  # how many of the committed nodes it holds (the first ones)
    reach_s: float = 0.0  # estimated time it reaches the frontier
    heading: tuple[float, float] | None = None
    goal: int | None = None  # None: it stays
    kept: bool = False  # its old plan stays, no search this round
    # how far ahead its old plan is booked, if it could be kept (same goal, not late)
    booked_ahead: float | None = None
    hold_end: float = math.inf  # the end of its frontier window before it was planned
    fixed: list[int] | None = None  # a given route after the frontier (a return lane)
    # out of service: where it stays (ends inf), it stays for good, in the way past the
    # cut-off too (else only until further notice: free from the cut-off on)
    lasting: bool = False
    starts: list[float] = field(default_factory=list)  # the windows' starts in this round


class TimeWindowTraffic(FunctionBlock):
    rounds = Output(0, doc="planning rounds completed")
    planning = Output(False, doc="a round is being planned: nothing new is released")
    plans = Output(0, doc="vehicle plans made")
    failed = Output(0, doc="vehicle plans not found (the vehicle waits for the next round)")
    expansions = Output(0, doc="search expansions in the last scan")
    booked = Output(0, doc="windows in the table of the current plans")
    overtakes = Output(0, doc="nodes taken before vehicles planned to pass them earlier")
    wait_replans = Output(0, doc="vehicles planned afresh after waiting too long for a node")
    stranded = Output(0, doc="vehicles without a path for longer than wait_occupied_s (FAULT)")
    give_ways = Output(0, doc="plans dropped to let a vehicle they boxed in get away first")
    cut_short = Output(
        0, doc="plans cut short at a swap: they put the vehicle before one already there"
    )
    kept_whole = Output(
        0, doc="plans kept whole, not searched again: more wanted a search than fit"
    )
    refused = Output(0, doc="plans of a plugged planner refused (the vehicle waits, as without)")

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
        window_s: float | None = None,
        replan_s: float = 2.0,
        budget: int = 200,
        wait_free_s: float = 15.0,
        wait_occupied_s: float = 30.0,
        path_heat: bool = False,
        highway_factor: float = 1.0,
        plan_order: str = "release",
        planner: str = "sipp",
    ) -> None:
        super().__init__()
        if plan_order not in PLAN_ORDERS:
            raise ValueError(f"plan_order must be one of {PLAN_ORDERS}, got {plan_order!r}")
        if planner not in planner_names():
            raise ValueError(f"planner must be one of {planner_names()}, got {planner!r}")
        # a planner of one's own (planners.py) instead of the safe-interval search
        self._planner = plugged_planner(planner)
        self._planner_limit = work_limit(plant)
        self.refused_reason: str | None = None  # why the first refused plan was refused
        if not (math.isfinite(horizon_s) and horizon_s > 0):
            raise ValueError(f"horizon_s must be a positive number of seconds, got {horizon_s!r}")
        window_s = math.inf if window_s is None else window_s
        if not window_s >= horizon_s:
            raise ValueError(
                f"window_s must be at least horizon_s ({horizon_s:g} s), got {window_s!r}"
            )
        if not (math.isfinite(replan_s) and replan_s > 0):
            raise ValueError(f"replan_s must be a positive number of seconds, got {replan_s!r}")
        if budget < 1:
            raise ValueError(f"budget must be at least 1 expansion per scan, got {budget!r}")
        for name, value in (("wait_free_s", wait_free_s), ("wait_occupied_s", wait_occupied_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
        self.plant = plant
        self.heuristic = heuristic
        self.reservation = reservation
        self.blockades = blockades
        self.priority = priority
        self.plan_order = plan_order
        self.speed, self.turns = float(speed), turns
        self.gap_s, self.horizon_s, self.replan_s = float(gap_s), float(horizon_s), replan_s
        # conflicts are resolved this far ahead (inf: no cut-off); plans are booked only up
        # to horizon_s
        self.window_s = float(window_s)
        self.budget = int(budget)
        self.path_heat = bool(path_heat)
        # the plant's highways: an arc against its lane's preferred direction costs this
        # many times its travel time (None: no highways, or a factor of 1)
        weights = highway_weights(plant, highway_factor)
        self._highways: list[float] | None = weights.tolist() if (weights != 1).any() else None
        self._weights: list[float] | None = None  # the round's arc weights (None: all 1)
        # the seed's wait thresholds: a vehicle that has waited this long for a node is
        # planned afresh (T_w1: the vehicle before it there has not come yet; T_w2: it is
        # on the node); one that then finds no path for T_w2 is reported stranded
        self.wait_free_ns = round(wait_free_s * 1e9)
        self.wait_occupied_ns = round(wait_occupied_s * 1e9)
        self._waits_handled: dict[int, int] = {}  # vehicle -> the wait it was replanned for
        # vehicle -> the round of its first failed plan in a row (a round that ends with a
        # plan for it ends the row)
        self._failing_since: dict[int, float] = {}
        self.stranded_at: dict[int, int] = {}  # stranded vehicle -> the node it stands on
        # how long a plan keeps its goal: until the next round at least, which books the
        # vehicle standing there for good if it stays (a vehicle that only keeps its goal
        # for the rest of time pushes every later plan around it)
        self.goal_hold_s = 2 * replan_s
        # how long a vehicle about to plan keeps its frontier past its arrival there, before
        # anyone planned earlier may cross it: long enough to turn away
        self.frontier_hold_s = turns.turn_180 + gap_s
        # a plan booked at least this far ahead is kept, not searched again: a round then
        # costs as much as the plans running out, not the fleet's size. Kept plans keep
        # their detours too: on kiva, half the horizon cost 12 % of the tasks at 60
        # vehicles (and gained 5 % at 140); three quarters cost 2.5 % (150 timesteps each)
        self.keep_s = 0.75 * horizon_s
        self.controls: Mapping = {}  # vehicle -> VehicleControl, set by the program
        self.geometry = ArcGeometry(plant)
        # a single-vehicle area is one resource in the plans: node id -> its area's name
        # (node ids are numbers, so a name never stands for a node)
        self.resources: dict[int, str] = {
            n: name for name, nodes in plant.areas.items() for n in nodes
        }
        # steps from each area node out of its area: of two vehicles in one area (put
        # there by an operator), the one nearer the way out leaves first
        self._exit_hops = _exit_hops(plant, self.resources)
        # dead ends (a station's spur, a queue siding): node index -> its pocket's root
        self._pocket: list[int] = dead_end_pockets(plant).tolist()
        self._pocket_entries = pocket_entries(plant, np.asarray(self._pocket))
        self.table = TimeWindowTable(gap_s, self.resources)  # the current plans' windows
        self.order = PassOrder()
        self._lengths = _segment_lengths(plant)
        self._ids: list[int] = plant.ids.tolist()
        self._directions: dict[tuple[int, int], tuple[float, float] | None] = {}
        # the current plans: vehicle -> booked step nodes, the step of its frontier (the
        # last one released), the goal the plan leads to, and its whole route
        self._steps: dict[int, list[int]] = {}
        self._front: dict[int, int] = {}
        self._goal: dict[int, int | None] = {}
        self._labels: dict[int, list[float]] = {}
        self._limit: dict[int, int] = {}  # while planning: the last step it may be released
        self._late: set[int] = set()  # vehicles whose plan failed: planned first next round
        # a search's work (expansions, walks counted), a moving average over the latest
        # searches: how many fit in a round
        self._work_per_search = FIRST_WORK_ESTIMATE
        self._due_ns = 0
        self._began_ns = 0
        self._min_gap_ns = round(replan_s * 1e9 / 4)
        self._allowed: list[bool] = []  # the open arcs this round (blockades closed)
        self._closed_pockets: set[int] = set()  # this round: pockets some vehicle is bound for
        self._pocket_allowed: list[bool] = []  # _allowed with those pockets' entries closed
        self._epoch = blockades.epoch
        self._wanted = False
        # the round being planned
        self._t0 = 0.0
        self._until = math.inf  # the round's cut-off: plans are conflict-free up to there
        self._book_until = math.inf  # plans are booked up to there (not past the cut-off)
        self._next_table: TimeWindowTable | None = None
        self._queue: list[_Entry] = []
        self._entries: dict[int, _Entry] = {}
        # the round's set-up: vehicles whose commitments are still to be read (empty: all
        # read, being laid out; None: laid out)
        self._pending: list[int] | None = None
        # the set-up and the swap under way, resumed scan by scan (generators of the work)
        self._committing: Iterator[int] | None = None
        self._staging: Iterator[int] | None = None
        self._staged: tuple[PassOrder, dict] | None = None
        self._search: SafeIntervalSearch | PluggedSearch | None = None
        self._made: dict[int, TimedPlan | None] = {}
        self._gave_way: set[int] = set()  # this round: planned again after a vehicle they blocked
        self._took_way: set[int] = set()  # this round: made others give way
        # what a round's start or swap replaced (a thousand vehicles' windows, visits and
        # entries): freed at the start of the next scan, not in the one that replaced it,
        # since freeing them takes milliseconds at that size
        self._retired: tuple | None = None

    # ----- what the controls ask ---------------------------------------------------------
    def gate(self, vehicle: int, node: int) -> tuple[bool, int | None]:
        """May ``vehicle`` be released into ``node`` (an id) now? (ok, the vehicle it waits
        for; None when it waits for a plan: its plan ends before, or a round is being planned
        and the node is beyond what that round took as committed)."""
        steps = self._steps.get(vehicle)
        if steps is None:
            self._wanted = True
            return False, None
        step = self._front[vehicle] + 1
        if self.planning and step > self._limit.get(vehicle, -1):
            return False, None
        if step >= len(steps) or steps[step] != node:
            self._wanted = True  # the horizon is reached, or the route changed
            return False, None
        blocker = self.order.blocker(vehicle, step)
        if blocker is not None and self._may_overtake(vehicle, step):
            return True, None
        return blocker is None, blocker

    def _may_overtake(self, vehicle: int, step: int) -> bool:
        """May ``vehicle`` take the node of ``step`` before the visits planned there
        earlier (the seed's swap at a node)? Only if none of those vehicles has come
        near it yet (none was released the node, nor its step before it), and the
        vehicle can leave it again at once: its next step is planned, releasable now, and
        its turn there in the order. Then it waits for nobody once on the node, so the
        vehicles it overtakes wait for one that waits for nothing: no circle of waits can
        form (a later overtaking keeps this, the same way)."""
        steps = self._steps[vehicle]
        after = step + 1
        if after >= len(steps) or (self.planning and after > self._limit.get(vehicle, -1)):
            return False
        if steps[after] == steps[step] or self.order.blocker(vehicle, after) is not None:
            return False
        if steps[step] in self.resources or steps[after] in self.resources:
            return False  # an area is not left at once, and others may be near its other nodes
        own = self.order.label(vehicle, step)
        for _label, other, other_step in self.order.pending(steps[step]):
            if (other, other_step) == (vehicle, step) or _label > own:
                break
            if self._front.get(other, other_step) >= other_step - 1:
                return False  # near or on the node: its turn stands
        return True

    def released(self, vehicle: int, node: int) -> None:
        """The control released ``node``, the step after its frontier (out of turn if
        :meth:`gate` let it overtake: its visit is then first there)."""
        if vehicle in self._steps:
            self._front[vehicle] += 1
            step = self._front[vehicle]
            if self.order.blocker(vehicle, step) is not None:
                self.order.take_turn(vehicle, step)
                self.overtakes += 1

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
        self._retired = None
        if not self.planning and self._round_due(ctx):
            self._begin(ctx)
        if not self.planning:
            return
        if self._pending:
            self._take_entries(ctx)
        elif self._pending is not None:
            self._commit(ctx)
        else:
            self._plan(ctx)

    def _resume(self, steps: Iterator[int], budget: int) -> bool:
        """Run ``steps`` (a generator that yields the visits it has just handled) until
        ``budget`` units' worth of visits are done this scan: True once it has finished."""
        allowance = budget * VISITS_PER_UNIT
        for visits in steps:
            allowance -= visits
            if allowance <= 0:
                return False
        return True

    def _round_due(self, ctx: CycleContext) -> bool:
        if ctx.time_ns >= self._due_ns:
            return True
        if ctx.time_ns < self._began_ns + self._min_gap_ns:
            return False  # rounds on demand, but not back to back
        if self._wanted or self._epoch != self.blockades.epoch:
            return True
        for v, c in self.controls.items():  # one pass over the fleet per scan
            if self._moving_goal(c) is not None and self._goal.get(v, -1) != c.goal:
                return True  # a new goal
            if self._overdue(v, c, ctx.time_ns):
                return True
        return False

    def _overdue(self, v: int, control, now_ns: int) -> bool:
        """Has ``v`` waited longer than the seed's threshold for the node it wants, and
        not been planned afresh for this wait yet?"""
        blocker = control.wait_blocker
        if blocker is None or self._waits_handled.get(v) == control.wait_since_ns:
            return False
        node = control.wait_node
        occupied = node is not None and self.plant.index[node] in self.reservation.holds.get(
            blocker, ()
        )
        limit = self.wait_occupied_ns if occupied else self.wait_free_ns
        return now_ns - control.wait_since_ns >= limit

    @staticmethod
    def _moving_goal(control) -> int | None:
        """Where a vehicle wants to drive now; None: it stays where it is."""
        if (
            control.state in OUT_OF_SERVICE
            or control.suspect
            or control.hold
            or control.goal is None
        ):
            return None
        if control.frontier == control.goal and control.fixed_route is None:
            return None  # there (a route that passed its goal and comes back is dropped)
        return control.goal

    # ----- a round -----------------------------------------------------------------------
    def _begin(self, ctx: CycleContext) -> None:
        """Start a round. Its set-up is spread over scans like its searches: first what
        each vehicle is committed to (:meth:`_take_entries`, ``budget`` units of visits
        per scan), then, in scans of their own, the layout and booking of those commitments
        (:meth:`_commit`). Until that layout is fixed nobody is released a node it was not
        released before, so every vehicle's commitments are read from one consistent state
        of the pass order, whichever scan reads them."""
        self.planning = True
        self._wanted = False
        self._epoch = self.blockades.epoch
        self._due_ns = ctx.time_ns + round(self.replan_s * 1e9)
        self._began_ns = ctx.time_ns
        self._allowed = (~self.blockades.blocked).tolist()
        self._t0 = ctx.time
        self._next_table = TimeWindowTable(self.gap_s, self.resources)
        self._retired = (self._entries, self._made)
        self._made, self._search = {}, None
        self._gave_way, self._took_way = set(), set()
        self._entries = {}
        self._queue = []
        self._limit = dict(self._front)  # released so far, and nothing more for now
        self._pending = list(reversed(self.controls))
        self._committing = self._staging = None

    def _take_entries(self, ctx: CycleContext) -> None:
        """Read vehicles' commitments (:meth:`_entry`), ``budget`` units' worth of their
        visits (:data:`VISITS_PER_UNIT`) per scan, and at least one vehicle."""
        allowance = self.budget * VISITS_PER_UNIT
        while self._pending and allowance > 0:
            v = self._pending.pop()
            control = self.controls[v]
            if self._overdue(v, control, ctx.time_ns):
                self._waits_handled[v] = control.wait_since_ns
                self._late.add(v)  # planned first, from where it stands
                self.wait_replans += 1
            entry = self._entry(v, control)
            allowance -= 1
            if entry is not None:
                self._entries[v] = entry
                allowance -= len(entry.committed)

    def _commit(self, ctx: CycleContext) -> None:
        """Lay out and book what the vehicles are committed to, and queue the searches:
        ``budget`` units of it per scan (:data:`VISITS_PER_UNIT`), like the searches, so
        that a thousand vehicles' commitments do not make one scan long. Until it is done
        nobody is released a node it was not released before."""
        if self._committing is None:
            self._committing = self._commit_steps(ctx)
        if self._resume(self._committing, self.budget):
            self._committing = None
            self._pending = None
            self._limit = {
                v: e.offset + len(e.committed) - 1
                for v, e in self._entries.items()
                if e.offset >= 0
            }

    def _commit_steps(self, ctx: CycleContext) -> Iterator[int]:
        fit = self._fit(ctx)
        kept = yield from self._keep_beyond(fit)
        yield from self._chain()
        # conflicts are resolved up to the window (and past every committed window, which
        # this round's searches must all see); plans are booked up to the horizon
        self._until = max(
            [self._t0 + self.window_s, *(e.starts[-1] + 1.0 for e in self._entries.values())]
        )
        self._book_until = self._t0 + self.horizon_s
        self.kept_whole += sum(e.kept for e in kept)  # (the layout may cut a kept plan short)
        movers = []
        for entry in self._entries.values():
            self._book_committed(entry)
            if entry.goal is not None and not entry.kept:
                movers.append(entry)
            yield len(entry.committed)
        self._close_pockets()
        self._weights = self._arc_weights()
        late = self._late
        self._queue = sorted(movers, key=lambda e: (e.vehicle not in late, *self._urgency(e)))
        self._late = set()

    def _close_pockets(self) -> None:
        """Close to this round's searches every dead end a vehicle is bound for (its goal
        lies in it), but to the vehicles bound for it or in it. A dead end is nobody's way
        through, only a place to wait, and a vehicle planned to wait in one another vehicle
        is sent to (a station's spur: the next vehicle that station serves) can only come
        out through the node that vehicle waits on in front of it. Both then wait for ever
        once the one inside has no plan for a round: the plans past the cut-off do not see
        it (the reactive resolver never pushes a vehicle into an area, for the same
        reason)."""
        pocket, index = self._pocket, self.plant.index
        closed = set()
        for control in self.controls.values():
            goal = control.goal
            if goal is not None and goal in index and pocket[index[goal]] != NO_POCKET:
                closed.add(pocket[index[goal]])
        self._closed_pockets = closed
        allowed = self._allowed
        if closed:
            allowed = list(allowed)
            for root in closed:
                for arc in self._pocket_entries.get(root, ()):
                    allowed[arc] = False
        self._pocket_allowed = allowed

    def _allowed_for(self, entry: _Entry) -> list[bool]:
        """The arcs ``entry``'s search may use: the round's, with the dead ends closed
        (:meth:`_close_pockets`) but for the one its goal lies in and the one it stands in."""
        index, pocket = self.plant.index, self._pocket
        own = {pocket[index[entry.goal]], pocket[index[entry.committed[-1]]]}
        own &= self._closed_pockets
        if not own:
            return self._pocket_allowed
        allowed = list(self._pocket_allowed)
        for root in own:
            for arc in self._pocket_entries.get(root, ()):
                allowed[arc] = self._allowed[arc]
        return allowed

    def _urgency(self, entry: _Entry) -> tuple:
        """Sort key of who is planned first (``plan_order``). Nearest the goal first lets
        a round book the short plans before the long ones: those vehicles are soon off
        the lanes, where the other order sends them round the long plans booked before
        theirs (what that gains, fleet size by fleet size: docs/benchmarks.md)."""
        if self.plan_order == "release":
            return (self.priority(entry.vehicle),)
        left = self.heuristic.distance(entry.committed[-1], entry.goal)
        return (math.inf if left is None else left, self.priority(entry.vehicle))

    def _keep_beyond(self, fit: int) -> Iterator[int]:
        """A round searches about as many vehicles as the budget gets through in
        ``replan_s`` at the latest searches' cost (``fit``): a round that searched a thousand
        vehicles would outlast the plans it replaces, and the vehicles would stand at
        their ends. So where more vehicles want a search, those that still have a plan to
        their goal keep it whole, however soon it runs out, the plans that run out latest
        first, until the others fit (returned: those kept; the layout may still cut one
        short, and that vehicle is searched after all). A vehicle whose plan failed or
        that waited too long, or that has no plan to keep (a new goal, or its plan ran
        out), is searched all the same, so a round can take on more than ``fit`` (a fleet
        starting, or one whose plans run out faster than the budget replaces them):
        putting those off too made them stand in the others' way, and cost more tasks at
        1000 vehicles than it saved. (A generator: yields the visits it looked at.)"""
        wanting = [
            e for e in self._entries.values() if e.goal is not None and not e.kept and not e.fixed
        ]
        spare = len(wanting) - fit
        keepable = sorted(
            (e for e in wanting if e.booked_ahead is not None),
            key=lambda e: (-e.booked_ahead, self.priority(e.vehicle)),
        )
        kept = []
        yield len(wanting)
        for entry in keepable:
            if len(kept) >= spare:
                break
            if self._keep_whole(entry):
                kept.append(entry)
            yield len(entry.committed)
        return kept

    def _fit(self, ctx: CycleContext) -> int:
        """How many searches a round takes on: as many as ``budget`` expansions per scan
        get through in ``replan_s`` at the work of a search, a moving average weighted
        towards the latest searches (about the last ten)."""
        scans = self.replan_s * 1e9 / ctx.interval_ns
        return max(MIN_SEARCHES, math.ceil(self.budget * scans / self._work_per_search))

    def _arc_weights(self) -> list[float] | None:
        """This round's cost factor per arc for the searches: path heat times the
        highway factor (None: all 1, the search's fast path)."""
        if not self.path_heat:
            return self._highways
        heat = self._heat()
        return (
            heat
            if self._highways is None
            else [h * w for h, w in zip(heat, self._highways, strict=True)]
        )

    def _heat(self) -> list[float]:
        """The seed's path heat for this round's searches: ``h`` from the shortest route
        of every vehicle with a goal, from its frontier (the routes the period will
        drive if nobody is steered off them), ``b`` from the vehicles driving along each
        arc now (from the node they hold to the one they were released next)."""
        plant, table = self.plant, self.heuristic
        routes = []
        for e in self._entries.values():
            row = table.row(e.goal) if e.goal is not None and table.has_row(e.goal) else None
            if row is not None:
                routes.append((plant.idx(e.committed[-1]), row))
        usage = usage_along_distances(plant, routes)
        occupancy = np.zeros(plant.n_arcs, dtype=np.int64)
        ids = plant.ids
        for holds in self.reservation.holds.values():
            if len(holds) >= 2:
                arcs = plant.arc_index.get((int(ids[holds[0]]), int(ids[holds[1]])))
                if arcs:
                    occupancy[arcs[0]] += 1
        return heat_weights(usage, occupancy).tolist()

    def _entry(self, v: int, control) -> _Entry | None:
        """What ``v`` is committed to: the nodes it holds and, while it drives on during
        the round, the next steps of its old plan (labelled as they were)."""
        held = [self._ids[n] for n in self.reservation.holds[v]]
        if control.current is None or not held:
            return None
        goal = self._moving_goal(control)
        steps, front = self._steps.get(v), self._front.get(v)
        offset = -1
        if steps is not None and front is not None and front + 1 >= len(held):
            if steps[front + 1 - len(held) : front + 1] == held:
                offset = front + 1 - len(held)
        committed = list(held)
        labels = [HELD] * len(held)
        kept = False
        booked_ahead = None
        if offset >= 0 and goal is not None and front + 1 < len(steps):
            # a plan that still leads to the same goal for a while is kept whole; otherwise
            # a vehicle on its way (its next step free to take) drives on meanwhile, and
            # one that waits is planned afresh from where it is
            old = self._labels[v]
            # (a control that dropped the route, back in service after a suspicion, or
            # that could not take the plan, follows none: it is searched again)
            if v not in self._late and self._goal.get(v) == goal and control.route:
                booked_ahead = old[-1] - self._t0
                kept = steps[-1] == goal or booked_ahead >= self.keep_s
            waits_long = v in self._late and control.wait_blocker is not None
            if kept or (self.order.blocker(v, front + 1) is None and not waits_long):
                last = len(steps) if kept else min(front + 1 + EXTEND, len(steps))
                for k in range(front + 1, last):
                    if steps[k] in committed:
                        kept = False  # coming back: not released before the frontier
                        break
                    if not self._open(committed[-1], steps[k]):
                        kept = False  # a segment closed since it was planned: round it
                        break
                    committed.append(steps[k])
                    labels.append(old[k])
        entry = _Entry(v, committed, labels, [], offset, len(held), goal=goal, kept=kept)
        # out of service (silent, stalled, suspect), it stays where it is for good: in the
        # way past the cut-off too. Any other vehicle goes on when it is given a plan or its
        # next goal: treated as a wall past the cut-off, the plans of a busy plant went the
        # long way round vehicles that were gone long before they got there.
        # A vehicle an operator holds stays as long as the hold does: past the cut-off too,
        # or every plan through its node waits there for the cut-off, fails, and is tried
        # again round after round while the way round it stays unused.
        entry.lasting = control.state in OUT_OF_SERVICE or control.suspect or bool(control.hold)
        entry.booked_ahead = booked_ahead
        self._time_committed(entry)
        if goal is not None and control.fixed_route is not None:
            fixed = list(control.fixed_route)
            front_node = committed[-1]
            entry.fixed = fixed[fixed.index(front_node) + 1 :] if front_node in fixed else None
            if not entry.fixed:
                entry.goal = None
                entry.ends = [math.inf] * len(committed)
        return entry

    def _open(self, a: int, b: int) -> bool:
        """May a vehicle drive from node ``a`` to node ``b`` (ids) in this round's plans?"""
        arcs = self.plant.arc_index.get((a, b))
        return bool(arcs) and any(self._allowed[arc] for arc in arcs)

    def _time_committed(self, entry: _Entry) -> None:
        """When the vehicle is estimated to reach its frontier, its heading there, and when
        it leaves each committed node."""
        committed, labels = entry.committed, entry.labels
        entry.reach_s, entry.heading = self._drive(committed, self._t0)
        if entry.goal is None:
            entry.ends = [math.inf] * len(committed)
        else:
            # it leaves a node when it sets off towards the next one: not before it
            # arrives there (estimated), nor before that step's place in the order
            arrive = self._arrivals(committed, self._t0)
            entry.ends = [max(arrive[k + 1], labels[k + 1]) for k in range(len(committed) - 1)]
            entry.ends.append(entry.reach_s + self.frontier_hold_s)

    def _keep_whole(self, entry: _Entry) -> bool:
        """Commit ``entry``'s vehicle to the rest of its old plan too, however soon that
        runs out (its committed steps are that plan's, from ``offset`` on). False, and the
        entry unchanged, where the plan comes back to a node committed before it."""
        v = entry.vehicle
        first = entry.offset + len(entry.committed)
        rest = self._steps[v][first:]
        if len(set(entry.committed).union(rest)) < len(entry.committed) + len(rest):
            return False
        path = [entry.committed[-1], *rest]
        if not all(self._open(a, b) for a, b in zip(path, path[1:], strict=False)):
            return False  # a segment closed since it was planned
        entry.committed += rest
        entry.labels += self._labels[v][first:]
        entry.kept = True
        self._time_committed(entry)
        return True

    def _chain(self) -> Iterator[int]:
        """Lay out the committed windows: at each node one after the other in the order the
        visits had (a held node first: the vehicle is there), from now; along each vehicle
        never earlier than its step before, and each window lasting until the next one of
        that vehicle begins (it leaves a node by setting off towards the next). Each start
        becomes the visit's label, so every committed label is a window start in this one
        table. A committed step must not depend on a plan not made yet, so an old plan's
        step is dropped (with all after it) where a vehicle ordered before it at that node
        stays there for good or only reaches it as its frontier (from there it leaves by its
        new plan, which may not be found), and where it goes on inside an area another
        vehicle holds a node of too. If the old order cannot be laid out (it never should),
        only the held nodes stay, and if even they cannot, nobody moves this round. (A
        generator: yields the visits it has just looked at.)"""
        key = self.resources.get
        # areas two vehicles hold nodes of (an operator put one there): neither is committed
        # further into it, whose visits there the layout could not keep apart
        holders: dict[Hashable, set[int]] = {}
        for e in self._entries.values():
            for node in e.committed[: e.held]:
                if node in self.resources:
                    holders.setdefault(key(node), set()).add(e.vehicle)
        shared = {area for area, vehicles in holders.items() if len(vehicles) > 1}
        yield len(self._entries)
        cut = True
        while cut:
            cut = False
            # node (its area, if in one) -> the earliest label of a visit ending there
            stays: dict[Hashable, float] = {}
            for e in self._entries.values():
                k = 0 if e.goal is None else len(e.committed) - 1
                for node, label in zip(e.committed[k:], e.labels[k:], strict=True):
                    stays[key(node, node)] = min(stays.get(key(node, node), math.inf), label)
                yield len(e.committed) - k
            for e in self._entries.values():
                k = next(
                    (
                        k
                        for k in range(e.held, len(e.committed))
                        if stays.get(key(e.committed[k], e.committed[k]), math.inf) < e.labels[k]
                        or key(e.committed[k], None) in shared
                    ),
                    None,
                )
                if k is not None:
                    self._cut(e, k)
                    cut = True
                yield len(e.committed) // 4 + 1  # a look at each visit: a quarter of one
        if not (yield from self._lay_out()):
            for e in self._entries.values():
                self._cut(e, e.held)
            if not (yield from self._lay_out()):
                for e in self._entries.values():  # nobody moves this round
                    e.goal, e.kept, e.fixed = None, False, None
                    e.starts = [self._t0] * len(e.committed)
                    e.ends = [math.inf] * len(e.committed)
        for e in self._entries.values():
            e.labels = list(e.starts)

    def _lay_out(self) -> Iterator[int]:
        """Give every committed visit the earliest start and end that keep the rules:

        * at each node the visits follow each other in their order, the next one starting
          ``gap_s`` after the one before it ends (in a single-vehicle area: after the
          vehicle before has left the area, i.e. after the end of its last step there);
          one vehicle's visits that follow each other there (its steps inside an area, or
          a node it comes back to) need no gap, the later one only ends no earlier;
        * a vehicle's visits start in the order of its steps;
        * a window lasts at least until the vehicle arrives (it set off when the window
          began), so a vehicle driving into a node is still on it, and on the segment to
          it, when the next one there may set off; and until its next window begins (it
          leaves a node by setting off towards the next one).

        These rules are a graph of earliest-time constraints (each start and each end a
        vertex), so the earliest times are its longest paths, found in one pass in
        topological order: the cost of a round's set-up grows with the committed visits,
        never with how far the rules push them. Returns False if the rules form a circle
        (the old order had one; it never should). (A generator: yields the visits it has
        just handled.)"""
        t0, gap = self._t0, self.gap_s
        entries = list(self._entries.values())
        base: dict[int, int] = {}  # vehicle -> index of its first visit
        value: list[float] = []  # 2i: start of visit i, 2i + 1: its end
        out: list[list[tuple[int, float]]] = []
        # by node, or by area: (label, then for visits of one label, i.e. vehicles holding
        # nodes of one area: movers before vehicles that stay, nearest the way out first,
        # vehicle, visit)
        visits: dict[Hashable, list[tuple[float, bool, int, int, int]]] = {}
        key, hops = self.resources.get, self._exit_hops
        for e in entries:
            first = base[e.vehicle] = len(value) // 2
            stays = e.ends[-1] == math.inf
            near: dict[Hashable, int] = {}  # area -> the vehicle's held node nearest its exit
            for node in e.committed[: e.held]:
                if node in hops:
                    near[key(node)] = min(near.get(key(node), hops[node]), hops[node])
            for k, (node, label) in enumerate(zip(e.committed, e.labels, strict=True)):
                i = first + k
                value += [t0, e.ends[k]]
                leg = self._lengths.get((e.committed[k - 1], node), 0.0) / self.speed if k else 0.0
                out += [[(2 * i + 1, leg)], []]
                if k:
                    out[2 * i - 2].append((2 * i, 0.0))  # after its step before
                    out[2 * i].append((2 * i - 1, 0.0))  # the step before lasts until this one
                where = key(node, node)
                rank = (label, stays, near.get(where, 0), e.vehicle, i)
                visits.setdefault(where, []).append(rank)
            yield len(e.committed)
        for queue in visits.values():
            queue.sort()
            for (*_, va, a), (*_, vb, b) in zip(queue, queue[1:], strict=False):
                if va != vb:
                    out[2 * a + 1].append((2 * b, gap))
                else:  # one vehicle again (inside an area, or back): it leaves last
                    out[2 * a + 1].append((2 * b + 1, 0.0))
            yield len(queue)
        indegree = [0] * len(value)
        for u, edges in enumerate(out):
            for w, _ in edges:
                indegree[w] += 1
            if not u % 256:
                yield 64
        ready = [u for u, d in enumerate(indegree) if d == 0]
        done = 0
        while ready:
            u = ready.pop()
            done += 1
            for w, weight in out[u]:
                if value[u] + weight > value[w]:
                    value[w] = value[u] + weight
                indegree[w] -= 1
                if indegree[w] == 0:
                    ready.append(w)
            if not done % 256:
                yield 128  # two vertices (a start and an end) to a visit
        if done < len(value):
            return False
        for e in entries:
            first = base[e.vehicle]
            n = len(e.committed)
            e.starts = value[2 * first : 2 * (first + n) : 2]
            e.ends = value[2 * first + 1 : 2 * (first + n) : 2]
        return True

    def _cut(self, e: _Entry, k: int) -> None:
        """Commit ``e`` only to its steps before ``k`` (never fewer than it holds)."""
        k = max(k, e.held)
        if k >= len(e.committed):
            return
        e.kept = False
        e.committed, e.labels, e.ends = e.committed[:k], e.labels[:k], e.ends[:k]
        e.reach_s, e.heading = self._drive(e.committed, self._t0)
        if e.goal is not None:
            e.ends[-1] = max(e.ends[-1], e.reach_s + self.frontier_hold_s)
        if e.fixed is not None:
            e.goal = None  # its given route goes on from further along: next round
            e.ends = [math.inf] * len(e.committed)

    def _book_committed(self, entry: _Entry) -> None:
        """Book what ``entry`` is committed to, as :meth:`_chain` laid it out (consistent by
        construction, so booked without the rules)."""
        self._next_table.book(
            entry.vehicle,
            list(zip(entry.committed, entry.starts, entry.ends, strict=True)),
            self._committed_segments(entry),
            check=False,
            lasting=entry.lasting,
        )

    def _committed_segments(self, entry: _Entry) -> list[tuple[int, int, float, float]]:
        out = []
        for k in range(1, len(entry.committed)):
            a, b = entry.committed[k - 1], entry.committed[k]
            start = entry.starts[k]
            out.append((a, b, start, start + self._lengths.get((a, b), 0.0) / self.speed))
        return out

    def _arrivals(self, nodes: list[int], t0: float) -> list[float]:
        """Estimated arrival at each of ``nodes``, driving from the first at ``t0``."""
        out, t = [t0], t0
        for a, b in zip(nodes, nodes[1:], strict=False):
            t += self._lengths.get((a, b), 0.0) / self.speed
            out.append(t)
        return out

    def _drive(self, nodes: list[int], t0: float) -> tuple[float, tuple[float, float] | None]:
        """Estimated arrival at the last of ``nodes`` (driving from the first at ``t0``) and
        the heading it arrives with (None: standing, unknown)."""
        steps = [self._direction(a, b) for a, b in zip(nodes, nodes[1:], strict=False)]
        heading = next((d for d in reversed(steps) if d is not None), None)
        return self._arrivals(nodes, t0)[-1], heading

    def _direction(self, a: int, b: int) -> tuple[float, float] | None:
        """Unit vector from node ``a`` to node ``b`` (ids); None where they coincide.
        Remembered per pair: a round times thousands of committed steps."""
        pair = (a, b)
        if pair not in self._directions:
            index = self.plant.index
            d = self.plant.positions[index[b]] - self.plant.positions[index[a]]
            norm = float(np.hypot(d[0], d[1]))
            self._directions[pair] = (float(d[0] / norm), float(d[1] / norm)) if norm > 0 else None
        return self._directions[pair]

    def _plan(self, ctx: CycleContext) -> None:
        budget = self.budget
        while budget > 0:
            if self._search is None:
                if not self._queue:
                    self._stage(ctx, budget)
                    return
                entry = self._queue.pop(0)
                if entry.fixed is not None:
                    self._book(entry, self._time_fixed(entry))
                    budget -= len(entry.fixed)
                    continue
                self._search = self._start_search(entry)
            search = self._search
            before, work = search.expansions, search.work
            search.step(budget)
            budget -= max(search.work - work, 1)
            self.expansions += search.expansions - before
            if search.done:
                self._search = None
                # at least a unit a search: searches that do no work (a plugged planner
                # that answers at once) must not bring the estimate to nothing
                self._work_per_search += 0.1 * (max(search.work, 1) - self._work_per_search)
                plan = search.plan
                if isinstance(search, PluggedSearch):
                    plan = self._checked(search)
                    budget -= check_units(plan)
                if plan is not None and len(plan.nodes) > 1 and plan.claims[1] >= self._until:
                    # it only waits where it is until the cut-off: no plan. Taken as one,
                    # every vehicle in a jam would wait for the cut-off, round after round
                    plan = None
                self._book(self._entries[search.vehicle], plan)

    def _start_search(self, entry: _Entry) -> SafeIntervalSearch | PluggedSearch:
        goal = entry.goal
        row = self.heuristic.row(goal) if self.heuristic.has_row(goal) else None
        if self._planner is not None:
            return PluggedSearch(self._planner, self._request(entry, row), self._planner_limit)
        return SafeIntervalSearch(
            self.plant,
            self._next_table,
            entry.vehicle,
            entry.committed[-1],
            goal,
            self._set_off(entry),
            speed=self.speed,
            heading=entry.heading,
            turns=self.turns,
            to_goal=row,
            hold_s=self.goal_hold_s,
            allowed=self._allowed_for(entry),
            geometry=self.geometry,
            until=self._until,
            weights=self._weights,
            labels="cheapest",  # searches as small as without weights (sipp.py)
        )

    def _request(self, entry: _Entry, row: np.ndarray | None) -> PlanRequest:
        """What a plugged planner is told of ``entry``'s vehicle and this round."""
        if row is None:  # a goal whose row is still being computed: this one alone
            row = distances_to(self.plant, [entry.goal])[0]
        # read-only copies: the heuristic table's row and the round's arc lists serve every
        # other search too
        to_goal = row.copy()
        to_goal.flags.writeable = False
        weights = None if self._weights is None else tuple(self._weights)
        return PlanRequest(
            vehicle=entry.vehicle,
            start=entry.committed[-1],
            goal=entry.goal,
            start_s=self._set_off(entry),
            heading=entry.heading,
            speed=self.speed,
            turns=self.turns,
            hold_s=self.goal_hold_s,
            horizon_s=self._book_until,
            until_s=self._until,
            plant=self.plant,
            windows=WindowView(self._next_table),
            allowed=tuple(self._allowed_for(entry)),
            to_goal=to_goal,
            weights=weights,
            geometry=self.geometry,
        )

    def _checked(self, search: PluggedSearch) -> TimedPlan | None:
        """A plugged planner's plan as the program books it, if it may take it (:func:`vetted`);
        None, counted with its reason, if not."""
        fault, plan = search.refused, search.plan
        if plan is not None:
            entry = self._entries[search.vehicle]
            plan, fault = vetted(
                plan, search.request, self._book_until, entry.starts[-1], self._next_table
            )
            if fault is not None:
                fault = f"vehicle {search.vehicle}: {fault}"
        if fault is None:
            return plan
        self.refused += 1
        if self.refused_reason is None:
            self.refused_reason = fault
        return None

    def _time_fixed(self, entry: _Entry) -> TimedPlan | None:
        nodes = [entry.committed[-1], *entry.fixed]
        pairs = list(zip(nodes, nodes[1:], strict=False))
        lengths = [self._lengths.get(pair, 0.0) for pair in pairs]
        directions = [self._direction(a, b) for a, b in pairs]
        return time_route(
            self._next_table,
            entry.vehicle,
            nodes,
            lengths,
            directions,
            self._set_off(entry),
            speed=self.speed,
            heading=entry.heading,
            turns=self.turns,
            hold_s=self.goal_hold_s,
        )

    def _set_off(self, entry: _Entry) -> float:
        """When its plan may start at the frontier: its estimated arrival there, but not
        before its window on it opens."""
        return max(entry.reach_s, entry.starts[-1])

    def _book(self, entry: _Entry, plan: TimedPlan | None) -> None:
        """Book the committed part and the plan up to the horizon together."""
        v = entry.vehicle
        if plan is None and self._yield_to(entry):
            return
        self._made[v] = None
        if plan is None:
            self.failed += 1
            self._late.add(v)
            self._failing_since.setdefault(v, self._t0)
            self._stand(entry)
            return
        # whether it is failing still is the swap's to say: a plan made here may yet be
        # dropped to let another vehicle get away, and its failing clock must not restart
        claims = plan.claims
        last = self._last_booked(plan)
        entry.hold_end = entry.ends[-1]
        entry.ends[-1] = plan.depart[0]
        nodes = list(zip(entry.committed, entry.starts, entry.ends, strict=True))
        nodes += [(plan.nodes[i], claims[i], plan.depart[i]) for i in range(1, last + 1)]
        segments = self._committed_segments(entry)
        segments += [
            (plan.nodes[i], plan.nodes[i + 1], plan.depart[i], plan.arrive[i + 1])
            for i in range(last)
        ]
        self._next_table.book(v, nodes, segments, check=False)  # the search kept the rules
        self._made[v] = plan
        self.plans += 1

    def _yield_to(self, entry: _Entry) -> bool:
        """No path for ``entry``'s vehicle because vehicles planned before it in this round
        cross its frontier before it can get away: they give way instead. Their plans are
        dropped (back to what they are committed to), the vehicle is planned again at once,
        and they after it. A vehicle that was made to give way never makes others give
        way, and one that did is never made to: so it ends, and each vehicle is searched at
        most twice a round. False (nothing changed) if a committed window or a vehicle that
        cannot give way is in the way."""
        v = entry.vehicle
        if v in self._gave_way:
            return False
        front, start = entry.committed[-1], entry.starts[-1]
        crossing = set()
        for w in self._next_table.node_windows(front):
            if w.vehicle == v or w.end < start:
                continue
            other = self._entries.get(w.vehicle)
            if (
                other is None
                or self._made.get(w.vehicle) is None
                or w.vehicle in self._took_way
                or w.start < other.starts[-1] + 1e-9  # its committed window: fixed
            ):
                return False
            crossing.add(w.vehicle)
        if not crossing:
            return False
        for o in sorted(crossing):
            other = self._entries[o]
            # on its frontier until it is planned again: as long as those planned before it
            # counted on, but no longer than those planned after it did
            other.ends[-1] = min(other.hold_end, other.ends[-1])
            self._book_committed(other)
            del self._made[o]
            self.plans -= 1
        self._gave_way |= crossing
        self._took_way.add(v)
        self.give_ways += 1
        order = sorted(crossing, key=lambda o: self._urgency(self._entries[o]))
        self._queue[0:0] = [entry, *(self._entries[o] for o in order)]
        return True

    def _last_booked(self, plan: TimedPlan) -> int:
        """The plan's last step whose window starts before the round's cut-off: the steps
        after it were planned against nobody, and are planned again next round."""
        claims, last = plan.claims, 0
        while last + 1 < len(plan.nodes) and claims[last + 1] < self._book_until:
            last += 1
        return last

    def _stand(self, entry: _Entry) -> None:
        """No plan: the vehicle stands at its frontier until the next round, so book that
        for good, and the vehicles planned after it go round it instead of waiting for it.
        Those planned before it in this round may already cross its frontier later on: then
        it keeps its short window there, and the pass order makes them wait for it (it
        plans first next round)."""
        front = entry.committed[-1]
        start = entry.starts[-1]
        if any(
            w.vehicle != entry.vehicle and w.end >= start
            for w in self._next_table.node_windows(front)
        ):
            return
        entry.ends[-1] = math.inf
        self._book_committed(entry)

    def _stage(self, ctx: CycleContext, budget: int) -> None:
        """Every plan of the round is made: put them in a new pass order, ``budget`` units
        of it per scan (:data:`VISITS_PER_UNIT`), then swap (the old order rules
        meanwhile)."""
        if self._staging is None:
            self._staging = self._stage_steps()
        if self._resume(self._staging, budget):
            self._staging = None
            self._swap(ctx)

    def _stage_steps(self) -> Iterator[int]:
        order = PassOrder()
        staged: dict[int, tuple[list[int], list[float], list[int]]] = {}
        for v, entry in self._entries.items():
            plan = self._made.get(v)
            steps, labels = list(entry.committed), list(entry.labels)
            beyond: list[int] = []
            if plan is not None:
                last = self._last_booked(plan)
                steps += plan.nodes[1 : last + 1]
                labels += plan.claims[1 : last + 1]
                beyond = list(plan.nodes[last + 1 :])
            order.set_plan(v, [self.resources.get(n, n) for n in steps], labels)
            staged[v] = steps, labels, beyond
            yield len(steps)
        self._staged = order, staged

    def _swap(self, ctx: CycleContext) -> None:
        """The round is complete: its plans replace the old ones, all at once. A vehicle may
        have been released further along its committed steps while the round was planned:
        it goes on from there."""
        self._retired = (self.table, self.order, self._steps, self._labels)
        self.table = self._next_table
        self._next_table = None
        order, staged = self._staged
        self._staged = None
        steps_of, front_of, goal_of, labels_of = {}, {}, {}, {}
        for v, entry in self._entries.items():
            plan = self._made.get(v)
            steps, labels, beyond = staged[v]
            # released since the round began: along its committed steps (the old plan)
            front = len(entry.committed) - 1
            if entry.offset >= 0:
                front = min(self._front[v] - entry.offset, front)
            held = {self._ids[n] for n in self.reservation.holds[v]}
            left = next((k for k, n in enumerate(steps) if n in held), 0)
            if left > 0:
                order.passed(v, left - 1)
            steps_of[v], front_of[v], goal_of[v] = steps, front, entry.goal
            labels_of[v] = labels
            control = self.controls[v]
            if plan is not None:
                control.follow_plan(steps[front], steps[front + 1 :] + beyond)
            elif entry.goal is None:
                control.follow_plan(steps[front], [])  # there already: nothing to drive
        self._cut_before_holders(order, steps_of, front_of, labels_of)
        self.order = order
        self._steps, self._front, self._goal = steps_of, front_of, goal_of
        self._labels = labels_of
        self._limit = {}
        for v in list(self._failing_since):
            # not planned this round (it stays, or is kept), or planned in the end
            if v not in self._late or self._made.get(v) is not None:
                del self._failing_since[v]
        self.stranded_at = {
            v: self._entries[v].committed[-1]
            for v, since in self._failing_since.items()
            if round((self._t0 - since) * 1e9) >= self.wait_occupied_ns
        }
        self.stranded = len(self.stranded_at)
        self.booked = len(self.table)
        self.planning = False
        self.rounds += 1

    def _cut_before_holders(
        self,
        order: PassOrder,
        steps_of: dict[int, list[int]],
        front_of: dict[int, int],
        labels_of: dict[int, list[float]],
    ) -> None:
        """Cut every new plan short before a visit the order puts ahead of a vehicle that
        is already on that node (or in that area). The holder may have overtaken that visit
        while the round was planned (the round laid it out in the old order), or a search
        may have claimed the node in the free time before the holder's committed window
        there; either way the plan is out of step with it: the planned vehicle would wait
        for it to leave, while it may wait for the planned one at its next node (head-on
        on neighbouring nodes, each waiting for the other). Cut short, the planned vehicle
        waits at the end of what is left of its plan, for nobody, and the next round,
        which that wait asks for, plans it on from there. Only the nodes a vehicle was
        released while the round was planned are looked at: those it held when the round
        began come first in their order. A step the other vehicle was released already is
        never cut (it may be driving onto it)."""
        cut: dict[int, int] = {}
        for v, front in front_of.items():
            for k in range(max(order.progress(v), self._entries[v].held), front + 1):
                for other, step in order.ahead(v, k):
                    if step > front_of[other]:
                        cut[other] = min(cut.get(other, step), step)
        for v, step in cut.items():
            order.cut(v, step)
            steps_of[v] = steps_of[v][:step]
            labels_of[v] = labels_of[v][:step]
        self.cut_short += len(cut)


def _exit_hops(plant: Plant, areas: Mapping[int, str]) -> dict[int, int]:
    """For each node of a single-vehicle area, the fewest steps to a node outside it (a
    node with no way out gets the area's size)."""
    ids, index = plant.ids, plant.index
    inside: dict[str, list[int]] = {}
    for node, name in areas.items():
        inside.setdefault(name, []).append(node)
    out: dict[int, int] = {}
    for name, nodes in inside.items():
        frontier = [
            n
            for n in nodes
            if any(areas.get(int(ids[v])) != name for v, _, _ in plant.neighbors[index[n]])
        ]
        hops = dict.fromkeys(frontier, 1)
        while frontier:
            nxt = []
            for n in frontier:
                for m in nodes:
                    if m not in hops and any(
                        int(ids[v]) == n for v, _, _ in plant.neighbors[index[m]]
                    ):
                        hops[m] = hops[n] + 1
                        nxt.append(m)
            frontier = nxt
        out.update({n: hops.get(n, len(nodes)) for n in nodes})
    return out


def _segment_lengths(plant: Plant) -> dict[tuple[int, int], float]:
    """Length of every segment by its end ids, both directions where it is driven both
    ways, return lanes included (they are timed, not searched)."""
    out: dict[tuple[int, int], float] = {}
    for e in plant.edges:
        out[(e.source, e.target)] = float(e.length)
        if e.bidirectional:
            out[(e.target, e.source)] = float(e.length)
    return out
