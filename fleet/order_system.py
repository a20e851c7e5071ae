"""The transport-order side of the fleet program: the order book, where its orders come
from, the dispatcher, and one OrderRunner per vehicle that takes orders.

Orders come from the configuration's order file and the seed's generator (each released
``lead_s`` before its start, as the seed's warehouse system does), and at run time from
:meth:`OrderSystem.submit` / :meth:`OrderSystem.withdraw`: any thread may call them; the
change is applied at the next scan, between two scans' blocks, so it never races the
program, and a bad order is refused with the book's error and changes nothing. Nothing
of the caller's is kept: a submitted order is copied into built-in values when it is
submitted, and the Future ends with a copy of the book's order, so no caller can change
the book behind the scan's back. Whatever a request raises while it is taken in is that
request's answer, never a fault of the scan.

The intake's work per scan is bounded (a scan has a watchdog): an order file of 100,000
orders due at once is released ``RELEASE_BUDGET`` orders a scan, in the feed's order,
and final orders leave the book ``keep_final_s`` after they became final,
``SWEEP_BUDGET`` a scan, their totals kept for the summary.
"""

from __future__ import annotations

import queue
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import Future

from blocks.dispatch.charging import ChargePolicy
from blocks.dispatch.dispatcher import Dispatcher
from blocks.dispatch.estimates import SectionEstimates
from blocks.dispatch.executor import Claims, OrderRunner, area_entries
from blocks.dispatch.generator import OrderFeed, generate_orders
from blocks.dispatch.order_file import located_orders
from blocks.dispatch.orders import (
    KEEP_FINAL_S,
    OrderBook,
    OrderError,
    TransportOrder,
    check_order,
    order_copy,
    plain_order,
    plain_value,
)
from blocks.dispatch.reachability import Reachability
from blocks.dispatch.station_schedule import StationSchedule
from blocks.routing.constraints import RoutingConstraints
from blocks.routing.heuristic import HeuristicTable
from plc_runtime import CycleContext, FunctionBlock
from plc_runtime.errors import ConfigError
from topology import Plant

from .config import FleetConfig
from .order_report import OrderTotals

# configured orders released, and outside requests decided, per scan at most: an add costs
# some 5 us (500 take about 2.5 ms), so releasing 100,000 orders due at once keeps every
# scan inside the default 10 ms cycle and 150 ms watchdog, and takes 200 scans; a pool of a
# few hundred orders known at once (the allocation experiments) is still released whole
RELEASE_BUDGET = 500
# requests from Python (submit, withdraw) that may wait for the scan at once: the most an
# order file may hold
MAX_WAITING = 100_000
# open orders (waiting or running, configured ones not released yet included) beyond which
# an order from outside is refused: as many as an order file may hold. A client may add
# orders as fast as its rate allows, and each open order costs memory and the dispatcher's
# indexes; the run's own orders (file, generator) are never refused for it
MAX_OPEN_ORDERS = 100_000
# final orders swept from the book per scan at most: removing one costs a few microseconds,
# and the seed's distribution centre finishes an order every 9 s, so the sweep keeps up
# with any plant while a day's orders turning final at once do not stretch a scan
SWEEP_BUDGET = 100


def order_stations(plant: Plant) -> dict[int, str]:
    """The nodes an order may name as Get or Put: the plant's stations."""
    return {s: plant.node(s).name or f"station {s}" for s in plant.with_role("station")}


def configured_orders(cfg: FleetConfig) -> list[TransportOrder]:
    """Every order of the configuration (file, then generator), checked against the plant
    and each other before the run starts: a bad order is a ConfigError naming it."""
    oc, plant = cfg.orders, cfg.plant
    if oc is None:
        return []
    located: list[tuple[str, TransportOrder]] = []  # (where it comes from, the order)
    if oc.file is not None:
        try:
            located += located_orders(oc.file)
        except ValueError as exc:
            raise ConfigError(f"{cfg.source}: orders.file: {exc}") from None
    g = oc.generator
    if g is not None:
        units = {name: plant.stations_for(f) for name, f in g.units.items()}
        relations = [type(r)(r.source, r.target, r.rate_per_h * g.scale) for r in g.relations]
        control = plant.stations_for(g.control)[0] if g.control is not None else None
        try:
            generated = generate_orders(
                relations, units, g.duration_s, g.seed, control, window_s=g.window_s
            )
        except ValueError as exc:
            raise ConfigError(f"{cfg.source}: orders.generator: {exc}") from None
        located += [("orders.generator", order) for order in generated]
    trial = order_book(cfg)
    for where, order in located:
        try:
            trial.add(_fresh(order), 0.0)
        except OrderError as exc:
            key = "orders.generator" if where == "orders.generator" else f"orders.file: {where}"
            problem = f"{cfg.source}: {key}: {exc}"
            if exc.field == "vehicle" and order.vehicle in cfg.vehicles_left_out:
                kept = len(cfg.starts)
                problem = (
                    f"--vehicles-count {kept}: {problem}, since the option keeps only the "
                    f"first {kept} vehicles"
                )
            raise ConfigError(problem) from None
    return [order for _where, order in located]


