"""Transport orders and the order book: what the fleet is asked to move, and where each order
stands in its life cycle.

An order is the seed's (and a warehouse system's) unit of work: fetch a load at a Get
station and deliver it to a Put station, not before its start time (earliest pickup) and
ideally by its end time (latest delivery). Its life cycle is openTCS's, so operators who know
openTCS read the states as they expect::

    RAW -> DISPATCHABLE -> BEING_PROCESSED -> FINISHED
                                         \\-> FAILED | WITHDRAWN
    RAW | DISPATCHABLE -> UNROUTABLE | WITHDRAWN;  DISPATCHABLE -> FAILED
    BEING_PROCESSED -> DISPATCHABLE   (taken back before the load was picked up)

The last arrow is what makes the seed's two-stage allocation possible: a vehicle's NEXT order,
and its active order until it enters the Get station's cluster zone, may still go to another
vehicle, and a blockade may take an order back from a vehicle that can no longer reach it.
Once the Get section has started the load is (being) put on the vehicle, so the order can
only finish, fail or be withdrawn.

The book validates an order completely before it changes anything: a bad order is one
OrderError naming the order, the field and what is wrong, and the book is as before. Every
transition is time-stamped in the order's ``history`` with the time the caller passes in
(the scan's ``ctx.time``): nothing here reads a clock, so a run is reproducible. An order
given out and taken back more often than ``HISTORY_KEPT`` allows keeps its release and its
newest transitions, and counts the others in ``history_dropped``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from sortedcontainers import SortedList

from topology.formats.numbers import MAX_DIGITS, TOO_LONG, shown

CHANGE_LOG = 4096  # state changes the book remembers for live views
# an order's history: two-stage allocation may take a next order back and give it out again
# at every recompute (dozens of times an hour while the fleet is behind), so an order keeps
# its first two transitions (its release) and its newest ones, HISTORY_KEPT at most, and
# counts those it dropped
HISTORY_KEPT = 64
# a controller that runs for months takes some 10,000 orders a day: a final order leaves the
# book a day after it became final by default, so the book holds about a day of orders, not
# the whole run (openTCS sweeps its order pool of old final orders the same way)
KEEP_FINAL_S = 86400.0
MAX_ID_CHARS = 64  # ids are shown in messages, the dashboard and the history CSV
FORMULA_STARTS = frozenset("=+-@")  # what a spreadsheet reads a cell beginning with as a formula
# integers (stations, priority, vehicle) have at most the digits an order file reads, so
# every order the book takes can be written to a file and read back
MAX_INT = 10**MAX_DIGITS - 1


class OrderState(StrEnum):
    """openTCS's states of a transport order; the value is the name (reports, CSV)."""

    RAW = "RAW"
    DISPATCHABLE = "DISPATCHABLE"
    BEING_PROCESSED = "BEING_PROCESSED"
    FINISHED = "FINISHED"
    FAILED = "FAILED"
    WITHDRAWN = "WITHDRAWN"
    UNROUTABLE = "UNROUTABLE"

    @property
    def final(self) -> bool:
        """No transition leaves a final state: the order is history."""
        return self in FINAL_STATES


FINAL_STATES = frozenset(
    {OrderState.FINISHED, OrderState.FAILED, OrderState.WITHDRAWN, OrderState.UNROUTABLE}
)

TRANSITIONS: dict[OrderState, frozenset[OrderState]] = {
    OrderState.RAW: frozenset(
        {OrderState.DISPATCHABLE, OrderState.UNROUTABLE, OrderState.WITHDRAWN}
    ),
    OrderState.DISPATCHABLE: frozenset(
        {
            OrderState.BEING_PROCESSED,
            OrderState.UNROUTABLE,
            OrderState.WITHDRAWN,
            OrderState.FAILED,
        }
    ),
    OrderState.BEING_PROCESSED: frozenset(
        {
            OrderState.FINISHED,
            OrderState.FAILED,
            OrderState.WITHDRAWN,
            OrderState.DISPATCHABLE,
        }
    ),
    **{state: frozenset() for state in FINAL_STATES},
}

# the fields an order from outside sets: what it asks for, and the run-time fields that must
# be fresh (``reason`` is the book's to set)
NEW_ORDER_FIELDS = (
    "id",
    "get",
    "put",
    "start_s",
    "end_s",
    "priority",
    "vehicle",
    "state",
    "history",
    "sections",
    "assigned",
)

