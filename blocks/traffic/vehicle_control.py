"""VehicleControl: the per-vehicle control layer of the thesis (sections 5.3.1 and 5.3.2).

One instance per vehicle, like the thesis' one PLC per vehicle. Every scan it reads the
vehicle's record (reported current and next node), passes the nodes the vehicle has
reached, and extends the released route node by node, up to ``lookahead`` nodes ahead of
the vehicle, each only after the ReservationMatrix granted it: the staged communication of
5.3.2, so a vehicle without a verified next node creeps to the crossing and stops there.
A vehicle standing at a node does not start by itself: it posts its next node
(``request``) and the DeadlockResolver grants the starts of all standing vehicles in
priority order (``grant``), pushing standing vehicles out of the way where needed; a
moving vehicle never extends into a node a standing vehicle was told to wait for.
A node is released only when the ReservationMatrix says it may be entered: nobody else
holds it, and nobody else occupies its single-vehicle area (if it has one). So a vehicle
bound for a station whose area another vehicle is in stops at the last node before the
area, and waits for that vehicle, whatever sent it there (a recipe, an order, a push).

Verification at every node (5.3.1): when the next node is held by a vehicle coming the
other way, the less urgent of the two replans with that segment carrying a very high extra
weight, so any detour wins (if both turned away, as in the thesis, they could meet again on
the other side, for ever); when the wait drags on (a queue, a vehicle processing), it
replans the same way once. Routes come from an IncrementalAStar instance with a bounded number of
expansions per cycle, planned from the last released node while the vehicle drives, and
replanned whenever a permanent blockade is set or cleared. Released nodes are never taken
back: the vehicle may already be past the point where it could obey.

Planned in time (``traffic``, the time-window mode): routes then come from the
TimeWindowTraffic block's planning rounds instead of this block's A*, and every node
is released only when its ``gate`` allows (the next step of the plan, in the order the plans
fixed); the vehicle neither replans by itself nor is pushed. The ReservationMatrix checks
every release as in the reactive mode.

Plausibility: a report may only move the vehicle along what it was released (the
ReservationMatrix decides). A report that claims anything else (another node, or none of
the plant), or a vehicle link that saw the vehicle's message counter jump, makes the
vehicle **suspect**: it gets a stop command, its holds stay as they are (the others wait
or route around it, as for a stale vehicle), and nothing of what it reports is applied
except moves along its holds. It returns to service by itself after reporting a node it
holds for ``recover_s`` without a break, or when an operator acknowledges it
(:meth:`acknowledge`): after looking, the operator confirms where it really is, and its
holds move there if that node is free.
"""

from __future__ import annotations

from collections.abc import Callable

from blocks.routing.astar import IncrementalAStar
from blocks.routing.constraints import RoutingConstraints
from blocks.routing.heuristic import HeuristicTable
from plc_runtime import CycleContext, FunctionBlock, Input, Output, Static
from topology import Plant

from .records import (
    CLEAR,
    FAULT,
    LINK_JUMP_SHIFT,
    LINK_JUMPS,
    NO_NODE,
    ONLINE,
    STALE,
    VehicleRecordsView,
)
from .reservation import OUT_OF_SERVICE, ReservationMatrix

RESEND_AFTER_NS = 300_000_000  # a command the vehicle shows no sign of: send it again
NO_ROUTE_RETRY_NS = 1_000_000_000
YIELD_NS = 20_000_000_000  # giving way after a back-off ends after this at the latest
RECOVER_S = 2.0  # a suspect vehicle reporting a node it holds this long returns to service


