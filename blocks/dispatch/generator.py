"""The seed's order generator: the order mix of a distribution centre from hourly rates.

The seed describes its plant's work as relations between logistic units with an average
throughput in pallets per hour (``SEED_RELATIONS``, 412.4 pallets/h in all) and generates
orders from them: per relation ``round(rate x duration / 3600)`` orders, spread as evenly as
possible over the stations of the two units, and per 100 orders of a relation 2 extra orders
through the control station, where damaged pallets are checked (about 420 orders/h).

What "evenly" and "through the control station" mean here, exactly:

* start times: the duration is cut into one slot per order and each order starts at a seeded
  random point of its slot, so the orders arrive at the relation's rate without being a
  metronome; every start lies in [0, duration);
* stations: Get stations are dealt from the source unit and Put stations from the target
  unit in rounds, each round a seeded shuffle of all the unit's stations, so per relation
  every station is used as often as every other, give or take one, and the Get/Put pairs
  still vary;
* control-station orders: ``round(n x extra_per_100 / 100)`` more orders per relation of n
  orders, each fetching a pallet at a station of the relation's source unit (dealt from the
  same rounds as the relation's own Get stations) and delivering it to the control station;
  their start times are spread over the duration the same way;
* time window: every order may be picked up from its start and should be delivered within
  ``window_s`` (end = start + window). The seed gives no figure: the default 900 s is an
  assumption, a few execution times of the seed's orders (about 100 s) plus queueing.

The seed's warehouse system releases an order about 10 minutes before its start time (so at
420 pallets/h about 70 orders are known at any moment): ``OrderFeed`` hands out the generated
orders at that lead. Everything is a function of the arguments and the seed: each relation
draws from its own generator (seeded by the seed and the relation's names), so adding a
relation does not change the orders of the others.
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .order_file import MAX_ORDERS
from .orders import TransportOrder

CONTROL = "control"  # the unit name of the control station in the seed's plant
WINDOW_S = 900.0
LEAD_S = 600.0  # the seed: orders are released about 10 minutes ahead


@dataclass(frozen=True)
class Relation:
    """Pallets moving from one logistic unit to another, on average ``rate_per_h`` an hour."""

    source: str
    target: str
    rate_per_h: float


SEED_RELATIONS = (
    Relation("receiving", "hrl", 72.3),
    Relation("hrl", "depalletising", 103.0),
    Relation("depalletising", "hrl", 67.9),
    Relation("depalletising", "empty_pallets", 35.1),
    Relation("hrl", "picking", 67.0),
    Relation("picking", "hrl", 42.4),
    Relation("picking", "empty_pallets", 24.7),
)


def generate_orders(
    relations: Sequence[Relation],
    units: Mapping[str, Sequence[int]],
    duration_s: float,
    seed: int,
    control_station: int | None = None,
    extra_per_100: float = 2,
    window_s: float = WINDOW_S,
) -> list[TransportOrder]:
    """The orders of ``duration_s`` seconds, sorted by start time, ids ``o00001``, ...

    ``units``: unit name -> its Get/Put station node ids. Without a ``control_station`` no
    extra orders are made. ValueError names what is wrong with the arguments.
    """
    _check_arguments(relations, units, duration_s, control_station, extra_per_100, window_s, seed)
    counts = order_counts(relations, duration_s, control_station is not None, extra_per_100)
    timed: list[tuple[float, int, int]] = []  # (start, get, put)
    for relation, (n, extra) in zip(relations, counts, strict=True):
        rng = random.Random(f"{seed}:{relation.source}>{relation.target}")
        gets = _dealt(units[relation.source], n + extra, rng)
        puts = _dealt(units[relation.target], n, rng)
        timed += zip(_spread(n, duration_s, rng), gets[:n], puts, strict=True)
        if extra:
            controls = [control_station] * extra
            timed += zip(_spread(extra, duration_s, rng), gets[n:], controls, strict=True)
        if len(timed) > MAX_ORDERS:  # order_counts refused this already; never grow past it
            raise ValueError(_too_many(len(timed)))
    timed.sort(key=lambda item: item[0])  # stable: equal starts keep the relations' order
    return [
        TransportOrder(f"o{k:05d}", get, put, start_s=start, end_s=start + window_s)
        for k, (start, get, put) in enumerate(timed, start=1)
    ]


def order_counts(
    relations: Sequence[Relation],
    duration_s: float,
    control: bool,
    extra_per_100: float = 2,
) -> list[tuple[int, int]]:
    """(orders, control-station orders) per relation, or ValueError if together they are
    more than MAX_ORDERS: counted before anything is generated, because a large rate times
    a long duration would otherwise fill the memory before the limit could be checked."""
    share = 1 + extra_per_100 / 100 if control else 1
    expected = sum(r.rate_per_h for r in relations) * duration_s / 3600 * share
    if not expected <= 2 * MAX_ORDERS:  # far too many (or inf): no need to count exactly
        raise ValueError(_too_many(expected, "about "))
    counts = []
    for relation in relations:
        n = round(relation.rate_per_h * duration_s / 3600)
        counts.append((n, round(n * extra_per_100 / 100) if control else 0))
    total = sum(n + extra for n, extra in counts)
    if total > MAX_ORDERS:
        raise ValueError(_too_many(total))
    return counts


def _too_many(count: float, about: str = "") -> str:
    counted = f"{about}{count:,.0f}" if math.isfinite(count) else "too many to count"
    return (
        f"{counted} orders: more than {MAX_ORDERS:,}, the limit of an order file "
        "(docs/orders.md, Size limits): generate a shorter duration or lower rates"
    )


def _spread(n: int, duration_s: float, rng: random.Random) -> list[float]:
    """n start times, one at a random point of each of n equal slots of [0, duration)."""
    slot = duration_s / n if n else 0.0
    last = math.nextafter(duration_s, 0.0)  # (k + u) x slot may round up to the duration
    return [min((k + rng.random()) * slot, last) for k in range(n)]


def _dealt(stations: Sequence[int], n: int, rng: random.Random) -> list[int]:
    """n stations dealt in rounds, each round a shuffle of all of them: every station is
    used as often as every other, give or take one."""
    out: list[int] = []
    while len(out) < n:
        deck = list(stations)
        rng.shuffle(deck)
        out += deck
    return out[:n]


def _check_arguments(
    relations: Sequence[Relation],
    units: Mapping[str, Sequence[int]],
    duration_s: float,
    control_station: int | None,
    extra_per_100: float,
    window_s: float,
    seed: object,
) -> None:
    if isinstance(seed, bool) or not isinstance(seed, int):
        # the seed names the random streams as text: 1.5 and 1 would be other runs silently
        raise ValueError(f"seed must be an integer, got {seed!r}")
    for name, stations in units.items():
        if isinstance(stations, str | bytes) or not isinstance(stations, Sequence):
            raise ValueError(
                f"unit {name!r}: expected a list of station node ids, got {stations!r}"
            )
    if not math.isfinite(duration_s) or duration_s <= 0:
        raise ValueError(f"duration must be a positive number of seconds, got {duration_s!r}")
    if not math.isfinite(window_s) or window_s < 0:
        raise ValueError(f"window_s must be a number of seconds >= 0, got {window_s!r}")
    if not math.isfinite(extra_per_100) or extra_per_100 < 0:
        raise ValueError(f"extra_per_100 must be a number >= 0, got {extra_per_100!r}")
    for relation in relations:
        name = f"relation {relation.source} -> {relation.target}"
        if not math.isfinite(relation.rate_per_h) or relation.rate_per_h < 0:
            raise ValueError(
                f"{name}: rate must be pallets per hour >= 0, got {relation.rate_per_h!r}"
            )
        for unit in (relation.source, relation.target):
            stations = units.get(unit)
            if not stations:
                raise ValueError(
                    f"{name}: unit {unit!r} has no stations (units: {', '.join(sorted(units))})"
                )
            if len(set(stations)) != len(stations):
                raise ValueError(f"unit {unit!r} lists a station twice: {list(stations)}")
        shared = set(units[relation.source]) & set(units[relation.target])
        if control_station is not None and control_station in units[relation.source]:
            shared.add(control_station)
        if shared:
            raise ValueError(
                f"{name}: station {min(shared)} would be Get and Put of one order "
                "(in both units, or the control station in the source unit)"
            )


class OrderFeed:
    """Hands out orders as the warehouse system releases them: each ``lead_s`` before its
    start time (at once if that is before the first call). Each order is handed out once;
    a call costs only the orders it returns, so a scan can ask every cycle."""

    def __init__(self, orders: Sequence[TransportOrder], lead_s: float = LEAD_S) -> None:
        if not math.isfinite(lead_s) or lead_s < 0:
            raise ValueError(f"lead_s must be a number of seconds >= 0, got {lead_s!r}")
        self.lead_s = lead_s
        self._orders = sorted(orders, key=lambda o: o.start_s)
        self._next = 0

    def due(self, now_s: float, limit: int | None = None) -> list[TransportOrder]:
        """The orders released by ``now_s`` and not handed out before, by start time; at
        most ``limit`` of them (the rest on the next calls), so a call's cost stays bounded
        however many orders fall due at once."""
        first = self._next
        end = len(self._orders) if limit is None else min(len(self._orders), first + limit)
        while self._next < end and self._orders[self._next].start_s - self.lead_s <= now_s:
            self._next += 1
        return self._orders[first : self._next]

    @property
    def pending(self) -> int:
        """Orders not released yet."""
        return len(self._orders) - self._next
