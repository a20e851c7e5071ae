"""StationSchedule: who occupies which Get/Put station when, as the seed's reservation lists.

The seed's two-stage allocation prices a (vehicle, order) pair by its idle time, and most of
that is waiting at stations. So every station keeps a time-sorted list of visits
(vehicle, order, start, end = start + dwell), and a new visit goes into the next free slot:
``wait = slot - arrival``. Vehicles never arrive exactly on time, so one global buffer ``B``
(seconds) pads every visit, half before its start and half after its end; two visits of a
station are therefore at least ``B`` apart. A larger ``B`` means more planned waiting but
fewer vehicles blocking each other in front of a station (the seed's buffer sweep found the
shortest execution time near B = 38 s).

A slot may fall into a gap between two visits when the gap is wide enough, else it follows
the last visit. The dispatcher builds a new schedule for every allocation round from the
vehicles' live state (their remaining visits, :func:`live_schedule`) and commits the round's assignments into it,
so it holds only the visits still to come, and memory stays bounded over a long run.

All times are simulation seconds passed in by the caller; nothing here reads a clock.
"""

from __future__ import annotations

import heapq
import math
from bisect import bisect_right, insort
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .arguments import finite_number

if TYPE_CHECKING:
    from .estimates import SectionEstimates
    from .executor import OrderRunner
    from .orders import TransportOrder


@dataclass(frozen=True, slots=True)
class Reservation:
    """One visit of a station: ``vehicle`` dwells there for ``order`` from start to end."""

    vehicle: int
    order: str
    start_s: float
    end_s: float


def _order_key(r: Reservation) -> tuple[float, float]:
    # Sorting by (start, end) keeps the ends non-decreasing too (visits never overlap), even
    # for zero-length visits sharing a start when B = 0; slot() relies on that to bisect.
    return (r.start_s, r.end_s)


def _time(where: str, name: str, value: float, minimum: float = -math.inf) -> float:
    return finite_number("StationSchedule", where, name, value, minimum)


class StationSchedule:
    """Per station a time-sorted list of :class:`Reservation`, padded by one buffer ``B``.

    A visit starting at ``t`` with dwell ``d`` occupies ``[t - B/2, t + d + B/2]``; it is free
    when that interval overlaps no reserved ``[s - B/2, e + B/2]`` (touching is allowed).
    """

    def __init__(self, buffer_s: float) -> None:
        self._buffer = _time("__init__", "buffer_s", buffer_s, minimum=0.0)
        self._lists: dict[int, list[Reservation]] = {}

    @property
    def buffer_s(self) -> float:
        """The global buffer B; fixed, since the existing lists were laid out with it."""
        return self._buffer

    def slot(self, station: int, arrival_s: float, dwell_s: float) -> float:
        """The earliest start >= ``arrival_s`` at which a visit of ``dwell_s`` fits."""
        arrival_s = _time("slot", "arrival_s", arrival_s)
        dwell_s = _time("slot", "dwell_s", dwell_s, minimum=0.0)
        visits = self._lists.get(station, [])
        b = self._buffer
        # Visits whose padded end lies at or before the arrival cannot delay it (ends are
        # non-decreasing along the list, so they form a prefix).
        first = bisect_right(visits, arrival_s, key=lambda r: r.end_s + b)
        t = arrival_s
        for r in visits[first:]:
            if t + dwell_s + b <= r.start_s:
                break  # fits in the gap before r, and every later visit starts later still
            t = max(t, r.end_s + b)
        return t

    def wait(self, station: int, arrival_s: float, dwell_s: float) -> float:
        """Seconds a vehicle arriving at ``arrival_s`` would wait before its visit starts."""
        return self.slot(station, arrival_s, dwell_s) - float(arrival_s)

    def reserve(
        self, station: int, vehicle: int, order: str, arrival_s: float, dwell_s: float
    ) -> Reservation:
        """Book the next free slot for this visit and return it."""
        start = self.slot(station, arrival_s, dwell_s)
        r = Reservation(vehicle, order, start, start + float(dwell_s))
        insort(self._lists.setdefault(station, []), r, key=_order_key)
        return r

    def reservations(self, station: int) -> tuple[Reservation, ...]:
        """The station's reservations, sorted by start."""
        return tuple(self._lists.get(station, ()))

    def __len__(self) -> int:
        return sum(len(visits) for visits in self._lists.values())


def live_schedule(
    runners: Mapping[int, OrderRunner],
    estimates: SectionEstimates,
    buffer_s: float,
    now_s: float,
) -> tuple[StationSchedule, dict[int, float]]:
    """The reservation lists as the vehicles stand at ``now_s``, and when each busy
    vehicle's active order is estimated to end (its Put visit's end).

    The dispatcher builds them anew for every allocation round rather than keeping the
    rounds' plans: a vehicle running late would otherwise drop out of the lists once its
    planned visit is over, and more vehicles be sent to a station it has yet to reach; a
    queue that formed in front of a station would go unseen. Every remaining visit of every
    active and next order is booked, earliest estimated arrival first, and each arrival
    follows from the vehicle's previous visit as booked: a vehicle third in a station's
    queue ends its order two visits later, and its next order starts later too. A vehicle
    standing at its station stays there until its dwell ends.
    """
    schedule = StationSchedule(buffer_s)
    chains: dict[int, list[tuple[int, str, TransportOrder]]] = {}
    due: list[tuple[float, int, int, float]] = []  # (arrival, vehicle, step, dwell)
    for v, r in runners.items():
        o = r.active
        if o is None or r.current is None:
            continue
        if r.phase in ("to_get", "get_queue", "get"):
            chain = [(o.get, "Get", o), (o.put, "Put", o)]
        elif r.phase in ("to_put", "put_queue", "put"):
            chain = [(o.put, "Put", o)]
        else:
            continue
        if r.next is not None:
            chain += [(r.next.get, "Get", r.next), (r.next.put, "Put", r.next)]
        chains[v] = chain
        if r.phase in ("get", "put"):
            due.append((now_s, v, 0, max(0.0, r.dwell_until_ns / 1e9 - now_s)))
        else:
            station, kind, _ = chain[0]
            arrival = now_s + estimates.travel(r.current, station)
            due.append((arrival, v, 0, estimates.dwell(station, kind)))
    heapq.heapify(due)
    finish: dict[int, float] = {}
    while due:
        arrival, v, step, dwell = heapq.heappop(due)
        station, kind, order = chains[v][step]
        booked = schedule.reserve(station, v, order.id, arrival, dwell)
        if kind == "Put" and order is runners[v].active:
            finish[v] = booked.end_s
        if step + 1 < len(chains[v]):
            after, then, _ = chains[v][step + 1]
            at = booked.end_s + estimates.travel(station, after)
            heapq.heappush(due, (at, v, step + 1, estimates.dwell(after, then)))
    return schedule, finish