SECTIONS = ("Go_To_Cluster", "Go_To_Get", "Get_Queue", "Get", "Go_To_Put", "Put_Queue", "Put")
LOADING = SECTIONS.index("Get")  # from this section on the load is the vehicle's


class OrderError(ValueError):
    """A bad order or an illegal step in its life cycle. ``str()`` is the whole message:
    ``order 'o7': field 'get': station 99 is not a Get/Put station``."""

    def __init__(self, order_id: object, field_name: str, problem: str) -> None:
        self.order_id = order_id
        self.field = field_name
        self.problem = problem
        super().__init__(f"order {_shown(order_id)}: field '{field_name}': {problem}")


@dataclass(eq=False)  # an order is an identity, not a value: two orders are never "equal"
class TransportOrder:
    id: str
    get: int  # Get station (node id): where the load is picked up
    put: int  # Put station (node id): where it is delivered
    start_s: float = 0.0  # earliest pickup, simulation seconds
    end_s: float = math.inf  # latest delivery; inf = no deadline
    priority: int = 0  # larger = more urgent
    vehicle: int | None = None  # the intended vehicle, if the order names one
    # run-time fields, kept by the OrderBook
    state: OrderState = OrderState.RAW
    history: list[tuple[float, OrderState]] = field(default_factory=list)
    sections: dict[str, list[float]] = field(default_factory=dict)  # name -> [start, end]
    assigned: int | None = None  # the vehicle that has it
    reason: str = ""  # why the last transition happened (FAILED, WITHDRAWN, taken back ...)
    position: int = -1  # the orders added to the book before it (-1: not in a book yet)
    history_dropped: int = 0  # transitions dropped from the history (HISTORY_KEPT)

    @property
    def created_s(self) -> float | None:
        return self.history[0][0] if self.history else None

    @property
    def finished_s(self) -> float | None:
        """When the order reached its final state (whichever), None while it is open."""
        return self.history[-1][0] if self.state.final and self.history else None


def check_order(order: object) -> None:
    """OrderError for what is wrong with ``order`` on its own, without knowing the plant:
    types, ranges, get = put, the time window, a fresh run-time state. The order files run these
    checks while reading, so a bad file is reported with its line; the book adds the checks
    that need the plant (stations, vehicles) and the other orders (duplicate ids).

    Total: whatever ``order`` holds (a list as id, a 400-digit number as time, a bool as
    station) the answer is an OrderError naming the field, never another exception, so a
    caller may run it on input from outside before anything else touches the order."""
    if not isinstance(order, TransportOrder):
        raise OrderError(None, "order", f"must be a TransportOrder, got {type(order).__name__}")
    oid = order.id
    if not isinstance(oid, str) or not oid:
        raise OrderError(oid, "id", "must be a non-empty string")
    if len(oid) > MAX_ID_CHARS:
        raise OrderError(oid, "id", f"longer than {MAX_ID_CHARS} characters")
    if not oid.isprintable() or oid != oid.strip():
        raise OrderError(oid, "id", "has control characters or leading/trailing spaces")
    if oid[0] in FORMULA_STARTS:
        # the id is the first cell of the run's orders.csv, which operators open in a
        # spreadsheet: there it would be a formula, run on their machine
        raise OrderError(
            oid, "id", f"begins with {oid[0]!r}, which a spreadsheet takes for a formula"
        )
    for name in ("get", "put"):
        _check_int(
            oid, name, getattr(order, name), "must be a station node id (an integer >= 0)", 0
        )
    if order.get == order.put:
        raise OrderError(oid, "put", f"Put station {order.put} is the Get station")
    start, end = _seconds(order.start_s), _seconds(order.end_s)
    if start is None or not math.isfinite(start) or start < 0:
        raise OrderError(
            oid, "start_s", f"must be a finite number of seconds >= 0, got {_brief(order.start_s)}"
        )
    if end is None or math.isnan(end):
        raise OrderError(
            oid, "end_s", f"must be a number of seconds (or inf), got {_brief(order.end_s)}"
        )
    if end < start:
        raise OrderError(oid, "end_s", f"end {end} s is before the start {start} s")
    _check_int(oid, "priority", order.priority, "must be an integer")
    if order.vehicle is not None:
        _check_int(oid, "vehicle", order.vehicle, "must be a vehicle id (an integer)")
    fresh = (
        order.state is OrderState.RAW
        and type(order.history) is list
        and not order.history
        and type(order.sections) is dict
        and not order.sections
        and order.assigned is None
    )
    if not fresh:
        state = order.state
        what = state.value if isinstance(state, OrderState) else _brief(state)
        raise OrderError(oid, "state", f"a new order must be RAW and unused, it is {what}")


