"""Dispatcher: gives transport orders to vehicles, with bounded work per scan.

The dispatcher decides *what* a vehicle does; routing and traffic decide *how* it drives
(openTCS's split of dispatcher, router and scheduler). Every scan it

1. checks new orders, and all waiting orders again when the blockades changed (at most
   ``ROUTE_BUDGET`` a scan): an order whose Put station cannot be reached from its Get
   station on the plant, or whose Get station no vehicle could reach, is UNROUTABLE; one
   that only closed segments keep from its stations waits, counted in ``cut_off``, and
   no round gives it out until they reopen (a blockade is temporary: closing a segment
   for a moment must not end a backlog of orders for good); an order whose vehicle can
   no longer reach its next station goes back to the pool (before the pickup) or FAILS
   (the load is on board);
2. with ``two_stage``, notices a running section that took more than ``1 + deviation``
   times its estimate, and then takes every vehicle's next order back for a new round;
3. starts an allocation round when a vehicle could take an order and orders wait (not more
   often than every ``interval_s``) over the ``pool_limit`` most urgent waiting orders
   (from an index, :class:`UrgentOrders`, not a sort of them all), and advances the
   running round by at most ``budget`` (vehicle, order) evaluations; a complete round is
   applied at once, after checking each assignment still holds (the order still waits,
   the vehicle is still free). A two_stage round starts from the station reservation
   lists as the vehicles stand (:func:`live_schedule`), so a late vehicle or a queue in
   front of a station is priced in. With ``next_order`` (the seed's rule) a two_stage
   vehicle is given its next order once it is in its active order's Get zone; without,
   only once it is free, when where it stands and what the others took are known, not
   estimated. ``bottleneck_s`` is two_stage's weight for the pool's busiest stations
   (:func:`two_stage`).

Vehicles that are offline, stale, faulty or suspect take nothing (``available``), nor does
one with a load left on board by an order that ended without its Put; a vehicle
whose battery would end an order below the ChargePolicy's ``good`` level takes nothing
either, and a charging one only once its charge is sufficient.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from numbers import Integral

import numpy as np

from plc_runtime import CycleContext, FunctionBlock, Output
from topology import Plant

from .charging import ChargePolicy
from .estimates import SectionEstimates
from .executor import Claims, OrderRunner
from .orders import OrderBook, OrderState, TransportOrder
from .reachability import Reachability
from .station_schedule import StationSchedule, live_schedule
from .strategies import (
    Assignment,
    Candidate,
    StationStats,
    dhht,
    nearest_idle,
    plugged_strategy,
    strategy_names,
    two_stage,
)
from .urgent_orders import UrgentOrders

# route checks of waiting orders per scan after the blockades changed (each a few lookups)
ROUTE_BUDGET = 1000
# seconds between two checks of the orders cut off, when no segment closed or reopened
ASIDE_RECHECK_S = 5.0
# orders whose start time came made startable per scan (dhht, nearest_idle): each costs two
# heap operations, so 1000 stay within a few milliseconds even on a pool of 100,000
STARTABLE_BUDGET = 1000


# a plugged strategy's round is given up after this many evaluations per (vehicle, order)
# pair, or this many in all if more: one that never ends must not keep the orders waiting
PLUGGED_ROUND_PAIRS = 100
PLUGGED_ROUND_MIN = 100_000

# orders a round's pool passes over (they cannot be given out now) before it stops looking:
# a bound on a scan's work however many orders wait at a station out of service
PASSED_LIMIT = 1000


class Dispatcher(FunctionBlock):
    rounds = Output(0, doc="allocation rounds completed")
    evaluations = Output(0, doc="(vehicle, order) pairs evaluated")
    assignments = Output(0, doc="orders given to a vehicle")
    reassigned = Output(0, doc="orders taken back from a vehicle and given again")
    deviations = Output(0, doc="sections that ran over their estimate (two_stage recomputes)")
    waiting = Output(0, doc="orders waiting for a vehicle")
    cut_off = Output(0, doc="waiting orders that closed segments keep from their stations")
    refused = Output(0, doc="malformed assignments and rounds of a plugged strategy, not applied")

    def __init__(
        self,
        book: OrderBook,
        runners: Mapping[int, OrderRunner],
        strategy: str,
        distance: Callable[[int, int], float],
        reach: Reachability,
        schedule: StationSchedule,
        estimates: SectionEstimates,
        charging: ChargePolicy,
        available: Callable[[int], bool],
        claims: Claims | None = None,
        budget: int = 500,
        interval_s: float = 1.0,
        deviation: float = 0.3,
        capacity_per_h: float = 60.0,
        pool_limit: int = 100,
        next_order: bool = True,
        bottleneck_s: float = 0.0,
    ) -> None:
        super().__init__()
        if strategy not in strategy_names():
            raise ValueError(
                f"dispatch strategy must be one of {', '.join(strategy_names())}, got {strategy!r}"
            )
        if budget < 1:
            raise ValueError(f"dispatch budget must be >= 1 evaluation per scan, got {budget}")
        self.book = book
        self.runners = runners
        self.strategy = strategy
        self.distance = distance
        self.reach = reach
        self.schedule = schedule
        self.estimates = estimates
        self.charging = charging
        self.available = available
        # the places vehicles hold: an order at a station a vehicle out of service holds
        # waits (none given: no such vehicles)
        self.claims = claims if claims is not None else Claims()
        self.budget = budget
        self.interval_ns = round(interval_s * 1e9)
        self.deviation = deviation
        self.capacity_per_h = capacity_per_h
        self.pool_limit = pool_limit
        self.next_order = next_order
        self.bottleneck_s = bottleneck_s
        self.stats: dict[int, StationStats] = {}
        self._supply: Counter[int] = Counter()  # dhht: orders per Get station so far
        self._supply_counted = 0  # of the book's orders, in the order added
        self._round = None
        # the running round's pool (id -> order): an order of it that has ended and left the
        # book since, or whose id a new order has taken, is passed over when it is applied
        self._pooled: dict[str, TransportOrder] = {}
        self._working: StationSchedule | None = None
        self.refused_reason: str | None = None  # why the first refused assignment was refused
        self._round_limit = PLUGGED_ROUND_MIN  # a plugged strategy's evaluations in a round
        self._round_evaluations = 0
        self._last_round_ns: int | None = None
        # orders whose routes were checked since the blockades changed, and the waiting
        # orders still to check again after a change
        self._checked: set[str] = set()
        self._recheck: deque[str] = deque()  # ids
        # waiting orders closed segments keep from a station (ids, in the order found)
        self._cut_off: dict[str, None] = {}
        self._aside_recheck_ns = 0  # when those are next checked again, segments unchanged
        self._revision = 0  # the book's revision when the routes were last checked
        # the waiting orders by urgency (two_stage also plans orders whose start is to come)
        self._urgent = UrgentOrders(startable_only=strategy != "two_stage")
        self._urgent_revision = 0  # the book's revision the index has seen
        self._epoch: int | None = None
        self._deviated: set[tuple[str, str]] = set()
        self._origin: dict[str, int] = {}  # order id -> the node its vehicle took it at

    # ----- the scan --------------------------------------------------------------------------
    def cycle(self, ctx: CycleContext) -> None:
        # an order withdrawn (or failed) since the last scan is still a runner's active or
        # next order until the runner's own scan, after this one: dropped now, or a check
        # below would hand it back to the pool from its final state
        for runner in self.runners.values():
            runner.withdrawn(ctx)
        if self.strategy == "dhht":
            self._count_supply()
        self._check_routes(ctx)
        self._index_changes(ctx)
        self._urgent.advance(ctx.time, STARTABLE_BUDGET)
        if self.strategy == "two_stage":
            self._check_deviations(ctx)
        if self._round is None and self._due(ctx):
            self._start_round(ctx)
        if self._round is not None:
            self._advance(ctx)
        self.waiting = self._open()

    def _open(self) -> int:
        """DISPATCHABLE orders, from the book's counts: the scan must not walk every open
        order (a released order file may hold 100,000)."""
        return self.book.counts()[OrderState.DISPATCHABLE.value]

    def _due(self, ctx: CycleContext) -> bool:
        if self._last_round_ns is not None and ctx.time_ns - self._last_round_ns < self.interval_ns:
            return False
        return self._open() > 0 and bool(self._candidates(ctx, {}))

    # ----- routes ------------------------------------------------------------------------------
    def _check_routes(self, ctx: CycleContext) -> None:
        blockades_changed = self._epoch != self.reach.blockades.epoch
        self._epoch = self.reach.blockades.epoch
        if blockades_changed:
            # every waiting order again, ROUTE_BUDGET a scan (a backlog may hold 100,000);
            # meanwhile a round checks its own pool (_start_round)
            self._checked.clear()
            self._recheck = deque(o.id for o in self.book.dispatchable())
        # the orders that changed state since the last check can be new to it (a few per
        # scan); if the book's journal overran, every waiting order again
        changed = self.book.changed_since(self._revision)
        if changed is None:
            self._checked.clear()
            self._cut_off.clear()  # (and the index's orders set aside, rebuilt whole)
            self._urgent.rebuild(self.book.dispatchable(), ctx.time)
            self._urgent_revision = self.book.revision
            self._recheck = deque(o.id for o in self.book.dispatchable())
            changed = []
        fresh = [o for o in changed if o.state is OrderState.DISPATCHABLE and o.assigned is None]
        for order in changed:  # taken, withdrawn, given back: checked again if it waits
            self._cut_off.pop(order.id, None)
            self._checked.discard(order.id)
        if self._cut_off and not self._recheck and ctx.time_ns >= self._aside_recheck_ns:
            # vehicles move, come online, go out of service: an order no vehicle could
            # reach a while ago may be reachable now with no segment reopened
            self._aside_recheck_ns = ctx.time_ns + round(ASIDE_RECHECK_S * 1e9)
            self._recheck.extend(self._cut_off)
        for _ in range(min(ROUTE_BUDGET, len(self._recheck))):
            order_id = self._recheck.popleft()
            self._checked.discard(order_id)
            if order_id in self.book:  # else it ended and has left the book since
                fresh.append(self.book.get(order_id))
        positions: _Positions | None = None  # the vehicles' nodes, read once a scan
        for order in fresh:
            if order.id in self._checked or order.state is not OrderState.DISPATCHABLE:
                continue
            self._checked.add(order.id)
            positions = positions or _Positions.of(self.runners, self.reach.plant)
            why = self._unroutable(order, positions)
            if why is not None:
                self._cut_off.pop(order.id, None)
                self.book.transition(order, OrderState.UNROUTABLE, ctx.time, why)
            elif not self._routable_now(order, positions):
                self._cut_off[order.id] = None
                self._urgent.set_aside(order)  # no round looks at it until it is driveable
            else:  # (back in the pool if it was set aside, however it came here)
                self._cut_off.pop(order.id, None)
                self._urgent.restore(order, ctx.time)
        self.cut_off = len(self._cut_off)
        self._revision = self.book.revision
        if not blockades_changed:
            return
        for runner in self.runners.values():
            self._check_active(ctx, runner)
            self._check_next(ctx, runner)

    def _check_active(self, ctx: CycleContext, runner: OrderRunner) -> None:
        """After a blockade: an active order the vehicle can no longer drive to its end
        fails (its load on board: from the start of the Get dwell) or goes back to the pool
        (not picked up yet: it could not be delivered from the Get station either). Reached
        from where it will stand: the nodes released to it are driven whatever closes (a
        vehicle on the closed segment itself drives on to its end)."""
        order = runner.active
        if order is not None and runner.current is not None:
            loaded, here, reaches = runner.load == order.id, _standing(runner), self.reach.reaches
            if loaded:
                drivable = reaches(here, order.put)
            else:
                drivable = reaches(here, order.get) and reaches(order.get, order.put)
            if drivable:
                return
            if loaded:
                self.book.transition(
                    order,
                    OrderState.FAILED,
                    ctx.time,
                    f"Put station {order.put} cut off by a blockade",
                )
                runner.withdrawn(ctx)
            else:
                runner.frozen = False  # not picked up yet: another vehicle may still get there
                self._give_back(ctx, runner)

    def _check_next(self, ctx: CycleContext, runner: OrderRunner) -> None:
        """After a blockade: a next order the vehicle can no longer drive (from where its
        active order ends, or from where it stands) goes back to the pool, where another
        vehicle may take it, or it waits for the segments to reopen."""
        order = runner.next
        if order is None or runner.current is None:
            return
        start = runner.active.put if runner.active is not None else _standing(runner)
        if self.reach.reaches(start, order.get) and self.reach.reaches(order.get, order.put):
            return
        runner.next, order.assigned = None, None
        self.book.transition(order, OrderState.DISPATCHABLE, ctx.time, "cut off by a blockade")
        self.reassigned += 1

    def _unroutable(self, order: TransportOrder, positions: _Positions) -> str | None:
        """Why no vehicle could ever drive ``order`` on this plant, every segment open."""
        if not self.reach.reaches_on_plant(order.get, order.put):
            return f"no route from Get station {order.get} to Put station {order.put}"
        nodes = positions.of_order(order)
        if len(nodes) and not self.reach.reached_from(nodes, order.get, on_plant=True):
            return f"no vehicle can reach Get station {order.get}"
        return None

    def _routable_now(self, order: TransportOrder, positions: _Positions) -> bool:
        """Can a vehicle that may take ``order`` (its intended one, if it names one) drive
        it over the segments open now? (Before any vehicle has reported where it is: yes,
        as far as is known.)"""
        if not self.reach.reaches(order.get, order.put):
            return False
        nodes = positions.of_order(order)
        return not len(nodes) or self.reach.reached_from(nodes, order.get)

    # ----- deviations ----------------------------------------------------------------------------
    def _check_deviations(self, ctx: CycleContext) -> None:
        for runner in self.runners.values():
            order = runner.active
            if order is None or runner.section not in ("Go_To_Cluster", "Go_To_Get", "Go_To_Put"):
                continue
            key = (order.id, runner.section)
            if key in self._deviated:
                continue
            start = order.sections[runner.section][0]
            to = order.put if runner.section == "Go_To_Put" else order.get
            origin = order.get if runner.section == "Go_To_Put" else self._origin.get(order.id)
            if origin is None:
                continue
            estimate = self.estimates.travel(origin, to)
            # (no estimate yet, or none possible: nothing to deviate from)
            if 0 < estimate < math.inf and self.estimates.deviates(
                start, estimate, ctx.time, self.deviation
            ):
                self._deviated.add(key)
                self.deviations += 1
                for other in self.runners.values():
                    if other.next is not None:
                        back = other.next
                        other.next = None
                        back.assigned = None
                        self.book.transition(back, OrderState.DISPATCHABLE, ctx.time, "recomputed")
                        self.reassigned += 1
                self._last_round_ns = None  # recompute now

    # ----- rounds --------------------------------------------------------------------------------
    def _candidates(self, ctx: CycleContext, finish: Mapping[int, float]) -> list[Candidate]:
        """Who may take an order; a busy vehicle (two_stage's next order) from its active
        order's Put station at its estimated ``finish``."""
        out = []
        for v, r in self.runners.items():
            if r.current is None or r.battery is None or not self.available(v) or r.load_left:
                continue  # (a vehicle whose charge is not known yet takes nothing)
            # (a vehicle charging by choice while idle stays available as if it were not)
            charging = r.phase in ("to_charger", "charging") and not r.topping_up
            if r.active is None:
                if self.charging.may_take(r.battery, charging):
                    out.append(Candidate(v, r.current, ctx.time, "active"))
            elif (
                self.strategy == "two_stage"
                and self.next_order
                and r.next is None
                and r.frozen
                and self.charging.may_take(r.battery - self.charging.use_per_order)
            ):
                out.append(Candidate(v, r.active.put, finish.get(v, ctx.time), "next"))
        return out

    def _index_changes(self, ctx: CycleContext) -> None:
        """Bring the urgency index up to date with the orders that changed state since it
        last looked (a few; all of them only if the book's journal overran)."""
        changed = self.book.changed_since(self._urgent_revision)
        if changed is None:
            self._urgent.rebuild(self.book.dispatchable(), ctx.time)
        else:
            for order in changed:
                self._urgent.update(order, ctx.time)
        self._urgent_revision = self.book.revision

    def _pool(self, ctx: CycleContext, vehicles: list[Candidate]) -> list[TransportOrder]:
        """The ``pool_limit`` most urgent waiting orders, as sorting them all would give
        (orders given back earlier in this scan included), that can be given out now
        (:meth:`_servable`); up to :data:`PASSED_LIMIT` that cannot are passed over."""
        self._index_changes(ctx)
        if not vehicles:
            return []
        return self._urgent.most_urgent(
            self.pool_limit, lambda o: self._servable(o, vehicles), PASSED_LIMIT
        )

    def _servable(self, order: TransportOrder, vehicles: list[Candidate]) -> bool:
        """An order not rechecked since the blockades changed may be cut off, one at a
        station a vehicle out of service holds cannot be served, and one for a vehicle that
        takes nothing now (busy, charging, out of service, a load left on board) waits for
        it: none is given out, or a round would give it again and again to a vehicle that
        could do another, or a pool of them would keep the others out of the rounds."""
        return (
            self.reach.reaches(order.get, order.put)
            and any(
                self.reach.reaches(c.node, order.get)
                for c in vehicles
                if order.vehicle is None or order.vehicle == c.vehicle
            )
            and not self.claims.stuck(order.get)
            and not self.claims.stuck(order.put)
        )

    def _start_round(self, ctx: CycleContext) -> None:
        self._last_round_ns = ctx.time_ns
        finish: dict[int, float] = {}
        if self.strategy == "two_stage":
            self._working, finish = live_schedule(
                self.runners, self.estimates, self.schedule.buffer_s, ctx.time
            )
        vehicles = self._candidates(ctx, finish)
        orders = self._pool(ctx, vehicles)
        if not vehicles or not orders:
            self._working = None
            return
        self._pooled = {o.id: o for o in orders}
        plugged = plugged_strategy(self.strategy)
        if plugged is not None:
            self._round_limit = max(
                PLUGGED_ROUND_MIN, PLUGGED_ROUND_PAIRS * len(vehicles) * len(orders)
            )
            self._round_evaluations = 0
            try:
                self._round = plugged(vehicles, orders, self.distance)
            except Exception as exc:  # the researcher's code: its round, not the fleet
                self._drop_round(f"it raised {_raised(exc)}")
                return
            if not isinstance(self._round, Iterator):
                self._drop_round(
                    f"it returned {type(self._round).__name__}, not a generator (it yields "
                    "after each evaluation and returns its Assignment list)"
                )
        elif self.strategy == "nearest_idle":
            self._round = nearest_idle(vehicles, orders, self.distance)
        elif self.strategy == "dhht":
            self._round = dhht(
                vehicles,
                orders,
                self.distance,
                self._dhht_stats(ctx),
                ctx.time,
                self.capacity_per_h,
            )
        else:
            self._round = two_stage(
                vehicles, orders, self._working, self.estimates, ctx.time, self.bottleneck_s
            )

    def _advance(self, ctx: CycleContext) -> None:
        plugged = plugged_strategy(self.strategy) is not None
        for _ in range(self.budget):
            try:
                next(self._round)
            except StopIteration as done:
                self._round = None
                self.rounds += 1
                self._apply(ctx, done.value)
                return
            except Exception as exc:
                if not plugged:
                    raise  # a built-in strategy's failure is the program's: it faults
                self._drop_round(f"it raised {_raised(exc)}")
                return
            self.evaluations += 1
            if plugged:
                self._round_evaluations += 1
                if self._round_evaluations > self._round_limit:
                    self._drop_round(
                        f"its round did not end after {self._round_limit:,} evaluations"
                    )
                    return

    def _drop_round(self, why: str) -> None:
        """A plugged strategy's round that cannot be applied: refused, with the reason."""
        self._refuse(why)
        self._round = self._working = None
        self._pooled = {}

    def _apply(self, ctx: CycleContext, assignments: list[Assignment]) -> None:
        pooled, self._pooled = self._pooled, {}
        if self._working is not None:
            self.schedule, self._working = self._working, None
        if not isinstance(assignments, list | tuple):
            self._refuse(f"the round returned {type(assignments).__name__}, not a list")
            return
        given: set[str] = set()
        for a in assignments:
            if self._left(a, pooled):
                continue  # it ended meanwhile, as an order still in the book may have
            if (why := self._malformed(a)) is not None:
                self._refuse(why)
                continue
            if a.order.id in given:
                self._refuse(f"order {a.order.id!r} is given twice in one round")
                continue
            given.add(a.order.id)
            runner, order = self.runners[int(a.vehicle)], self.book.get(a.order.id)
            free = runner.active is None or (runner.next is None and runner.frozen)
            free = free and not runner.load_left
            # a next order is driven from where the active one ends
            start = runner.active.put if runner.active is not None else runner.current
            if (
                order.state is not OrderState.DISPATCHABLE
                or order.assigned is not None
                or not free
                or not self.reach.reaches(start, order.get)
                or not self.reach.reaches(order.get, order.put)  # closed since the round began
                or self.claims.stuck(order.get)
                or self.claims.stuck(order.put)
            ):
                continue
            if runner.active is None:
                self._origin[order.id] = runner.current
            else:
                self._origin[order.id] = runner.active.put
            runner.take(ctx, order)
            self.assignments += 1
        self._forget_ended()

    def _forget_ended(self) -> None:
        """Keep where orders were taken and which sections deviated only for the orders the
        vehicles hold now: an order that ended otherwise than by its Put (withdrawn,
        failed, given back) would stay in them for the rest of a months-long run."""
        held = {o.id for r in self.runners.values() for o in (r.active, r.next) if o is not None}
        self._origin = {oid: node for oid, node in self._origin.items() if oid in held}
        self._deviated = {key for key in self._deviated if key[0] in held}

    def _left(self, a: object, pooled: Mapping[str, TransportOrder]) -> bool:
        """Whether ``a`` gives out an order of the round's pool that has left the book since
        the round began (it ended, and was swept), or whose id names another order now (a
        new one took it once the old one had left): neither is the strategy's mistake, and
        the new order was never weighed by the round."""
        if not isinstance(a, Assignment) or not isinstance(a.order, TransportOrder):
            return False
        oid = a.order.id
        if not isinstance(oid, str) or (order := pooled.get(oid)) is None:
            return False
        return oid not in self.book or self.book.get(oid) is not order

    def _malformed(self, a: object) -> str | None:
        """Why ``a`` is no assignment this dispatcher could apply at all, or None. A plugged
        strategy's mistake costs its own assignment, not the fleet: the round's other
        assignments are applied, and the scan goes on."""
        if not isinstance(a, Assignment):
            return f"{type(a).__name__} {a!r:.60} is not an Assignment"
        if (
            isinstance(a.vehicle, bool)
            or not isinstance(a.vehicle, Integral)
            or int(a.vehicle) not in self.runners
        ):
            return f"vehicle {a.vehicle!r:.30} is not a vehicle that takes orders"
        if not isinstance(a.order, TransportOrder) or a.order.id not in self.book:
            return f"{a.order!r:.60} is not an order of the book"
        intended = self.book.get(a.order.id).vehicle
        if intended not in (None, int(a.vehicle)):
            return f"order {a.order.id!r} is for vehicle {intended}, not vehicle {int(a.vehicle)}"
        return None

    def _refuse(self, why: str) -> None:
        """Count a malformed assignment and keep the first reason (the summary says it)."""
        self.refused += 1
        if self.refused_reason is None:
            self.refused_reason = f"dispatch strategy {self.strategy!r}: {why}"

    # ----- bookkeeping -------------------------------------------------------------------------
    def _give_back(self, ctx: CycleContext, runner: OrderRunner) -> None:
        self.reassigned += len(runner.give_back(ctx))

    def section_done(self, order: TransportOrder, name: str, start_s: float, end_s: float) -> None:
        """A runner ended a section: learn its duration and count pickups for dhht."""
        duration = end_s - start_s
        est = self.estimates
        if name == "Go_To_Get":
            origin = self._origin.get(order.id)
            cluster = order.sections.get("Go_To_Cluster")
            if origin is not None and cluster is not None:
                est.record_travel(origin, order.get, end_s - cluster[0])
        elif name == "Get":
            est.record_dwell(order.get, "Get", duration)
            s = self.stats.setdefault(order.get, StationStats(pickups_s=[]))
            s.delivered += 1
            s.pickups_s.append(end_s)
            del s.pickups_s[:-200]
        elif name == "Go_To_Put":
            est.record_travel(order.get, order.put, duration)
        elif name == "Put":
            est.record_dwell(order.put, "Put", duration)
            self._origin.pop(order.id, None)

    def _count_supply(self) -> None:
        """Count the orders added since the last scan per Get station (by position, which
        never changes), so that the count costs the new orders, not the run's whole book.
        Every scan, not only when a round starts: an order added and ended while no round
        starts (withdrawn, unroutable, while no vehicle is free) may have left the book
        (``OrderBook.sweep``) by the next round, and it counts all the same. (The intake
        adds orders earlier in the scan, and sweeps none before the next one.)"""
        for order in self.book.page(self._supply_counted, self.book.added - self._supply_counted):
            self._supply[order.get] += 1
        self._supply_counted = self.book.added

    def _dhht_stats(self, ctx: CycleContext) -> dict[int, StationStats]:
        """Each Get station's supply rate: the orders it has had so far per hour."""
        self._count_supply()
        hours = max(ctx.time / 3600.0, 1.0 / 60.0)
        for station, n in self._supply.items():
            s = self.stats.setdefault(station, StationStats(pickups_s=[]))
            s.supply_per_h = n / hours
        return self.stats


@dataclass(frozen=True)
class _Positions:
    """The nodes (indices) the order-taking vehicles stand on, for one scan's route checks:
    the whole fleet's, and each vehicle's for an order that names its vehicle."""

    nodes: np.ndarray
    by_vehicle: dict[int, int]

    @classmethod
    def of(cls, runners: Mapping[int, OrderRunner], plant: Plant) -> _Positions:
        by_vehicle = {v: plant.idx(r.current) for v, r in runners.items() if r.current is not None}
        return cls(np.fromiter(by_vehicle.values(), dtype=np.intp), by_vehicle)

    def of_order(self, order: TransportOrder) -> np.ndarray:
        if order.vehicle is None:
            return self.nodes
        mine = self.by_vehicle.get(order.vehicle)
        return self.nodes[:0] if mine is None else np.array([mine], dtype=np.intp)


def _standing(runner: OrderRunner) -> int:
    """Where the vehicle will stand once it has driven what it was released."""
    return runner.frontier if runner.frontier is not None else runner.current


def _raised(exc: Exception) -> str:
    """An exception in one line: its type and the first line of its message."""
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {lines[0][:120]}" if lines else type(exc).__name__
