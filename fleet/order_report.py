"""What a run with transport orders reports: order counts per state, execution and
waiting times, charging, and the per-order history CSV (the seed's section times)."""

from __future__ import annotations

from pathlib import Path
from statistics import mean
from typing import TYPE_CHECKING, Any

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


def station_use(system: OrderSystem) -> dict[int, tuple[int, float]]:
    """Per station: the transport orders' finished visits (Get and Put dwells) and the
    seconds they took, for the summary's ``station_utilisation``."""
    use: dict[int, tuple[int, float]] = {}
    for order in system.book:
        for name, station in (("Get", order.get), ("Put", order.put)):
            times = order.sections.get(name)
            if times is not None and len(times) == 2:
                visits, busy = use.get(station, (0, 0.0))
                use[station] = (visits + 1, busy + times[1] - times[0])
    return use


def order_summary(system: OrderSystem) -> dict[str, Any]:
    finished = [o for o in system.book if o.state is OrderState.FINISHED]
    times = [t for o in finished if (t := execution_s(o)) is not None]
    runners = system.runners.values()
    d = system.dispatcher
    return {
        "orders": system.book.counts(),
        "orders_pending_release": len(system.intake.pending),
        "mean_order_time_s": round(mean(times), 3) if times else None,
        "station_wait_s": round(mean(waiting_s(o) for o in finished), 3) if finished else None,
        "makespan_s": round(max(o.finished_s for o in finished), 3) if finished else None,
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
            "time_s": round(sum(r.charging_s for r in runners), 3),
            "min_battery": min((r.min_battery for r in runners), default=None),
        },
    }


def write_orders_csv(system: OrderSystem, path: Path) -> Path:
    write_history(path, list(system.book))
    return path