def plain_order(order: object) -> TransportOrder:
    """A new TransportOrder holding ``order``'s fields as built-in values, for an order from
    outside the scan (not yet checked: ``check_order`` refuses what is wrong with it).

    The book keeps the copy, so the caller cannot change a stored order afterwards (the
    scan's blocks trust a stored order's stations and times). A subclass of str, int or
    float becomes that built-in type: one may redefine hashing, comparing or
    ``isprintable``, which the book and the dispatcher call in the scan. A field that
    cannot be read (a subclass's property raising) is an OrderError naming it."""
    if not isinstance(order, TransportOrder):
        raise OrderError(None, "order", f"must be a TransportOrder, got {type(order).__name__}")
    values: dict[str, object] = {}
    for name in NEW_ORDER_FIELDS:
        try:
            value = getattr(order, name)
        except Exception as exc:
            raise OrderError(
                values.get("id"), name, f"cannot be read ({type(exc).__name__})"
            ) from None
        # the run-time fields only have to be fresh: a copy of an empty list or dict is
        # empty, a non-empty one or another type is refused by check_order as it is
        if name == "history" and type(value) is list:
            value = list(value)
        elif name == "sections" and type(value) is dict:
            value = dict(value)
        elif name == "end_s" and value is None:
            value = math.inf  # no deadline, as null in an order file or over HTTP
        elif name != "state":  # an OrderState stays one (check_order compares identity)
            value = plain_value(value)
        values[name] = value
    return TransportOrder(**values)  # type: ignore[arg-type]


def plain_value(value: object) -> object:
    """``value`` as the built-in type if it is an instance of a subclass of str, int or
    float (whose methods it may redefine), or a numpy scalar (a node id taken from
    ``plant.ids``); anything else as it is, a bool included."""
    if isinstance(value, bool | np.bool_):
        return value
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, str):
        return str.__str__(value)  # the base class's own copy, whatever the subclass defines
    if isinstance(value, int):
        return int.__int__(value)
    if isinstance(value, float):
        return float.__float__(value)
    return value


def order_copy(order: TransportOrder) -> TransportOrder:
    """A copy of a stored order as it is now, sharing nothing that changes: what an order
    handed out of the scan is, so nobody outside can change the book through it."""
    return TransportOrder(
        order.id,
        order.get,
        order.put,
        order.start_s,
        order.end_s,
        order.priority,
        order.vehicle,
        order.state,
        list(order.history),
        {name: list(times) for name, times in order.sections.items()},
        order.assigned,
        order.reason,
        order.position,
    )


