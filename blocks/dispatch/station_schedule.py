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
the last visit. Tentative evaluations (which vehicle should get this order?) reserve on a
:meth:`copy`; the winner's copy replaces the working schedule. ``prune`` drops visits that can
no longer delay anyone, so memory stays bounded over a long run.

All times are simulation seconds passed in by the caller; nothing here reads a clock.
"""

from __future__ import annotations

import math
from bisect import bisect_right, insort
from collections.abc import Callable
from dataclasses import dataclass

from .arguments import finite_number


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

    def cancel(self, order: str) -> int:
        """Drop every reservation of ``order`` (all stations); returns how many."""
        return self._drop(lambda r: r.order == order)

    def cancel_vehicle(self, vehicle: int) -> int:
        """Drop every reservation of ``vehicle`` (all stations); returns how many."""
        return self._drop(lambda r: r.vehicle == vehicle)

    def prune(self, now_s: float) -> int:
        """Drop reservations ended before ``now_s - B``; returns how many.

        Their padded end is past, so they cannot delay any visit arriving at ``now_s`` or
        later, which is every visit the dispatcher still plans.
        """
        now_s = _time("prune", "now_s", now_s)
        b = self._buffer
        dropped = 0
        for station in list(self._lists):
            visits = self._lists[station]
            n = bisect_right(visits, now_s, key=lambda r: r.end_s + b)
            if n:
                del visits[:n]
                dropped += n
            if not visits:
                del self._lists[station]
        return dropped

    def copy(self) -> StationSchedule:
        """An independent clone for tentative evaluation (reservations are immutable)."""
        clone = StationSchedule.__new__(StationSchedule)
        clone._buffer = self._buffer
        clone._lists = {station: list(visits) for station, visits in self._lists.items()}
        return clone

    def reservations(self, station: int) -> tuple[Reservation, ...]:
        """The station's reservations, sorted by start."""
        return tuple(self._lists.get(station, ()))

    def __len__(self) -> int:
        return sum(len(visits) for visits in self._lists.values())

    def _drop(self, doomed: Callable[[Reservation], bool]) -> int:
        dropped = 0
        for station in list(self._lists):
            visits = self._lists[station]
            kept = [r for r in visits if not doomed(r)]
            dropped += len(visits) - len(kept)
            if kept:
                self._lists[station] = kept
            else:
                del self._lists[station]
        return dropped
