"""Pages of the order book (``OrderBook.page``) and what they cost the web desk's per-scan
budget (fleet/web/desk.py): a page is a slice of the book in the order added, so a page
deep in a long run's book touches only the orders it holds, and the budget it is charged
is the orders it copies. The work is counted (orders walked over, orders copied), never
timed."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from blocks.dispatch.orders import OrderBook, OrderError, TransportOrder
from fleet.web import desk as desk_module
from fleet.web.desk import MAX_PAGE, OrderDesk, OrderView

ORDERS = 5_000


@pytest.fixture
def book() -> OrderBook:
    book = OrderBook({20: "in", 21: "out"})
    for k in range(ORDERS):
        book.add(TransportOrder(f"o{k}", 20, 21), float(k))
    return book


@pytest.fixture
def work(monkeypatch) -> dict[str, int]:
    """Orders walked over by iterating the book, and orders copied into views."""
    counted = {"walked": 0, "copied": 0}
    walk, view = OrderBook.__iter__, OrderView.of

    def counting_walk(self):
        for order in walk(self):
            counted["walked"] += 1
            yield order

    def counting_view(order):
        counted["copied"] += 1
        return view(order)

    monkeypatch.setattr(OrderBook, "__iter__", counting_walk)
    monkeypatch.setattr(desk_module.OrderView, "of", staticmethod(counting_view))
    return counted


def test_a_page_is_the_orders_in_the_order_added_and_a_refused_add_shifts_nothing(book):
    assert [o.id for o in book.page(0, 3)] == ["o0", "o1", "o2"]
    assert [o.id for o in book.page(ORDERS - 2, 10)] == [f"o{ORDERS - 2}", f"o{ORDERS - 1}"]
    assert book.page(ORDERS, 10) == [] and book.page(10**9, 1) == []
    with pytest.raises(OrderError):
        book.add(TransportOrder("o3", 20, 21), float(ORDERS))  # the id is taken
    book.add(TransportOrder("last", 21, 20), float(ORDERS))
    assert [o.id for o in book.page(ORDERS - 1, 5)] == [f"o{ORDERS - 1}", "last"]
    assert book.page(0, len(book)) == list(book)
    with pytest.raises(ValueError, match="offset >= 0"):
        book.page(-1, 1)


def test_pages_deep_in_the_book_cost_their_orders_not_their_offset(book, work):
    budget = 10
    desk = OrderDesk(SimpleNamespace(book=book), budget=budget)  # type: ignore[arg-type]
    deep = [desk.ask_page(ORDERS - 1 - k, 1) for k in range(4 * budget)]
    assert desk.answer() == budget  # one order each: the budget's worth of requests
    assert work["copied"] == budget
    assert work["walked"] <= work["copied"]  # not the 10 x 5,000 orders before the offsets
    assert [f.result(0).orders[0].id for f in deep[:budget]] == [
        f"o{ORDERS - 1 - k}" for k in range(budget)
    ]
    assert not any(f.done() for f in deep[budget:])


def test_a_page_is_charged_the_orders_it_copies_and_an_empty_one_costs_one(book, work):
    desk = OrderDesk(SimpleNamespace(book=book), budget=10)  # type: ignore[arg-type]
    full = [desk.ask_page(1000 * k, 4) for k in range(4)]  # 4 + 4 + 4 >= 10: three a tick
    assert desk.answer() == 3 and [f.done() for f in full] == [True, True, True, False]
    beyond = [desk.ask_page(ORDERS + k, MAX_PAGE) for k in range(12)]
    assert desk.answer() == 7  # the fourth page (4) and six empty ones (1 each)
    assert all(f.result(0).orders == () and f.result(0).total == ORDERS for f in beyond[:6])
    assert not beyond[6].done()
    assert work["copied"] == 16 and work["walked"] <= work["copied"]


@pytest.mark.parametrize(("offset", "limit"), [(-1, 1), (0, 0), (0, MAX_PAGE + 1), (10**10, 1)])
def test_a_page_out_of_range_is_refused_at_once_and_nothing_is_queued(book, offset, limit):
    desk = OrderDesk(SimpleNamespace(book=book))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="a page needs"):
        desk.ask_page(offset, limit)
    assert desk.waiting == 0