class OrderBook:
    """The pool of orders of a run, open and final: the dispatcher takes orders from it, the
    executors record their progress in it, reports read it.

    A final order stays in the book for ``keep_final_s`` after it became final, then
    :meth:`sweep` removes it, so a controller that runs for months holds the orders of the
    last ``keep_final_s``, not of the whole run (docs/orders.md, "Size limits"). Until then
    its id cannot be used again, and the history written at the end holds it. Each order
    has a position, the count of orders added before it, which never changes: pages of the
    book are by position, so a page does not shift when older orders leave.
    """

    def __init__(
        self,
        stations: Mapping[int, str],
        vehicles: Iterable[int] | None = None,
        recipe_vehicles: Iterable[int] = (),
        keep_final_s: float = KEEP_FINAL_S,
    ) -> None:
        """``stations``: the valid Get/Put stations (node id -> name for messages);
        ``vehicles``: the ids of the vehicles that take orders, if intended vehicles are to
        be checked; ``recipe_vehicles``: the fleet's other vehicles, which run recipes: an
        order intended for one would wait for ever, and is refused saying why."""
        self.stations = dict(stations)
        self.vehicles = None if vehicles is None else frozenset(vehicles)
        self.recipe_vehicles = frozenset(recipe_vehicles)
        if isinstance(keep_final_s, bool) or not (
            isinstance(keep_final_s, int | float) and keep_final_s >= 0
        ):
            raise ValueError(f"keep_final_s must be a number of seconds >= 0, got {keep_final_s!r}")
        self.keep_final_s = float(keep_final_s)
        self._orders: dict[str, TransportOrder] = {}
        self.added = 0  # orders ever added: the next order's position
        self.swept = 0  # final orders that have left the book
        # the positions of the orders in the book, ascending, and the order at each: a page
        # is a slice from a bisection, so it costs the orders it holds, whatever the offset;
        # sorted in blocks, so the sweep takes an order out in log time, not by moving every
        # later position of a long run's book
        self._positions: SortedList = SortedList()
        self._at: dict[int, TransportOrder] = {}
        # (time it became final, id), oldest first: what the sweep removes next
        self._final: deque[tuple[float, str]] = deque()
        # the DISPATCHABLE ones, in the order added: a scan asks for them every cycle, and a
        # long run's book is mostly final orders
        self._dispatchable: dict[str, TransportOrder] = {}
        # orders per state, kept on every transition: read every refresh of a live view
        self._counts: dict[str, int] = {state.value: 0 for state in OrderState}
        # the ids of the orders that changed state, newest last: live views read what changed
        # since they last looked (``changed_since``) instead of the whole book; the orders
        # themselves, so that one swept since can still be told in its final state
        self.revision = 0  # transitions so far
        self._changed: deque[tuple[int, TransportOrder]] = deque(maxlen=CHANGE_LOG)

    # ----- the pool ------------------------------------------------------------------------
    def add(
        self, order: TransportOrder, now_s: float, withdrawn: str | None = None
    ) -> TransportOrder:
        """Check ``order`` whole, then put it in the book as DISPATCHABLE (RAW and
        DISPATCHABLE both time-stamped ``now_s``). A bad order raises OrderError and leaves
        the book unchanged. With ``withdrawn`` (the reason) it goes in WITHDRAWN instead:
        a known order withdrawn before it was released keeps its id and history, and is
        never dispatched."""
        check_order(order)
        oid = order.id
        for name in ("get", "put"):
            station = getattr(order, name)
            if station not in self.stations:
                raise OrderError(oid, name, f"node {station} is not a Get/Put station")
        vehicle = order.vehicle
        if self.vehicles is not None and vehicle is not None and vehicle not in self.vehicles:
            if vehicle in self.recipe_vehicles:
                raise OrderError(
                    oid, "vehicle", f"vehicle {vehicle} runs recipes, it takes no orders"
                )
            raise OrderError(oid, "vehicle", f"there is no vehicle {vehicle}")
        if oid in self._orders:
            raise OrderError(
                oid, "id", f"already used by an order that is {self._orders[oid].state}"
            )
        _check_time(order, now_s)
        self._orders[oid] = order
        order.position = self.added
        self._positions.add(self.added)
        self._at[self.added] = order
        self.added += 1
        self._counts[order.state.value] += 1
        order.history.append((now_s, OrderState.RAW))
        if withdrawn is None:
            self.transition(order, OrderState.DISPATCHABLE, now_s)
        else:
            self.transition(order, OrderState.WITHDRAWN, now_s, withdrawn)
        return order

    def withdraw(self, order_id: str, now_s: float, reason: str = "withdrawn") -> TransportOrder:
        """Withdraw an open order. A vehicle processing it sees the final state and stops;
        a final order cannot be withdrawn (OrderError)."""
        order = self.get(order_id)
        if order.state.final:
            raise OrderError(
                order.id, "state", f"the order is final ({order.state}) and cannot be withdrawn"
            )
        self.transition(order, OrderState.WITHDRAWN, now_s, reason)
        return order

    def get(self, order_id: str) -> TransportOrder:
        """The order with this id; OrderError if the book has none (a typed-in id is wrong)."""
        try:
            return self._orders[order_id]
        except (KeyError, TypeError):
            raise OrderError(order_id, "id", "no such order") from None

    def __contains__(self, order_id: object) -> bool:
        return isinstance(order_id, str) and order_id in self._orders

    def __iter__(self) -> Iterator[TransportOrder]:
        return iter(self._orders.values())

    def __len__(self) -> int:
        return len(self._orders)

    def page(self, offset: int, limit: int) -> list[TransportOrder]:
        """The first ``limit`` orders of the book at position ``offset`` or later, in the
        order added (fewer at the end; orders that have left the book are skipped). A slice
        after a bisection: it costs the orders it holds, not the offset, so a page deep in a
        long run's book costs a scan no more than the first one."""
        if offset < 0 or limit < 0:
            raise ValueError(f"a page needs offset >= 0 and limit >= 0, got {offset}, {limit}")
        first = self._positions.bisect_left(offset)
        return [self._at[p] for p in self._positions.islice(first, first + limit)]

    def sweep(self, now_s: float, budget: int) -> list[TransportOrder]:
        """Remove at most ``budget`` orders that have been final for ``keep_final_s`` by
        ``now_s``, oldest first, and return them (for totals kept beyond the book). Their
        ids can be used again; counts() still counts them."""
        out: list[TransportOrder] = []
        until = now_s - self.keep_final_s
        while self._final and len(out) < budget and self._final[0][0] <= until:
            _, oid = self._final.popleft()
            order = self._orders.pop(oid)
            self._positions.remove(order.position)
            del self._at[order.position]
            self.swept += 1
            out.append(order)
        return out

    def dispatchable(self) -> list[TransportOrder]:
        """Orders waiting for a vehicle: DISPATCHABLE and not assigned, in the order they
        became dispatchable. Costs the open orders, not the whole book."""
        return [o for o in self._dispatchable.values() if o.assigned is None]

    def open_count(self) -> int:
        """The orders not in a final state (waiting or being processed)."""
        return sum(n for state, n in self._counts.items() if not OrderState(state).final)

    def counts(self) -> dict[str, int]:
        """Orders per state, every state named (zeros included), for reports."""
        return dict(self._counts)

    def changed_since(self, revision: int, swept: bool = False) -> list[TransportOrder] | None:
        """The orders that changed state after ``revision`` (each once, in the order of their
        last change), or None if more changed than the journal remembers. Only orders in the
        book, unless ``swept``: then also those that have left it since (final, in the state
        a live view must still be told), each before a new order that took its id."""
        if revision >= self.revision:
            return []
        if self.revision - revision > len(self._changed):
            return None
        newest_first: dict[int, TransportOrder] = {}
        for rev, order in reversed(self._changed):
            if rev <= revision:
                break
            newest_first.setdefault(id(order), order)
        changed = reversed(newest_first.values())
        if swept:
            return list(changed)
        return [o for o in changed if self._orders.get(o.id) is o]

    # ----- the life cycle ------------------------------------------------------------------
    def transition(
        self, order: TransportOrder, state: OrderState, now_s: float, reason: str = ""
    ) -> None:
        """Move ``order`` to ``state`` at ``now_s`` if the life cycle allows it (else
        OrderError, nothing changed). ``reason`` is kept as the order's ``reason`` (why it
        failed, was withdrawn or taken back). Taking an order back to DISPATCHABLE frees it
        from its vehicle and forgets the sections it ran, as a new vehicle starts afresh."""
        self._check_member(order)
        if not isinstance(state, OrderState):
            raise OrderError(order.id, "state", f"{state!r} is not an order state")
        if state not in TRANSITIONS[order.state]:
            raise OrderError(order.id, "state", f"cannot go from {order.state} to {state}")
        _check_time(order, now_s)
        if state is OrderState.DISPATCHABLE and order.state is OrderState.BEING_PROCESSED:
            self.abandon_sections(order)
            order.assigned = None
        self._counts[order.state.value] -= 1
        self._counts[state.value] += 1
        order.state = state
        order.reason = reason
        self.revision += 1
        self._changed.append((self.revision, order))
        order.history.append((now_s, state))
        if len(order.history) > HISTORY_KEPT:
            # the oldest take-back: BEING_PROCESSED then DISPATCHABLE again (the only cycle
            # of the life cycle), so what is kept still follows the life cycle
            del order.history[2:4]
            order.history_dropped += 2
        if state is OrderState.DISPATCHABLE:
            self._dispatchable[order.id] = order
        else:
            self._dispatchable.pop(order.id, None)
        if state.final:
            self._final.append((now_s, order.id))

    # ----- sections ------------------------------------------------------------------------
    def start_section(self, order: TransportOrder, name: str, now_s: float) -> None:
        """Section ``name`` of a BEING_PROCESSED order starts at ``now_s``. Sections run in
        the seed's order, one at a time; any may be skipped (no queue, already in the zone)."""
        self._check_member(order)
        index = _section_index(order, name)
        if order.state is not OrderState.BEING_PROCESSED:
            raise OrderError(
                order.id, "sections", f"{name} cannot start: the order is {order.state}"
            )
        if name in order.sections:
            raise OrderError(order.id, "sections", f"{name} has already run")
        for other, times in order.sections.items():
            if SECTIONS.index(other) > index:
                raise OrderError(order.id, "sections", f"{name} cannot start after {other}")
            if len(times) == 1:
                raise OrderError(order.id, "sections", f"{name} starts while {other} still runs")
            if not now_s >= times[-1]:
                raise OrderError(
                    order.id,
                    "sections",
                    f"{name} cannot start at {now_s!r} s, before {other} ended",
                )
        _check_time(order, now_s)
        order.sections[name] = [now_s]

    def end_section(self, order: TransportOrder, name: str, now_s: float) -> None:
        """The running section ``name`` ends at ``now_s``."""
        self._check_member(order)
        _section_index(order, name)
        times = order.sections.get(name)
        if times is None or len(times) != 1:
            raise OrderError(order.id, "sections", f"{name} is not running")
        if not _is_number(now_s) or not times[0] <= now_s < math.inf:
            raise OrderError(
                order.id,
                "sections",
                f"{name} cannot end at {now_s!r} s (it started at {times[0]} s)",
            )
        times.append(now_s)

    def abandon_sections(self, order: TransportOrder) -> None:
        """Forget the sections of an order taken back from its vehicle. Only before loading:
        once the Get section started, the load is the vehicle's (OrderError)."""
        self._check_member(order)
        if any(SECTIONS.index(name) >= LOADING for name in order.sections):
            raise OrderError(order.id, "sections", "taken back after its load was picked up")
        order.sections.clear()

    def _check_member(self, order: TransportOrder) -> None:
        if self._orders.get(order.id) is not order:
            raise OrderError(order.id, "id", "not an order of this book")