def order_book(cfg: FleetConfig) -> OrderBook:
    """An empty book for the configuration: an intended vehicle must take orders (a vehicle
    that runs recipes never takes one, so its order would wait for ever)."""
    recipes = [v for v in cfg.starts if v not in cfg.order_vehicles]
    keep = cfg.orders.keep_final_s if cfg.orders else KEEP_FINAL_S
    return OrderBook(order_stations(cfg.plant), cfg.order_vehicles, recipes, keep)


def _fresh(order: TransportOrder) -> TransportOrder:
    return TransportOrder(
        order.id, order.get, order.put, order.start_s, order.end_s, order.priority, order.vehicle
    )


class OrderIntake(FunctionBlock):
    """Puts orders into the book: the released ones of the feed, and those submitted or
    withdrawn from outside the scan (applied here, at the start of the program's scan), and
    takes out the final orders whose time in the book is up, adding them to ``swept``.

    At most ``budget`` released orders and ``budget`` requests a scan: the rest wait, in
    their order, for the next scans, so no number of orders due at once stretches a scan."""

    def __init__(
        self,
        book: OrderBook,
        feed: OrderFeed,
        configured: Iterable[TransportOrder] = (),
        budget: int = RELEASE_BUDGET,
        swept: OrderTotals | None = None,
    ) -> None:
        super().__init__()
        if budget < 1:
            raise ValueError(f"intake budget must be >= 1 order per scan, got {budget}")
        self.book = book
        self.feed = feed
        self.budget = budget
        self.swept = swept if swept is not None else OrderTotals()
        # the configured orders not released yet: their ids are taken, and the operator may
        # withdraw them before they are released
        self.pending: dict[str, TransportOrder] = {o.id: o for o in configured}
        self.requests: queue.SimpleQueue = queue.SimpleQueue()

    def cycle(self, ctx: CycleContext) -> None:
        self.swept.add(self.book.sweep(ctx.time, SWEEP_BUDGET))
        for order in self.feed.due(ctx.time, self.budget):
            if self.pending.pop(order.id, None) is not None:  # else withdrawn before release
                self.book.add(_fresh(order), ctx.time)  # checked against the plant at start
        for _ in range(self.budget):
            try:
                action, arg, done = self.requests.get_nowait()
            except queue.Empty:
                return
            if not done.set_running_or_notify_cancel():
                continue  # the caller cancelled it before this scan: it is never applied
            try:
                result = (
                    self._add(arg, ctx.time) if action == "add" else self._withdraw(arg, ctx.time)
                )
                answer = order_copy(result)
            except Exception as exc:  # whatever the request raised is its answer, not a fault
                done.set_exception(exc)
            else:
                done.set_result(answer)

    def _add(self, order: TransportOrder, now_s: float) -> TransportOrder:
        check_order(order)  # first: whatever came from outside, only OrderError from here on
        if order.id in self.pending:
            raise OrderError(order.id, "id", "used by a configured order not released yet")
        if self.book.open_count() + len(self.pending) >= MAX_OPEN_ORDERS:
            raise OrderError(
                order.id,
                "book",
                f"{MAX_OPEN_ORDERS:,} orders are open already, the most the book takes from "
                "outside: withdraw some, or add it once some have finished",
            )
        return self.book.add(order, now_s)

    def _withdraw(self, order_id: str, now_s: float) -> TransportOrder:
        """Withdraw an order of the book, or a configured one not released yet: that one
        goes in the book WITHDRAWN (its history says when), and is never released."""
        if not isinstance(order_id, str):  # never an id: not hashed, it may not be hashable
            raise OrderError(order_id, "id", "no such order")
        if order_id in self.pending:
            order = self.pending.pop(order_id)
            return self.book.add(_fresh(order), now_s, withdrawn="withdrawn")
        return self.book.withdraw(order_id, now_s)


