"""The allocation strategies: which vehicle gets which transport order.

Each strategy is a generator over a snapshot (the vehicles that may take an order, the
orders that may be given) that yields after every (vehicle, order) evaluation and returns
its assignments; the Dispatcher advances it a bounded number of evaluations per scan, like
the A* block, and applies the result only when the round is complete.

* ``nearest_idle``: the baseline fleet managers ship. Orders by priority, then end time;
  each to the idle vehicle nearest to its Get station (exact distance from the heuristic
  table).
* ``dhht``: the seed's original pull-based allocation. Each idle vehicle pulls the order of
  the station with the smallest D_i = log(d_i) / w_i, w_i = (1 / e_i) (N_Q - N_C) /
  N_delivered, e_i = Tr / Tr_max. Guards: N_delivered = 0 counts as 1; e_i = 0 (nothing
  picked up yet) as a small floor, so a starved station comes first; log(d_i) is taken as
  log(1 + d_i), positive for every distance. An assignment is never changed.
* ``two_stage``: the seed's new allocation. A vehicle holds one active and one next order;
  cost of a pair = idle time = travel to Get + queue wait at Get + queue wait at Put, the
  waits from the station reservation lists (evaluated on a copy). Late orders first (by end
  time), each to the vehicle that finishes it earliest; then, with at least as many orders
  as vehicles, the pair of minimum idle time, committed, and the rest re-evaluated; with
  fewer orders, each order to the vehicle that finishes it earliest. An order whose Get
  arrival would be before its start time waits for a later round. ``bottleneck_s`` (0 in
  the seed) takes up to that many seconds off a pair's idle time in the greedy stage, in
  proportion to how many of the pool's orders visit the busier of its two stations: a
  station most orders must pass (a plant's bottleneck) is then worked from the start, not
  left to the end of a pool, where its queue would hold the whole fleet.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass

from plc_runtime.registry import register

from .estimates import SectionEstimates
from .orders import TransportOrder
from .station_schedule import StationSchedule

STRATEGIES = ("nearest_idle", "dhht", "two_stage")
E_FLOOR = 0.05  # dhht: the pickup efficiency of a station that has not delivered yet


@dataclass
class Candidate:
    """A vehicle that may take an order: from ``node`` at ``free_s`` (now, or when its
    active order is estimated to end at that order's Put station)."""

    vehicle: int
    node: int
    free_s: float
    slot: str  # "active" or "next"


@dataclass
class Assignment:
    vehicle: int
    order: TransportOrder
    idle_s: float = 0.0
    finish_s: float = 0.0


Round = Generator[None, None, list[Assignment]]
# a strategy of one's own: (idle vehicles, orders startable now, exact distance a -> b)
PluggedStrategy = Callable[
    [Sequence[Candidate], Sequence[TransportOrder], Callable[[int, int], float]], Round
]
PLUGGED: dict[str, PluggedStrategy] = {}


def register_strategy(name: str, strategy: PluggedStrategy, replace: bool = False) -> None:
    """Make ``strategy`` a dispatch strategy under ``name`` (``[dispatch] strategy``, or
    ``cfg.dispatch.strategy``, in this process), for trying an allocation of one's own on
    the whole fleet program. It is called as ``nearest_idle`` is: with the idle vehicles
    that may take an order (``Candidate``, slot "active"), the waiting orders whose start
    time has come (the most urgent, at most the dispatcher's pool), and the exact distance
    a -> b in metres; it is a generator that yields after each evaluation (the dispatcher
    runs a bounded number of them per scan) and returns its ``Assignment`` list. Orders
    for another vehicle (``order.vehicle``) must not be given to this one, and at most one
    order to a vehicle; the dispatcher checks each assignment again before it applies it,
    and one it cannot apply at all (not an ``Assignment``, a vehicle that takes no orders,
    an order not in the book, given twice or to a vehicle it is not intended for), like a
    round that is no generator (a list returned at once), raises or never ends, is counted
    in the summary's ``dispatch.refused``, with the first reason, instead of stopping the
    fleet. A name already registered is taken again
    only with ``replace=True`` (a second experiment must not change the first one's
    strategy unnoticed)."""
    register(PLUGGED, "strategy", STRATEGIES, name, strategy, replace)


def plugged_strategy(name: str) -> PluggedStrategy | None:
    """The strategy registered under ``name``, None for a built-in one."""
    return PLUGGED.get(name)


def strategy_names() -> tuple[str, ...]:
    """The built-in strategies, then those registered in this process."""
    return (*STRATEGIES, *PLUGGED)


def _by_urgency(orders: Sequence[TransportOrder]) -> list[TransportOrder]:
    return sorted(orders, key=lambda o: (-o.priority, o.end_s, o.start_s, o.id))


def nearest_idle(
    vehicles: Sequence[Candidate],
    orders: Sequence[TransportOrder],
    distance: Callable[[int, int], float],
) -> Round:
    free = [c for c in vehicles if c.slot == "active"]
    out: list[Assignment] = []
    for order in _by_urgency(orders):
        if not free:
            break
        best, best_d = None, math.inf
        for c in free:
            if order.vehicle is not None and order.vehicle != c.vehicle:
                continue
            d = distance(c.node, order.get)
            yield
            if d < best_d:
                best, best_d = c, d
        if best is not None:
            free.remove(best)
            out.append(Assignment(best.vehicle, order))
    return out


@dataclass
class StationStats:
    """What dhht weighs per Get station: loads collected, pickup times, supply rate."""

    delivered: int = 0
    pickups_s: list[float] | None = None
    supply_per_h: float = 0.0

    def throughput_per_h(self, now_s: float, window_s: float) -> float:
        times = self.pickups_s or []
        recent = sum(1 for t in times if t > now_s - window_s)
        return recent * 3600.0 / window_s


def dhht(
    vehicles: Sequence[Candidate],
    orders: Sequence[TransportOrder],
    distance: Callable[[int, int], float],
    stats: dict[int, StationStats],
    now_s: float,
    capacity_per_h: float,
    window_s: float = 600.0,
) -> Round:
    open_at: dict[int, list[TransportOrder]] = {}
    for order in _by_urgency(orders):
        open_at.setdefault(order.get, []).append(order)
    out: list[Assignment] = []
    for c in (c for c in vehicles if c.slot == "active"):
        best, best_d = None, math.inf
        for station, waiting in open_at.items():
            mine = [o for o in waiting if o.vehicle in (None, c.vehicle)]
            if not mine:
                continue
            s = stats.get(station) or StationStats()
            n_open = len(waiting)  # N_Q - N_C: open orders nobody was given yet
            tr_max = min(s.supply_per_h, capacity_per_h) or capacity_per_h
            e = max(s.throughput_per_h(now_s, window_s) / tr_max, E_FLOOR)
            w = (1.0 / e) * max(n_open, 1) / max(s.delivered, 1)
            d = math.log1p(distance(c.node, station)) / w
            yield
            if d < best_d:
                best, best_d = (station, mine[0]), d
        if best is not None:
            station, order = best
            open_at[station].remove(order)
            if not open_at[station]:
                del open_at[station]
            out.append(Assignment(c.vehicle, order))
    return out


def _evaluate(
    c: Candidate,
    order: TransportOrder,
    schedule: StationSchedule,
    estimates: SectionEstimates,
) -> tuple[float, float, float, float]:
    """(idle time, Put finish, Get arrival, Put arrival) of ``order`` done by ``c``."""
    to_get = estimates.travel(c.node, order.get)
    arrive_get = c.free_s + to_get
    dwell_get = estimates.dwell(order.get, "Get")
    start_get = arrive_get + schedule.wait(order.get, arrive_get, dwell_get)
    arrive_put = start_get + dwell_get + estimates.travel(order.get, order.put)
    dwell_put = estimates.dwell(order.put, "Put")
    wait_put = schedule.wait(order.put, arrive_put, dwell_put)
    idle = to_get + (start_get - arrive_get) + wait_put
    return idle, arrive_put + wait_put + dwell_put, arrive_get, arrive_put


def _busier_station_share(pool: Sequence[TransportOrder]) -> dict[str, float]:
    """Per order of ``pool``: the visits the pool makes to the busier of its Get and Put
    stations, as a share of the visits to the pool's busiest station (0..1]."""
    visits: Counter[int] = Counter()
    for order in pool:
        visits[order.get] += 1
        visits[order.put] += 1
    most = max(visits.values())
    return {o.id: max(visits[o.get], visits[o.put]) / most for o in pool}


def two_stage(
    vehicles: Sequence[Candidate],
    orders: Sequence[TransportOrder],
    schedule: StationSchedule,
    estimates: SectionEstimates,
    now_s: float,
    bottleneck_s: float = 0.0,
) -> Round:
    """Works on ``schedule`` (the caller passes a copy): the committed visits are reserved
    in it, so the caller adopts it with the assignments."""
    free = list(vehicles)
    out: list[Assignment] = []

    def commit(c: Candidate, order: TransportOrder) -> None:
        idle, finish, arrive_get, arrive_put = _evaluate(c, order, schedule, estimates)
        schedule.reserve(
            order.get, c.vehicle, order.id, arrive_get, estimates.dwell(order.get, "Get")
        )
        schedule.reserve(
            order.put, c.vehicle, order.id, arrive_put, estimates.dwell(order.put, "Put")
        )
        free.remove(c)
        out.append(Assignment(c.vehicle, order, idle, finish))

    def allowed(c: Candidate, order: TransportOrder) -> bool:
        return order.vehicle is None or order.vehicle == c.vehicle

    def earliest(order: TransportOrder) -> Generator[None, None, Candidate | None]:
        best, best_finish = None, math.inf
        for c in free:
            if not allowed(c, order):
                continue
            idle, finish, arrive_get, _ = _evaluate(c, order, schedule, estimates)
            yield
            if arrive_get >= order.start_s and finish < best_finish:
                best, best_finish = c, finish
        return best

    pool = _by_urgency(orders)
    # late orders first: those that cannot be done in time any more, by end time
    late = sorted(
        (o for o in pool if o.end_s < now_s + estimates.travel(o.get, o.put)),
        key=lambda o: (o.end_s, o.id),
    )
    for order in late:
        if not free:
            return out
        c = yield from earliest(order)
        if c is not None:
            commit(c, order)
            pool.remove(order)
    if len(pool) >= len(free):
        while free and pool:
            best, best_idle = None, math.inf
            busier = _busier_station_share(pool) if bottleneck_s else {}
            for c in free:
                for order in pool:
                    if not allowed(c, order):
                        continue
                    idle, _finish, arrive_get, _ = _evaluate(c, order, schedule, estimates)
                    idle -= bottleneck_s * busier.get(order.id, 0.0)
                    yield
                    if arrive_get >= order.start_s and idle < best_idle:
                        best, best_idle = (c, order), idle
            if best is None:
                break
            commit(*best)
            pool.remove(best[1])
    else:
        for order in list(pool):
            if not free:
                break
            c = yield from earliest(order)
            if c is not None:
                commit(c, order)
    return out
