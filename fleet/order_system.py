"""The transport-order side of the fleet program: the order book, where its orders come
from, the dispatcher, and one OrderRunner per vehicle that takes orders.

Orders come from the configuration's order file and the seed's generator (each released
``lead_s`` before its start, as the seed's warehouse system does), and at run time from
:meth:`OrderSystem.submit` / :meth:`OrderSystem.withdraw`: any thread may call them; the
change is applied at the next scan, between two scans' blocks, so it never races the
program, and a bad order is refused with the book's error and changes nothing.
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
from blocks.dispatch.order_file import load_orders
from blocks.dispatch.orders import OrderBook, OrderError, TransportOrder
from blocks.dispatch.reachability import Reachability
from blocks.dispatch.station_schedule import StationSchedule
from blocks.routing.constraints import RoutingConstraints
from blocks.routing.heuristic import HeuristicTable
from plc_runtime import CycleContext, FunctionBlock
from plc_runtime.errors import ConfigError
from topology import Plant

from .config import FleetConfig


def order_stations(plant: Plant) -> dict[int, str]:
    """The nodes an order may name as Get or Put: the plant's stations."""
    return {s: plant.node(s).name or f"station {s}" for s in plant.with_role("station")}


def configured_orders(cfg: FleetConfig) -> list[TransportOrder]:
    """Every order of the configuration (file, then generator), checked against the plant
    and each other before the run starts: a bad order is a ConfigError naming it."""
    oc, plant = cfg.orders, cfg.plant
    if oc is None:
        return []
    orders: list[TransportOrder] = []
    if oc.file is not None:
        try:
            orders += load_orders(oc.file)
        except ValueError as exc:
            raise ConfigError(f"{cfg.source}: orders.file: {exc}") from None
    g = oc.generator
    if g is not None:
        units = {name: plant.stations_for(f) for name, f in g.units.items()}
        relations = [type(r)(r.source, r.target, r.rate_per_h * g.scale) for r in g.relations]
        control = plant.stations_for(g.control)[0] if g.control is not None else None
        try:
            orders += generate_orders(
                relations, units, g.duration_s, g.seed, control, window_s=g.window_s
            )
        except ValueError as exc:
            raise ConfigError(f"{cfg.source}: orders.generator: {exc}") from None
    trial = OrderBook(order_stations(plant), cfg.starts)
    for order in orders:
        try:
            trial.add(_fresh(order), 0.0)
        except OrderError as exc:
            where = f"orders.file ({oc.file})" if oc.file is not None else "orders.generator"
            raise ConfigError(f"{cfg.source}: {where}: {exc}") from None
    return orders


def _fresh(order: TransportOrder) -> TransportOrder:
    return TransportOrder(
        order.id, order.get, order.put, order.start_s, order.end_s, order.priority, order.vehicle
    )


class OrderIntake(FunctionBlock):
    """Puts orders into the book: the released ones of the feed, and those submitted or
    withdrawn from outside the scan (applied here, at the start of the program's scan)."""

    def __init__(self, book: OrderBook, feed: OrderFeed, configured: Iterable[str] = ()) -> None:
        super().__init__()
        self.book = book
        self.feed = feed
        self.configured = frozenset(configured)  # ids the feed will still release
        self.requests: queue.SimpleQueue = queue.SimpleQueue()

    def cycle(self, ctx: CycleContext) -> None:
        for order in self.feed.due(ctx.time):
            self.book.add(_fresh(order), ctx.time)  # checked against the plant at start
        while True:
            try:
                action, arg, done = self.requests.get_nowait()
            except queue.Empty:
                return
            try:
                if action == "add":
                    if arg.id in self.configured and arg.id not in self.book:
                        raise OrderError(
                            arg.id, "id", "used by a configured order not released yet"
                        )
                    result = self.book.add(arg, ctx.time)
                else:
                    result = self.book.withdraw(arg, ctx.time)
            except OrderError as exc:
                done.set_exception(exc)
            else:
                done.set_result(result)


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
        self.book = OrderBook(order_stations(plant), cfg.starts)
        configured = configured_orders(cfg)
        self.feed = OrderFeed(configured, cfg.orders.lead_s if cfg.orders else 0.0)
        self.intake = OrderIntake(self.book, self.feed, (o.id for o in configured))
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
            budget=d.budget,
            interval_s=d.interval_s,
            deviation=d.deviation,
            capacity_per_h=d.capacity_per_h,
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
            )

    def distance(self, a: int, b: int) -> float:
        """Exact distance a -> b (ids) in metres; inf while the table has no row for b."""
        d = self.table.distance(a, b)
        return float("inf") if d is None else d

    # ----- the entry point for operators and scripts -------------------------------------------
    def submit(self, order: TransportOrder) -> Future:
        """Queue ``order`` for the book; the Future ends with the order, or the OrderError
        that refused it, after the next scan."""
        return self._request("add", order)

    def withdraw(self, order_id: str) -> Future:
        return self._request("withdraw", order_id)

    def _request(self, action: str, arg: object) -> Future:
        done: Future = Future()
        self.intake.requests.put((action, arg, done))
        return done

    def blocks(self) -> list[FunctionBlock]:
        """The blocks that run before the per-vehicle cycle, in scan order."""
        return [self.intake, self.dispatcher]

    def counts(self) -> Mapping[str, int]:
        return self.book.counts()


def targets(plant: Plant) -> list[int]:
    """Nodes vehicles are sent to by orders, charging and parking (heuristic-table rows)."""
    return sorted(
        set(plant.with_role("station", "charger", "parking", "queue"))
        | {n for nodes in plant.queues.values() for n in nodes}
        | set(area_entries(plant).values())
    )
