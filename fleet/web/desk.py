"""The scan's side of the HTTP API: requests wait in a queue and are answered at the quiet
point, between two scans, in the scan thread.

Why there and not from the HTTP thread: the order book belongs to the scan. Its orders are
plain mutable objects (the history grows, sections start and end, an order taken back loses
its sections) that the program changes while its blocks run, and the book has no lock,
so any read from another thread could see an order half-way through a transition. A copy
published by the scan every cycle would cost every scan the whole book, asked for or not.
A request queue costs nothing while nobody asks, and a request is answered where nothing
changes the book: ``WebServer.write_outputs`` calls :meth:`OrderDesk.answer` at the end of
every scan, after its outputs are copied out and before the next scan's blocks run. The answers are copies (:class:`OrderView`),
so the HTTP thread never touches a live order.

Changes go the same way: an order to add or withdraw is taken from the queue at the quiet
point and handed to :class:`~fleet.order_system.OrderSystem` (``submit`` / ``withdraw``),
whose intake applies it in the next scan; the answer is copied in the scan thread the
moment the intake has decided. A request that nobody took yet can be cancelled (the HTTP
side gave up waiting: the controller is not scanning), and then it is never applied, so a
client that got an error knows that nothing changed.

The work per quiet point is bounded: requests are answered in arrival order until
``budget`` orders have been copied (at least one request per tick), the rest wait for the
next tick; a page of the list holds at most ``MAX_PAGE`` orders and costs only those,
whatever its offset (a page is a slice of the book, not a walk to the offset).
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass
from typing import NamedTuple

from blocks.dispatch.orders import OrderBook, OrderError, OrderState, TransportOrder

from ..order_system import OrderSystem

MAX_PAGE = 500  # orders in one page of the list
MAX_OFFSET = 10**9  # far beyond any book (the order files hold 100,000 orders at most)
SCAN_BUDGET = 500  # orders copied per quiet point (some 2 ms), over the requests answered


class ControllerStopped(RuntimeError):
    """The run ended before the request was answered."""


class OrderView(NamedTuple):
    """A copy of one order as the scan saw it: safe to read from any thread. Only what is
    immutable is shared (the history's tuples, the states, the numbers), so the copy costs
    a few microseconds inside the scan; a NamedTuple is the cheapest record to build."""

    id: str
    get: int
    put: int
    start_s: float
    end_s: float | None  # None: no deadline
    priority: int
    vehicle: int | None
    state: OrderState
    assigned: int | None
    reason: str
    history: tuple[tuple[float, OrderState], ...]
    sections: dict[str, tuple[float, ...]]
    position: int
    history_dropped: int

    @classmethod
    def of(cls, order: TransportOrder) -> OrderView:
        return cls(
            order.id,
            order.get,
            order.put,
            order.start_s,
            order.end_s if order.end_s != math.inf else None,
            order.priority,
            order.vehicle,
            order.state,
            order.assigned,
            order.reason,
            tuple(order.history),
            {name: tuple(times) for name, times in order.sections.items()},
            order.position,
            order.history_dropped,
        )


@dataclass(frozen=True)
class Page:
    """The book's orders from position ``offset`` on (positions count the orders added
    before, and never change, so pages stay stable when old orders leave the book), how
    many it holds in all, the position the next page starts at, and the orders ever added
    (the next order's position: a view of the newest orders pages from a little before it)."""

    total: int
    offset: int
    orders: tuple[OrderView, ...]
    next_offset: int
    added: int


class Desk:
    """Thread-safe requests from the HTTP side, answered by :meth:`answer` in the scan.

    ``_ask(work)`` queues ``work(future) -> cost``, run in the scan at the quiet point; it
    ends the ``concurrent.futures.Future`` it is given with an answer or an exception.
    ``Future.cancel()`` succeeds only while the scan has not taken the request, and a
    cancelled request is never applied."""

    def __init__(self, budget: int = SCAN_BUDGET) -> None:
        self._budget = budget
        self._queue: queue.SimpleQueue[tuple[Callable[[Future], int], Future]] = queue.SimpleQueue()
        self._handed_over: set[Future] = set()  # given to the OrderSystem, not answered yet
        self._lock = threading.Lock()  # guards _handed_over and _closed
        self._closed = False

    @property
    def waiting(self) -> int:
        """Requests queued for the next quiet point (some may have been given up)."""
        return self._queue.qsize()

    def _ask(self, work: Callable[[Future], int]) -> Future:
        done: Future = Future()
        with self._lock:
            if self._closed:
                done.set_exception(ControllerStopped("the run has ended"))
                return done
            self._queue.put((work, done))
        return done

    # ----- the scan side (the scan thread, at the quiet point) ----------------------------
    def answer(self) -> int:
        """Answer waiting requests within the budget; returns how many were taken."""
        if self._queue.empty():  # the usual tick: nobody asks
            return 0
        spent, taken = 0, 0
        while spent < self._budget or taken == 0:
            try:
                work, done = self._queue.get_nowait()
            except queue.Empty:
                break
            if not done.set_running_or_notify_cancel():
                continue  # the asker gave up before the scan took it: nothing is done
            taken += 1
            try:
                spent += work(done)
            except Exception as exc:  # a bug answers its request (HTTP 500), never faults the scan
                done.set_exception(exc)
        return taken

    def _hand_over(self, done: Future, decided: Future, copy: Callable[[object], object]) -> int:
        """Chain an answer decided later in this scan (``decided``) to ``done``, passing
        its result through ``copy`` (in the scan thread) the moment it is decided."""
        with self._lock:
            self._handed_over.add(done)

        def settle(f: Future) -> None:
            with self._lock:
                self._handed_over.discard(done)
            exc = f.exception()
            _settle(done, exc if exc is not None else copy(f.result()))

        decided.add_done_callback(settle)
        return 1

    def close(self) -> None:
        """The run ends: every request still waiting, or handed over and not decided,
        fails with ControllerStopped; later requests fail at once."""
        with self._lock:
            self._closed = True
            handed_over, self._handed_over = self._handed_over, set()
        for done in handed_over:
            _settle(done, ControllerStopped("the run ended before the order was decided"))
        while True:
            try:
                _, done = self._queue.get_nowait()
            except queue.Empty:
                return
            if done.set_running_or_notify_cancel():
                done.set_exception(ControllerStopped("the run has ended"))


class OrderDesk(Desk):
    """The order book's requests. Every ``ask_*`` method returns a Future that ends with an
    :class:`OrderView` or a :class:`Page`, or raises ``OrderError`` (the book refused) or
    :class:`ControllerStopped`."""

    def __init__(self, orders: OrderSystem, budget: int = SCAN_BUDGET) -> None:
        super().__init__(budget)
        self._orders = orders
        self._book: OrderBook = orders.book

    # ----- the HTTP side (any thread) -----------------------------------------------------
    def ask_page(self, offset: int, limit: int) -> Future:
        """Orders ``offset`` .. ``offset + limit - 1``. ValueError at once for an offset
        outside 0 .. MAX_OFFSET or a limit outside 1 .. MAX_PAGE: a page's work in the
        scan is bounded by MAX_PAGE orders."""
        if not (0 <= offset <= MAX_OFFSET and 1 <= limit <= MAX_PAGE):
            raise ValueError(
                f"a page needs 0 <= offset <= {MAX_OFFSET} and 1 <= limit <= {MAX_PAGE},"
                f" got offset {offset}, limit {limit}"
            )
        return self._ask(lambda done: self._page(done, offset, limit))

    def ask_order(self, order_id: str) -> Future:
        return self._ask(lambda done: self._show(done, order_id))

    def ask_add(self, order: TransportOrder) -> Future:
        return self._ask(lambda done: self._hand_over(done, self._orders.submit(order), _view))

    def ask_withdraw(self, order_id: str) -> Future:
        return self._ask(lambda done: self._hand_over(done, self._orders.withdraw(order_id), _view))

    # ----- the scan side ------------------------------------------------------------------
    def _page(self, done: Future, offset: int, limit: int) -> int:
        """The page is a slice of the book (``OrderBook.page``), so its work is the orders
        it copies whatever the offset, and that is what it costs the budget (an empty page
        beyond the end costs one, as any request)."""
        book = self._book.page(offset, limit)
        orders = tuple(OrderView.of(o) for o in book)
        after = book[-1].position + 1 if book else max(offset, self._book.added)
        done.set_result(Page(len(self._book), offset, orders, after, self._book.added))
        return max(1, len(orders))

    def _show(self, done: Future, order_id: str) -> int:
        try:
            done.set_result(OrderView.of(self._book.get(order_id)))
        except OrderError as exc:
            done.set_exception(exc)
        return 1


def _view(order: object) -> OrderView:
    return OrderView.of(order)  # type: ignore[arg-type]


def _settle(done: Future, outcome: object) -> None:
    """End ``done`` with a result or an exception, unless it has ended already."""
    try:
        if isinstance(outcome, BaseException):
            done.set_exception(outcome)
        else:
            done.set_result(outcome)
    except InvalidStateError:
        pass
