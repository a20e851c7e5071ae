"""UrgentOrders: the dispatchable orders, indexed so that a round takes the most urgent few.

An allocation round looks at the ``k`` most urgent waiting orders (highest priority, then
earliest latest-delivery, earliest start, id). Sorting or scanning the whole pool for them
costs every waiting order, and a released order file may hold 100,000: tens of
milliseconds in one scan. This index keeps them in heaps instead, updated with each state
change the book reports, so a round costs ``k`` plus what changed since the last one.

Heaps cannot delete, so an order that leaves the pool leaves its entry behind; an entry
counts only while its order is a member under the same generation (an order taken back
and dispatchable again is a new generation). Dead entries are dropped as they surface.
Orders leave mostly from the top (a round assigns the ones it was given), so few linger,
and never more than the transitions the orders' histories in the book record anyway.

An order no vehicle can drive now (a blockade cuts a station off) is *set aside*: out of
the heaps until the dispatcher restores it. Left in, every round would pass over it, and
enough of them at the top would keep a round from reaching the orders it could give out.

With ``startable_only`` (dhht, nearest_idle: they take only orders whose start time has
come) orders wait in a second heap by start time and move to the urgency heap once it has
come, each once, at most ``budget`` a scan (:meth:`advance`): a file whose 100,000 orders
share one start time makes them startable over some scans, as they were released.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterable

from .orders import OrderState, TransportOrder

Urgency = tuple[int, float, float, str]


def urgency(order: TransportOrder) -> Urgency:
    """Sort key of the pool: the most urgent first."""
    return (-order.priority, order.end_s, order.start_s, order.id)


class UrgentOrders:
    def __init__(self, startable_only: bool) -> None:
        self.startable_only = startable_only
        self._members: dict[str, int] = {}  # order id -> its generation in the pool
        self._generation = 0
        self._ready: list[tuple[Urgency, int, TransportOrder]] = []
        self._later: list[tuple[float, Urgency, int, TransportOrder]] = []
        self._now_s = float("-inf")  # the latest time the index was told
        self._aside: set[str] = set()  # waiting orders kept out of the heaps until restored

    def __len__(self) -> int:
        return len(self._members)

    def update(self, order: TransportOrder, now_s: float) -> None:
        """``order`` changed state at ``now_s``: in the pool while DISPATCHABLE, out of it
        otherwise."""
        self._now_s = max(self._now_s, now_s)
        if order.state is not OrderState.DISPATCHABLE:
            self._members.pop(order.id, None)
            self._aside.discard(order.id)
            return
        if order.id in self._members or order.id in self._aside:
            return
        self._generation += 1
        self._members[order.id] = self._generation
        self._push(order, self._generation)

    def rebuild(self, orders: Iterable[TransportOrder], now_s: float) -> None:
        """Start again from ``orders`` (every DISPATCHABLE order), when the book's journal
        no longer covers the changes since the last update."""
        self._members.clear()
        self._ready.clear()
        self._later.clear()
        self._aside.clear()
        for order in orders:
            self.update(order, now_s)

    def set_aside(self, order: TransportOrder) -> None:
        """Keep ``order`` out of the pool until :meth:`restore` (its entry dies)."""
        self._aside.add(order.id)
        self._members.pop(order.id, None)

    def restore(self, order: TransportOrder, now_s: float) -> None:
        """Take an order set aside back into the pool (if it still waits)."""
        self._aside.discard(order.id)
        self.update(order, now_s)

    def advance(self, now_s: float, budget: int) -> bool:
        """Make orders whose start time has come by ``now_s`` startable, at most ``budget``
        of them. True if none is left waiting for a later call."""
        self._now_s = max(self._now_s, now_s)
        moved = 0
        while self._later and self._later[0][0] <= self._now_s:
            if moved == budget:
                return False
            _, key, generation, order = heapq.heappop(self._later)
            if self._live(order, generation):
                heapq.heappush(self._ready, (key, generation, order))
                moved += 1
        return True

    def most_urgent(
        self,
        k: int,
        accept: Callable[[TransportOrder], bool] | None = None,
        passed_limit: int = 0,
    ) -> list[TransportOrder]:
        """The ``k`` most urgent orders in the pool not assigned to a vehicle, most urgent
        first (only those made startable, if so built). With ``accept``, the orders it
        refuses are passed over, up to ``passed_limit`` of them (a look bounded however
        many are refused), so that more urgent orders that cannot be given out now do
        not take the places of those that can."""
        taken: list[tuple[Urgency, int, TransportOrder]] = []
        out: list[TransportOrder] = []
        passed = 0
        while self._ready and len(out) < k:
            entry = heapq.heappop(self._ready)
            if not self._live(entry[2], entry[1]):
                continue  # (it left the pool: its entry goes)
            taken.append(entry)
            if entry[2].assigned is not None:
                continue
            if accept is None or accept(entry[2]):
                out.append(entry[2])
            else:
                passed += 1
                if passed > passed_limit:
                    break
        for entry in taken:
            heapq.heappush(self._ready, entry)
        return out

    def _live(self, order: TransportOrder, generation: int) -> bool:
        return self._members.get(order.id) == generation

    def _push(self, order: TransportOrder, generation: int) -> None:
        key = urgency(order)
        if self.startable_only and order.start_s > self._now_s:
            heapq.heappush(self._later, (order.start_s, key, generation, order))
        else:
            heapq.heappush(self._ready, (key, generation, order))