class VehicleControl(FunctionBlock):
    target = Input(None, doc="goal node id (from the sequencer); None: no goal")
    fixed_route = Input(None, doc="a static route of node ids to drive instead (return lane)")
    hold = Input(False, doc="plan, but release nothing (processing at a station)")
    budget = Input(4, doc="A* expansions per cycle")

    state = Output(
        "offline",
        doc="offline|idle|planning|driving|waiting|arrived|no_route|stale|fault|suspect",
    )
    suspect = Output(False, doc="a report was implausible: stopped, holds kept, see reason")
    suspect_reason = Output("", doc="why the vehicle is suspect (empty when it is not)")
    suspect_events = Output(0, doc="times the vehicle became suspect")
    current = Output(None, doc="the node the vehicle last reported")
    arrived = Output(False, doc="standing at its target with nothing left to drive")
    waiting_for = Output(None, doc="the vehicle holding the node this one waits for")
    wait_since_ns = Output(0)
    replans = Output(0, doc="routes recomputed because the next segment was taken")
    waits = Output(0, doc="times the vehicle had to stop for a node held by another")
    no_routes = Output(0)
    plans = Output(0)
    planned = Output((), doc="released and planned nodes ahead, for drawing")

    released = Static([])  # node ids released and not yet reached, in driving order
    route = Static([])  # planned node ids after the last released one
    goal = Static(None)  # the goal the route leads to
    sequence = Static(0)
    sent_ns = Static(0)
    planning = Static(False)
    adopted_fixed = Static(None)
    plan_goal = Static(None)
    blockade_epoch = Static(0)
    retry_ns = Static(0)
    wait_node = Static(None)
    # the vehicle last waited for at wait_node: kept while the vehicle waits for a planning
    # round instead (time-window traffic), so that the planner's wait thresholds count on
    wait_blocker = Static(None)
    wait_replanned = Static(False)
    consistent_since_ns = Static(None)  # suspect: reporting a held node since then
    link_jumps = Static(0)  # the link's count of this vehicle's counter jumps, last seen
    reported = Static(None)  # the last reported node, plausible or not (None: not in the plant)
    # stopped because it reports a next node it was not released (see _keep_to_released)
    foreign_route = Output(False, doc="stopped: it reports a next node it was not released")
    foreign_since_ns = Static(0)  # since when (a spoofed status lasts one status period)

    def __init__(
        self,
        vehicle: int,
        plant: Plant,
        table: HeuristicTable,
        reservation: ReservationMatrix,
        records: VehicleRecordsView,
        blockades: RoutingConstraints,
        lookahead: int = 2,
        wait_replan_s: float = 5.0,
        priority: Callable[[int], tuple] | None = None,
        recover_s: float = RECOVER_S,
        traffic=None,
    ) -> None:
        super().__init__()
        if not 1 <= lookahead <= 3:
            raise ValueError(f"lookahead must be 1..3 nodes, got {lookahead}")
        self.vehicle = vehicle
        self.plant = plant
        self.reservation = reservation
        self.records = records
        self.blockades = blockades
        self.lookahead = lookahead
        self.wait_replan_ns = round(wait_replan_s * 1e9)
        self.recover_ns = round(recover_s * 1e9)
        # smaller is more urgent; of two vehicles facing each other only the less urgent one
        # detours, so they cannot both turn away and meet again on the other side for ever
        self.priority = priority or (lambda v: (0, v))
        # own penalties (the occupancy seen from this vehicle), shared blockades
        self.constraints = RoutingConstraints(plant)
        self.constraints.blocked = blockades.blocked
        self.astar = IncrementalAStar(plant, table, constraints=self.constraints)
        self.index = plant.index
        # the plant builds it on first use: here, not in the scan that first asks (some
        # 50 ms on a plant of 8000 nodes)
        self.arc_index = plant.arc_index
        self.yield_node: int | None = None
        self._planned_from: int | None = None
        self.yield_while: Callable[[], int | None] | None = None
        self.yield_until_ns = 0
        # the time-window planner (None: reactive, routes from this block's own A*)
        self.traffic = traffic

    # ----- the scan ------------------------------------------------------------------------
    def cycle(self, ctx: CycleContext) -> None:
        self._scan(ctx)
        if self.state in OUT_OF_SERVICE:
            self.reservation.out_of_service.add(self.vehicle)
        else:
            self.reservation.out_of_service.discard(self.vehicle)

    def _scan(self, ctx: CycleContext) -> None:
        # the record's fields as Python ints in one call (a numpy field read each costs more)
        current, reported_next, _state, _battery, _speed, flags = self.records.inputs(
            self.vehicle
        ).item()
        if not flags & ONLINE and (not flags & STALE or self.current is None):
            self.state = "offline"  # never heard of: its record holds no position
            return
        if current == NO_NODE or current not in self.index:
            self._nowhere(ctx, current)
            return
        self.reported = current
        clear = bool(flags & CLEAR)
        jumps = (flags & LINK_JUMPS) >> LINK_JUMP_SHIFT
        if jumps != self.link_jumps:
            # a new jump (a change of the count: none can hide behind one not yet seen)
            self.link_jumps = jumps
            if self.suspect:
                self.consistent_since_ns = None  # the recovery starts again
            else:
                self._become_suspect(
                    ctx, "link: message counter jumped (restart, or a second sender)"
                )
        why = self.reservation.plausible(self.vehicle, self.index[current], clear)
        if why is not None:
            self.reservation.refuse()
            if not self.suspect:
                self._become_suspect(ctx, why)
        if self.suspect:
            fresh = not flags & (STALE | FAULT)
            self._while_suspect(ctx, current, clear, why is None and fresh)
            return
        self._passed(current, clear)
        if flags & STALE or flags & FAULT:
            # an obstacle where it was last seen: its holds stay, nothing more is released
            self.state = "stale" if flags & STALE else "fault"
            return
        self._follow_inputs()
        if self.planning:
            self._plan_step(ctx)
        elif self._needs_plan(ctx):
            self._start_plan(ctx)
        if self.released and not self.planning and not self.hold:
            self._release(ctx)  # driving: extend; standing: the resolver grants the start
        elif not self.released and not self.route and not self.planning:
            self._not_waiting()
        self._resend_if_lost(ctx, reported_next)
        self._keep_to_released(ctx, reported_next)
        self._publish_state()

    def _keep_to_released(self, ctx: CycleContext, reported_next: int) -> None:
        """A vehicle carries the route of the last command it got, and the released nodes
        are that route as it is passed, so the next node it reports is one of them or none.
        Any other is a route it was not released: the old route of a vehicle pushed by hand
        whose cancel was lost, one a controller gave before a restart. Its holds do not
        cover that node. It is stopped (the go bit off, whatever else this scan commanded)
        and its command repeated until it reports no other; then it may go. With nothing
        released (the cases above), no hold, and the node next to it free, the node is
        claimed for it once the report has lasted a resend interval, as a grant does, and
        the vehicle is sent there: what it may do is then covered, and a vehicle braked on
        its way there finishes the segment instead of standing on it for ever. (The wait:
        a spoofed status frame lasts until the vehicle's next, and must not move it.)"""
        if reported_next == NO_NODE or reported_next in self.released:
            if self.foreign_route:
                self.foreign_route = False
                self._command(go=True)
            return
        if not self.foreign_route:
            self.foreign_route, self.foreign_since_ns = True, ctx.time_ns
        if (
            not self.released
            and not self.hold
            and (self.current, reported_next) in self.arc_index
            and ctx.time_ns - self.foreign_since_ns >= RESEND_AFTER_NS
            and self.reservation.may_enter(self.vehicle, self.index[reported_next])[0]
        ):
            self._forget_route(ctx)  # planned again from there
            self._claim(reported_next)
            self._not_waiting()
            self.foreign_route = False
            self._send(ctx)
            return
        if ctx.time_ns - self.sent_ns >= RESEND_AFTER_NS:
            self.sequence = self.sequence % 255 + 1
            self.sent_ns = ctx.time_ns
        self._command(go=False)

    def _passed(self, current: int, clear: bool) -> None:
        """A plausible report: the nodes up to ``current`` are passed."""
        if current in self.released:
            del self.released[: self.released.index(current) + 1]
        self.current = current
        self.reservation.report(self.vehicle, self.index[current], clear)
        if self.traffic is not None:
            self.traffic.reached(self.vehicle, current, clear)

    # ----- suspect vehicles ----------------------------------------------------------------
    def _nowhere(self, ctx: CycleContext, current: int) -> None:
        """A report naming no node of the plant passed the link's checks (a forged frame, or
        a vehicle configured for another plant): nothing in it can be checked or applied, so
        the vehicle is suspect like one reporting a node it was never given."""
        self.reservation.refuse()
        self.reported = None  # an operator cannot confirm it stands where it reports
        if not self.suspect:
            where = "no node" if current == NO_NODE else f"node {current}, not in the plant"
            self._become_suspect(ctx, f"reports {where}")
        self._while_suspect(ctx, current, clear=False, plausible=False)

    def _become_suspect(self, ctx: CycleContext, why: str) -> None:
        self.suspect, self.suspect_reason = True, why
        self.suspect_events += 1
        self.consistent_since_ns = None
        self.state = "suspect"
        self._stop(ctx)

    def _while_suspect(self, ctx: CycleContext, current: int, clear: bool, plausible: bool) -> None:
        """Stopped, holds kept: only moves along its holds are applied (it may still roll to
        the next released node). Fresh reports of a held node for ``recover_ns`` end it."""
        self.state = "suspect"
        self._not_waiting()
        self.reservation.intent[self.vehicle] = None
        if not plausible:
            self.consistent_since_ns = None
            return
        self._passed(current, clear)
        if self.consistent_since_ns is None:
            self.consistent_since_ns = ctx.time_ns
        elif ctx.time_ns - self.consistent_since_ns >= self.recover_ns:
            self._return_to_service(ctx)

    def _return_to_service(self, ctx: CycleContext) -> None:
        self.suspect, self.suspect_reason = False, ""
        self.consistent_since_ns = None
        # what it was released may be gone or behind it: plan again from where it is
        self.released = [
            n for n in self.released if self.index[n] in self.reservation.holds[self.vehicle]
        ]
        self._forget_route(ctx)
        if self.released:
            self._send(ctx)  # go again, with what it still holds ahead
        else:
            self._command(go=True)  # go again; its next route comes as a new command
        self._publish_state()

    def acknowledge(self, ctx: CycleContext) -> str | None:
        """An operator has checked the vehicle: it is where it reports. A report its holds
        already cover (a vehicle made suspect by its link, not by where it is) changes
        none of them. Otherwise its holds move there, if that place is free, and it returns
        to service. "Where it reports" is the node, or, once the vehicle is clear of that
        node, the segment to the next node it reports: it is then held for that next node,
        as a vehicle driving there is, and sent on to it; holding the node behind it would
        free the one it stands in front of for another vehicle. Returns why not, or None."""
        if not self.suspect:
            return "not suspect"
        if self.reported is None:
            return "no position reported"
        _current, reported_next, _state, _battery, _speed, flags = self.records.inputs(
            self.vehicle
        ).item()
        clear = bool(flags & CLEAR)
        node = self.index[self.reported]
        if self.reservation.plausible(self.vehicle, node, clear) is None:
            self._passed(self.reported, clear)
        else:
            where = self.reported
            if clear:
                if (self.reported, reported_next) not in self.arc_index:
                    return f"clear of node {self.reported}, but on the way to no node next to it"
                where = reported_next
            why = self.reservation.relocate(
                self.vehicle, self.index[where], cleared=node if clear else None
            )
            if why is not None:
                return why
            # the route it still carries leads from where it was: replace it (by the node
            # it is on the way to, or an empty route) before it may go again
            self.released = [where] if clear else []
            self.sequence = self.sequence % 255 + 1
            self.sent_ns = ctx.time_ns
            self._command(go=False)
        self.current = self.reported
        self._return_to_service(ctx)
        return None

    def _stop(self, ctx: CycleContext) -> None:
        """The go bit off (a stop command); the route command itself stays as it was."""
        self._command(go=False)

    def _command(self, go: bool) -> None:
        """Write the command record: the released nodes, the go bit, the acknowledge bit."""
        self.records.write_command(self.vehicle, tuple(self.released[:3]), go, self.sequence)

    @property
    def frontier(self) -> int:
        return self.released[-1] if self.released else self.current

    def _follow_inputs(self) -> None:
        if self.fixed_route is not None:
            if self.fixed_route != self.adopted_fixed:
                self.adopted_fixed = self.fixed_route
                fixed = list(self.fixed_route)
                if self.frontier in fixed:
                    # adopted again part way along (after a suspicion): only what is ahead
                    fixed = fixed[fixed.index(self.frontier) + 1 :]
                self.route, self.goal, self.planning = fixed, self.fixed_route[-1], False
            return
        self.adopted_fixed = None
        if self.target != self.goal:
            self.goal, self.route = self.target, []
            self.planning = False

    def _forget_route(self, ctx: CycleContext) -> None:
        """Drop the planned route: it is planned again from the frontier, or, on a fixed
        route, the rest of the fixed route is adopted again."""
        self.route, self.planning = [], False
        self.retry_ns = ctx.time_ns
        self.adopted_fixed = None

    def _needs_plan(self, ctx: CycleContext) -> bool:
        if self.goal is None or self.fixed_route is not None or self.traffic is not None:
            return False
        if self.blockades_changed():
            return True
        if self.route or self.frontier == self.goal:
            return False
        return ctx.time_ns >= self.retry_ns

    def blockades_changed(self) -> bool:
        if self.blockade_epoch != self.blockades.epoch:
            self.blockade_epoch = self.blockades.epoch
            return self.goal is not None and self.frontier != self.goal
        return False

    # ----- planning ------------------------------------------------------------------------
    def follow_plan(self, frontier: int, route: list[int]) -> None:
        """The time-window planner's route from ``frontier`` (node ids after it; empty: it
        is at its goal). Ignored if the vehicle's frontier has moved since the plan was made
        (it is planned again), or if the route does not end at its goal."""
        if frontier != self.frontier or self.goal is None:
            return
        if (route[-1] if route else frontier) != self.goal:
            return
        self.route, self.planning = list(route), False

    def _start_plan(self, ctx: CycleContext, oncoming: tuple[int, int] | None = None) -> None:
        self.reservation.penalties_for(
            self.vehicle,
            self.constraints.penalty,
            None if oncoming is None else (self.index[oncoming[0]], self.index[oncoming[1]]),
        )
        self.planning, self.plan_goal, self.route = True, self.goal, []
        self.plans += 1
        self.astar(ctx, request=False)
        self.astar(ctx, request=True, start=self.frontier, goal=self.goal, budget=self.budget)
        self._take_result(ctx)

    def _plan_step(self, ctx: CycleContext) -> None:
        self.astar(ctx, request=True, budget=self.budget)
        self._take_result(ctx)

    def _take_result(self, ctx: CycleContext) -> None:
        a = self.astar
        if a.busy:
            return
        self.planning = False
        if a.no_route:
            self.no_routes += 1
            self.retry_ns = ctx.time_ns + NO_ROUTE_RETRY_NS
            self.route = []
            return
        route = list(a.route)
        self.route = route[1:] if route and route[0] == self.frontier else []

    # ----- releasing ---------------------------------------------------------------------------
    def _release(self, ctx: CycleContext) -> None:
        """Driving: extend the released route up to ``lookahead`` nodes, each only if free."""
        changed = False
        while len(self.released) < self.lookahead and self.route:
            here, there = self.frontier, self.route[0]
            if self._step_withheld(ctx, here, there)[0]:
                break  # it stops at the frontier and asks again from there
            res, idx = self.reservation, self.index[there]
            if (
                not res.may_enter(self.vehicle, idx)[0]
                or res.awaited_by(self.vehicle, idx) is not None
            ):
                # held, its area occupied, or a standing vehicle was told to wait for it (or
                # for its area): stop at the frontier
                break
            self._claim(self.route.pop(0))
            changed = True
        if changed:
            self._send(ctx)

    def _blocked(self, ctx: CycleContext, blocker: int | None, here: int, there: int) -> None:
        """Standing at ``here``, its start to ``there`` was not granted: it waits."""
        res = self.reservation
        res.wants[self.vehicle] = self.index[there]
        if self.wait_node != there or self.waiting_for != blocker:
            if self.wait_node != there:
                self.waits += 1
                self.wait_since_ns = ctx.time_ns
                self.wait_replanned = False
            self.wait_node, self.waiting_for = there, blocker
        self.wait_blocker = blocker
        if self.traffic is not None:
            return  # the plans' order decides, and the planner replans
        oncoming = (
            blocker is not None
            and self.index[here] in (res.intent.get(blocker), res.wants.get(blocker))
            and self.priority(self.vehicle) > self.priority(blocker)
        )
        if blocker is not None and res.making_way(blocker):
            self.wait_since_ns = ctx.time_ns  # it is on its way: the wait is not overdue
        overdue = ctx.time_ns - self.wait_since_ns >= self.wait_replan_ns
        if (oncoming or overdue) and not self.wait_replanned and self.fixed_route is None:
            self.wait_replanned = True
            self.replans += 1
            self._start_plan(ctx, oncoming=(here, there))

    def _not_waiting(self) -> None:
        self.reservation.wants[self.vehicle] = None
        self.wait_node = self.waiting_for = self.wait_blocker = None

    # ----- starts, granted by the resolver -----------------------------------------------------
    def request(self, ctx: CycleContext) -> int | None:
        """The node (id) a vehicle standing at a node wants to start to, or None: nothing to
        drive, planning, on hold, giving way, or the next segment closed (it replans)."""
        if (
            self.released
            or self.planning
            or self.hold
            or self.suspect
            or self.foreign_route  # (stopped until it carries only what it was released)
            or not self.route
        ):
            return None
        here, there = self.current, self.route[0]
        withheld, giving_way_to = self._step_withheld(ctx, here, there)
        if giving_way_to is not None:
            # for deadlock detection, giving way is waiting for the vehicle it gave way to
            self._blocked(ctx, giving_way_to, here, there)
            self._publish_state()
        elif withheld and self.traffic is not None:
            # waiting for a plan, not for a vehicle (a vehicle named here would make a
            # waits-for circle the resolver reports, where none is). While a round is being
            # planned a vehicle that waited for one goes on waiting at that node (the round
            # withholds every step past its commitments): clearing the wait would restart
            # its clock every round, and the planner's wait thresholds could never be reached
            if self.traffic.planning:
                if self.waiting_for is not None:
                    self.waiting_for = None
                    self._publish_state()
            else:
                self._not_waiting()
        return None if withheld else there

    def _step_withheld(self, ctx: CycleContext, here: int, there: int) -> tuple[bool, int | None]:
        """Must the route step ``here`` -> ``there`` wait, whoever holds ``there``? Also the
        vehicle it gives way to, if that is the reason. A closed segment starts a replan."""
        arcs = self.arc_index.get((here, there))
        blocked = self.blockades.blocked
        if arcs is not None and all(blocked[arc] for arc in arcs):
            if self.traffic is None:
                self._start_plan(ctx)  # the next segment was closed: plan around it
            return True, None
        if (
            there == self.current
            or there in self.released
            or self.index[there] in self.reservation.holds[self.vehicle]
        ):
            # the route comes back to a node it is at, holds or will pass: reports name
            # nodes, so it must reach the next node first, or a report of this node would
            # be ambiguous (the visit before or the one after?)
            return True, None
        if self.traffic is not None:
            ok, blocker = self.traffic.gate(self.vehicle, there)
            if not ok:
                return True, blocker  # not its turn there yet (or no plan up to there)
        if there == self.yield_node:
            needing = self._giving_way(ctx)
            if needing is not None:
                return True, needing  # the vehicle it backed off for still needs this node
            self.yield_node, self.yield_while = None, None
        return False, None

    def grant(self, ctx: CycleContext, node: int) -> None:
        """Start to the free node ``node`` (an id): the next node of its route, or a node it
        was pushed to (it then replans from there)."""
        if self.route and self.route[0] == node:
            self.route.pop(0)
        else:
            self._forget_route(ctx)
        self._claim(node)
        self._not_waiting()
        self._send(ctx)
        self._publish_state()

    def _claim(self, node: int) -> None:
        """Release ``node`` (an id) to the vehicle: it holds it from now on."""
        self.reservation.claim(self.vehicle, self.index[node])
        self.released.append(node)
        if self.traffic is not None:
            self.traffic.released(self.vehicle, node)

    def wait_for(self, ctx: CycleContext, blocker: int | None, node: int) -> None:
        """Its start to ``node`` (an id) was not granted this scan: it waits for ``blocker``."""
        self._blocked(ctx, blocker, self.current, node)
        self._publish_state()

    def back_off(
        self, ctx: CycleContext, node: int, needed: Callable[[], int | None] | None = None
    ) -> None:
        """Deadlock resolution: give way by driving to the free neighbour ``node`` first,
        and do not take the node it leaves again while ``needed()`` names a vehicle it gave
        way to that still plans to pass there."""
        self.planning = False
        self.route = [node]
        self._not_waiting()
        self.retry_ns = ctx.time_ns
        if needed is not None:
            self.yield_node, self.yield_while = self.current, needed
            self.yield_until_ns = ctx.time_ns + YIELD_NS

    def _giving_way(self, ctx: CycleContext) -> int | None:
        """The vehicle it still gives way to, or None. Bounded in time: a vehicle that only
        gives way never becomes urgent enough to be started, so it would wait for ever if
        the one it backed off for got stuck elsewhere."""
        if ctx.time_ns >= self.yield_until_ns:
            return None
        return self.yield_while()

    # ----- the command -----------------------------------------------------------------------
    def _send(self, ctx: CycleContext) -> None:
        self.sequence = self.sequence % 255 + 1  # 0 means "no command yet"
        self.sent_ns = ctx.time_ns
        self._command(go=True)

    def _resend_if_lost(self, ctx: CycleContext, reported_next: int) -> None:
        """A vehicle standing still with released nodes has not got the command (a lost
        frame, or it passed a node before the command arrived and refused it): repeat it."""
        if (
            self.released
            and not self.suspect
            and reported_next == NO_NODE
            and ctx.time_ns - self.sent_ns >= RESEND_AFTER_NS
        ):
            self._send(ctx)

    def _publish_state(self) -> None:
        res = self.reservation
        res.intent[self.vehicle] = (
            self.index[self.route[0]] if self.route and not self.released else None
        )
        self.arrived = (
            self.goal is not None
            and self.current == self.goal
            and not self.released
            and not self.route
            and not self.planning
        )
        planned = tuple(self.released + self.route)
        if planned != self.planned or (planned and self.current != self._planned_from):
            self.planned, self._planned_from = planned, self.current
            index = self.index
            res.plan(self.vehicle, [index[n] for n in (self.current, *planned)])
        if self.arrived:
            self.state = "arrived"
        elif self.planning:
            self.state = "planning"
        elif self.waiting_for is not None:
            self.state = "waiting"
        elif self.released:
            self.state = "driving"
        elif self.goal is None:
            self.state = "idle"
        elif self.no_routes and not self.route and self.current != self.goal:
            self.state = "no_route"
        else:
            self.state = "idle" if self.hold else "planning"