def _check_time(order: TransportOrder, now_s: float) -> None:
    """Times of an order's history never go backwards: a time from another clock is a bug."""
    if not _is_number(now_s) or not math.isfinite(now_s):
        raise OrderError(order.id, "history", f"time {now_s!r} is not a finite number of seconds")
    if order.history and now_s < order.history[-1][0]:
        raise OrderError(
            order.id,
            "history",
            f"time {now_s} s is before its last transition at {order.history[-1][0]} s",
        )


def _section_index(order: TransportOrder, name: str) -> int:
    try:
        return SECTIONS.index(name)
    except ValueError:
        raise OrderError(
            order.id, "sections", f"unknown section {name!r} (one of {', '.join(SECTIONS)})"
        ) from None


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _check_int(oid: object, name: str, value: object, kind: str, low: int | None = None) -> None:
    """OrderError unless ``value`` is an int (not a bool), >= ``low`` if given, of at most
    MAX_DIGITS digits; worded as the order files word the same faults."""
    if not isinstance(value, int) or isinstance(value, bool) or (low is not None and value < low):
        raise OrderError(oid, name, f"{kind}, got {_brief(value)}")
    if abs(value) > MAX_INT:
        text = shown(str(value)) if abs(value) < 10**40 else _brief(value)
        raise OrderError(oid, name, f"{TOO_LONG}: {text}")


def _seconds(value: object) -> float | None:
    """``value`` as a float if it is a number (not a bool) a float can hold, else None:
    ``float(10**400)`` raises instead of answering."""
    if not _is_number(value):
        return None
    try:
        return float(value)  # type: ignore[arg-type]
    except OverflowError:
        return None


def _brief(value: object) -> str:
    """A value for a message, short: a 5000-digit number must not flood the terminal (nor
    raise, as ``repr`` of an integer over 4300 digits does)."""
    if isinstance(value, int) and abs(value) >= 10**40:
        return f"an integer of about 10^{int(math.log10(abs(value)))}"
    try:
        text = repr(value)
    except Exception:  # an object whose repr fails still gets its message
        return f"a {type(value).__name__}"
    return text if len(text) <= 40 else text[:32] + "..."


def _shown(value: object) -> str:
    """An id quoted for a message, whole if it could be a valid one, else shortened: a
    5000-character id must not flood the terminal."""
    if not isinstance(value, str):
        return _brief(value)
    text = repr(value)
    return text if len(text) <= MAX_ID_CHARS + 8 else text[: MAX_ID_CHARS // 2] + "...'"
