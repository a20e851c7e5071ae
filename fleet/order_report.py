"""What a run with transport orders reports: order counts per state, execution and
waiting times, charging, and the per-order history CSV (the seed's section times)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from blocks.dispatch.energy import EnergyBalance
from blocks.dispatch.order_file import write_history
from blocks.dispatch.orders import OrderState, TransportOrder

if TYPE_CHECKING:
    from .order_system import OrderSystem


def execution_s(order: TransportOrder) -> float | None:
    """From taking the order (its first section) to the end of its Put: the seed's order
    execution time. None unless the order finished."""
    if order.state is not OrderState.FINISHED or "Put" not in order.sections:
        return None
    first = min(times[0] for times in order.sections.values())
    put = order.sections["Put"]
    return put[1] - first if len(put) == 2 else None


def waiting_s(order: TransportOrder) -> float:
    """Time spent waiting for the Get and the Put station (the queue sections)."""
    total = 0.0
    for name in ("Get_Queue", "Put_Queue"):
        times = order.sections.get(name)
        if times is not None and len(times) == 2:
            total += times[1] - times[0]
    return total


# every finite float is a whole multiple of 2**-1074: summed as whole numbers of it, times
# add up exactly, so a total does not depend on the order its times were added in
EXACT = 1074


def exact(seconds: float) -> int:
    """``seconds`` as a whole number of 2**-1074 s (exact, for sums)."""
    n, d = seconds.as_integer_ratio()
    return n << (EXACT + 1 - d.bit_length())


def seconds(total: int, count: int = 1) -> float:
    """An exact sum (:func:`exact`) divided by ``count``, as the nearest float."""
    return total / (count << EXACT)


@dataclass
class OrderTotals:
    """What the summary reports of a set of orders, summed, so that orders that have left
    the book (``OrderBook.sweep``) still count: a month-long run's summary covers the month
    while its book holds only the last day. Times are summed exactly (:func:`exact`): a
    float sum depends on the order of its terms, and the orders that left the book are
    summed in the order they left it, so the rounded means would depend on when orders
    left (and a run that swept its orders would report other means than one that kept
    them)."""

    finished: int = 0
    timed: int = 0  # finished orders with an execution time
    execution: int = 0  # their execution times, exact
    waiting: int = 0  # the finished orders' station waits, exact
    makespan_s: float | None = None
    station_use: dict[int, tuple[int, int]] = field(default_factory=dict)  # visits, exact s

    def add(self, orders: Iterable[TransportOrder]) -> OrderTotals:
        for order in orders:
            for name, station in (("Get", order.get), ("Put", order.put)):
                times = order.sections.get(name)
                if times is not None and len(times) == 2:
                    visits, busy = self.station_use.get(station, (0, 0))
                    self.station_use[station] = (visits + 1, busy + exact(times[1] - times[0]))
            if order.state is not OrderState.FINISHED:
                continue
            self.finished += 1
            self.waiting += exact(waiting_s(order))
            if (t := execution_s(order)) is not None:
                self.timed += 1
                self.execution += exact(t)
            end = order.finished_s
            if end is not None and (self.makespan_s is None or end > self.makespan_s):
                self.makespan_s = end
        return self

    def merged(self, other: OrderTotals) -> OrderTotals:
        out = OrderTotals(
            self.finished + other.finished,
            self.timed + other.timed,
            self.execution + other.execution,
            self.waiting + other.waiting,
            max((t for t in (self.makespan_s, other.makespan_s) if t is not None), default=None),
            dict(self.station_use),
        )
        for station, (visits, busy) in other.station_use.items():
            v, b = out.station_use.get(station, (0, 0))
            out.station_use[station] = (v + visits, b + busy)
        return out


def run_totals(system: OrderSystem) -> OrderTotals:
    """The totals of every order of the run: those in the book and those swept from it."""
    return OrderTotals().add(system.book).merged(system.swept)


def station_use(totals: OrderTotals) -> dict[int, tuple[int, float]]:
    """Per station: the transport orders' finished visits (Get and Put dwells) and the
    seconds they took, for the summary's ``station_utilisation``."""
    return {
        station: (visits, seconds(busy)) for station, (visits, busy) in totals.station_use.items()
    }


def order_summary(system: OrderSystem, totals: OrderTotals | None = None) -> dict[str, Any]:
    """The summary's order keys; ``totals``: the run's (``run_totals``), if the caller has
    them already (they cost a pass over the book)."""
    totals = run_totals(system) if totals is None else totals
    runners = system.runners.values()
    d = system.dispatcher
    return {
        "orders": system.book.counts(),
        "orders_pending_release": len(system.intake.pending),
        "orders_swept": system.book.swept,
        "mean_order_time_s": (
            round(seconds(totals.execution, totals.timed), 3) if totals.timed else None
        ),
        "station_wait_s": (
            round(seconds(totals.waiting, totals.finished), 3) if totals.finished else None
        ),
        "makespan_s": round(totals.makespan_s, 3) if totals.makespan_s is not None else None,
        "dispatch": {
            "strategy": d.strategy,
            "rounds": d.rounds,
            "evaluations": d.evaluations,
            "assignments": d.assignments,
            "reassigned": d.reassigned,
            "deviations": d.deviations,
            "cut_off": d.cut_off,
            "refused": d.refused,
            **({"refused_reason": d.refused_reason} if d.refused_reason else {}),
        },
        "charging": {
            "visits": sum(r.charges for r in runners),
            "top_ups": sum(r.top_ups for r in runners),
            "given_up": sum(r.chargers_given_up for r in runners),
            "time_s": round(sum(r.charging_s for r in runners), 3),
            "min_battery": min((r.min_battery for r in runners), default=None),
            **energy_summary(system),
        },
    }


def energy_summary(system: OrderSystem) -> dict[str, Any]:
    """The fleet's energy balance: % of the capacity per hour lost off the chargers (per
    vehicle) and gained on one, the chargers its work needs sustained, and the plant's."""
    balance = EnergyBalance.of(r.meter for r in system.runners.values())

    def rounded(value: float | None) -> float | None:
        return None if value is None else round(value, 2)

    return {
        "drain_pct_per_h": rounded(balance.drain_per_h),
        "charge_pct_per_h": rounded(balance.charge_per_h),
        "chargers_needed": rounded(balance.chargers_needed),
        "chargers": len(system.cfg.plant.with_role("charger")),
    }


def write_orders_csv(system: OrderSystem, path: Path) -> Path:
    write_history(path, list(system.book))
    return path