class OrderSystem:
    def __init__(
        self,
        cfg: FleetConfig,
        table: HeuristicTable,
        blockades: RoutingConstraints,
        available: Callable[[int], bool],
        occupied: Callable[[int, int], bool] | None = None,
    ) -> None:
        """``occupied(node, vehicle)``: whether a vehicle other than ``vehicle`` stands on
        ``node`` or in its single-vehicle area (the reservations'): places are given only
        when empty."""
        plant, d = cfg.plant, cfg.dispatch
        self.cfg = cfg
        self.book = order_book(cfg)
        configured = configured_orders(cfg)
        self.feed = OrderFeed(configured, cfg.orders.lead_s if cfg.orders else 0.0)
        self.swept = OrderTotals()  # the orders that have left the book
        self.intake = OrderIntake(self.book, self.feed, configured, swept=self.swept)
        # why a request would never be answered now (None: it will be); its owner sets it
        self.refusal: Callable[[], str | None] = lambda: None
        self.claims = Claims(occupied)
        self.charging: ChargePolicy = cfg.battery.policy()
        self.table = table
        self.estimates = SectionEstimates(
            self.distance, d.get_s, d.mean_speed, outlier=d.outlier, method=d.estimate
        )
        self.reach = Reachability(plant, blockades, targets(plant))
        self.runners: dict[int, OrderRunner] = {}
        self.dispatcher = Dispatcher(
            self.book,
            self.runners,
            d.strategy,
            self.distance,
            self.reach,
            StationSchedule(d.buffer_s),
            self.estimates,
            self.charging,
            available,
            claims=self.claims,
            budget=d.budget,
            interval_s=d.interval_s,
            deviation=d.deviation,
            capacity_per_h=d.capacity_per_h,
            next_order=d.next_order,
            bottleneck_s=d.bottleneck_s,
        )
        for v in cfg.order_vehicles:
            self.runners[v] = OrderRunner(
                v,
                plant,
                self.book,
                self.claims,
                self.charging,
                self.distance,
                get_s=d.get_s,
                put_s=d.put_s,
                park=d.park,
                on_section=self.dispatcher.section_done,
                out_of_service_s=d.out_of_service_s,
                reaches=self.reach.reaches,
            )

    def distance(self, a: int, b: int) -> float:
        """Exact distance a -> b (ids) in metres; inf while the table has no row for b."""
        d = self.table.distance(a, b)
        return float("inf") if d is None else d

    # ----- the entry point for operators and scripts -------------------------------------------
    def submit(self, order: TransportOrder) -> Future:
        """Queue a copy of ``order`` for the book; the Future ends with a copy of the order
        as the book took it, or the OrderError that refused it (anything that is not a good
        order), after the next scan. The copy is made here, in the caller's thread: changing
        ``order`` afterwards changes nothing, and a value that cannot be copied costs the
        caller, not the scan (its Future ends at once with the error)."""
        try:
            plain = plain_order(order)
        except Exception as exc:
            return _answered(exc)
        return self._request("add", plain)

    def withdraw(self, order_id: str) -> Future:
        """Queue the withdrawal of an open order, or of a configured one not released yet;
        the Future ends with a copy of the order, now WITHDRAWN, or the OrderError that
        refused it (no such order, or the order is final)."""
        try:
            plain = plain_value(order_id)
        except Exception as exc:
            return _answered(exc)
        return self._request("withdraw", plain)

    def _request(self, action: str, arg: object) -> Future:
        """A Future the intake ends; cancelled before the intake takes it, it is never
        applied. Refused at once (the Future ends with the reason) once the program is
        closed, when no scan will ever answer, and while MAX_WAITING requests wait: the
        intake takes a budget a scan, and a script that submits without stepping must not
        fill the memory."""
        if (why := self.refusal()) is not None:
            return _answered(RuntimeError(why))
        if self.intake.requests.qsize() >= MAX_WAITING:
            return _answered(
                RuntimeError(
                    f"{MAX_WAITING:,} requests wait for the scan already: step the runtime "
                    f"(it takes {self.intake.budget} a scan)"
                )
            )
        done: Future = Future()
        self.intake.requests.put((action, arg, done))
        return done

    def close(self) -> None:
        """No scan will run any more: the requests waiting end with the reason, and the
        later ones at once."""
        self.refusal = lambda: "the fleet program is closed: no scan will answer"
        while True:
            try:
                _action, _arg, done = self.intake.requests.get_nowait()
            except queue.Empty:
                return
            if done.set_running_or_notify_cancel():
                done.set_exception(RuntimeError("the fleet program was closed before the scan"))

    def blocks(self) -> list[FunctionBlock]:
        """The blocks that run before the per-vehicle cycle, in scan order."""
        return [self.intake, self.dispatcher]

    def counts(self) -> Mapping[str, int]:
        return self.book.counts()


def _answered(exc: Exception) -> Future:
    """A Future that has ended with ``exc``."""
    done: Future = Future()
    done.set_exception(exc)
    return done


def targets(plant: Plant) -> list[int]:
    """Nodes vehicles are sent to by orders, charging and parking (heuristic-table rows)."""
    return sorted(
        set(plant.with_role("station", "charger", "parking", "queue"))
        | {n for nodes in plant.queues.values() for n in nodes}
        | set(area_entries(plant).values())
    )
