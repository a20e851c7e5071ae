"""Final orders leave the book ``keep_final_s`` after they end (``OrderBook.sweep``), so a
controller that runs for months holds a bounded book: what is swept, when, at what cost a
scan, that positions and pages do not shift, and that a run's summary is the same whether
its orders were swept or kept."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_orders_program import WORKSHOP, config, run, start

from blocks.dispatch.orders import KEEP_FINAL_S, OrderBook, OrderError, OrderState, TransportOrder
from fleet import order_system
from fleet.config import parse_config
from fleet.report import summary
from fleet.web.desk import OrderDesk
from plc_runtime.errors import ConfigError

S = OrderState


def finish(book: OrderBook, order: TransportOrder, now_s: float) -> None:
    book.transition(order, S.BEING_PROCESSED, now_s)
    book.transition(order, S.FINISHED, now_s)


def test_only_orders_final_for_keep_final_s_leave_and_counts_stay_whole():
    book = OrderBook({20: "in", 21: "out"}, keep_final_s=100.0)
    orders = [book.add(TransportOrder(f"o{k}", 20, 21), 0.0) for k in range(5)]
    finish(book, orders[0], 10.0)
    book.withdraw("o1", 20.0)
    finish(book, orders[3], 30.0)
    assert book.sweep(109.9, 100) == []  # o0 has been final for 99.9 s
    assert book.sweep(110.0, 100) == [orders[0]]
    assert book.sweep(130.0, 100) == [orders[1], orders[3]]
    assert [o.id for o in book] == ["o2", "o4"] and len(book) == 2  # open ones never leave
    assert book.sweep(1e9, 100) == []
    assert (book.added, book.swept) == (5, 3)
    counts = book.counts()  # every order of the run, swept or not
    assert (counts["FINISHED"], counts["WITHDRAWN"], counts["DISPATCHABLE"]) == (2, 1, 2)
    with pytest.raises(OrderError, match="no such order"):
        book.get("o0")


def test_a_sweep_takes_at_most_its_budget_a_call_oldest_first():
    book = OrderBook({20: "in", 21: "out"}, keep_final_s=0.0)
    for k in range(10):
        book.withdraw(book.add(TransportOrder(f"o{k}", 20, 21), float(k)).id, float(k))
    assert [o.id for o in book.sweep(100.0, 4)] == ["o0", "o1", "o2", "o3"]
    assert [o.id for o in book.sweep(100.0, 4)] == ["o4", "o5", "o6", "o7"]
    assert [o.id for o in book.sweep(100.0, 4)] == ["o8", "o9"]


def test_positions_never_change_so_pages_do_not_shift_when_orders_leave():
    book = OrderBook({20: "in", 21: "out"}, keep_final_s=0.0)
    orders = [book.add(TransportOrder(f"o{k}", 20, 21), 0.0) for k in range(6)]
    for k in (0, 2, 3):
        finish(book, orders[k], 1.0)
    book.sweep(1.0, 100)
    assert [o.position for o in book] == [1, 4, 5]
    assert [o.id for o in book.page(0, 2)] == ["o1", "o4"]
    assert [o.id for o in book.page(2, 2)] == ["o4", "o5"]  # from position 2 on
    assert book.page(6, 5) == []
    late = book.add(TransportOrder("late", 21, 20), 2.0)
    assert late.position == 6 and [o.id for o in book.page(5, 9)] == ["o5", "late"]


# a step of the book's life: add an order, end the k-th open one, sweep with a budget, or
# let time pass
STEPS = st.one_of(
    st.tuples(st.just("add"), st.integers(0, 3)),
    st.tuples(st.just("end"), st.integers(0, 50)),
    st.tuples(st.just("sweep"), st.integers(0, 7)),
    st.tuples(st.just("wait"), st.integers(1, 30)),
)


@settings(max_examples=150, deadline=None)
@given(st.lists(STEPS, max_size=120), st.integers(0, 40), st.integers(1, 12))
def test_pages_are_the_books_orders_by_position_after_any_adds_and_sweeps(steps, offset, limit):
    """A model of the book (every order added, in order, less those swept) against its
    pages: the positions survive any mix of adds, ends and sweeps, ids used again
    included."""
    book = OrderBook({20: "in", 21: "out"}, keep_final_s=10.0)
    model: list[TransportOrder] = []  # in the book, by position
    now, made = 0.0, 0
    for kind, n in steps:
        if kind == "add":
            for _ in range(n):
                oid = f"o{made % 17}"  # an id used again once its order has left the book
                oid = f"n{made}" if oid in book else oid
                model.append(book.add(TransportOrder(oid, 20, 21, 0.0, math.inf), now))
                made += 1
        elif kind == "end":
            open_ = [o for o in model if not o.state.final]
            if open_:
                book.withdraw(open_[n % len(open_)].id, now)
        elif kind == "sweep":
            gone = book.sweep(now, n)
            assert len(gone) <= n
            model = [o for o in model if all(o is not g for g in gone)]
        else:
            now += n
        assert len(book) == len(model)
    expected = [o for o in model if o.position >= offset][:limit]
    assert book.page(offset, limit) == expected
    assert book.page(0, len(model)) == model


def test_an_id_can_be_used_again_only_once_its_order_has_left_the_book():
    book = OrderBook({20: "in", 21: "out"}, keep_final_s=60.0)
    old = book.add(TransportOrder("x", 20, 21), 0.0)
    finish(book, old, 5.0)
    with pytest.raises(OrderError, match="already used"):
        book.add(TransportOrder("x", 21, 20), 10.0)
    book.sweep(65.0, 10)
    new = book.add(TransportOrder("x", 21, 20), 66.0)
    assert book.get("x") is new and new.position == 1
    # the change journal still names the old order's id: it reads as the new order
    assert book.changed_since(0) == [new]


def test_a_bad_keep_time_is_refused():
    for bad in (-1.0, math.nan, "1", True):
        with pytest.raises(ValueError, match="keep_final_s"):
            OrderBook({20: "in", 21: "out"}, keep_final_s=bad)
    assert OrderBook({20: "in"}).keep_final_s == KEEP_FINAL_S


ORDERS = "id,get,put,start_s,end_s\n" + "".join(
    f"o{k},{20 + k % 10},{20 + (k * 3 + 1) % 10},{k * 20},{k * 20 + 900}\n" for k in range(24)
)


def _outcome(keep_final_s: float, tmp_path, made):
    cfg = config(ORDERS, tmp_path)
    cfg.orders.keep_final_s = keep_final_s
    p = start(cfg, made)
    book_sizes = []
    for _ in range(20):
        run(p, 60.0)
        book_sizes.append(len(p.orders.book))
    return summary(p, wall_s=1.0), book_sizes, p


def test_a_runs_summary_is_the_same_whether_its_orders_were_swept_or_kept(tmp_path, made):
    """The same run twice (the virtual clock makes it repeat exactly): keeping final orders
    60 s, the book shrinks as orders end, and every total of the summary is the one of the
    run that kept them all."""
    kept, kept_sizes, first = _outcome(KEEP_FINAL_S, tmp_path, made)
    first.close()  # one runtime at a time: the watchdog's timer signal is the process's
    swept, swept_sizes, p = _outcome(60.0, tmp_path, made)
    assert kept["orders"]["FINISHED"] == 24 and swept["orders"] == kept["orders"]
    assert swept["orders_swept"] == 24 and kept["orders_swept"] == 0
    assert len(p.orders.book) == 0 and kept_sizes[-1] == 24
    assert max(swept_sizes) < max(kept_sizes)
    for key in ("mean_order_time_s", "station_wait_s", "makespan_s", "station_utilisation"):
        assert swept[key] == kept[key], key
    assert swept["mean_order_time_s"] is not None and swept["station_utilisation"]


def test_the_sweep_costs_a_scan_its_budget_at_most(tmp_path, made, monkeypatch):
    monkeypatch.setattr(order_system, "SWEEP_BUDGET", 2)
    cfg = config("id,get,put\n" + "".join(f"w{k},20,21\n" for k in range(7)), tmp_path)
    cfg.orders.keep_final_s = 0.0
    p = start(cfg, made)
    run(p, 0.1)
    for k in range(7):
        p.orders.withdraw(f"w{k}")
    run(p, 0.05)  # the scan that withdraws them all
    left = []
    for _ in range(4):
        run(p, 0.05)
        left.append(len(p.orders.book))
    assert left == [5, 3, 1, 0]


def test_keep_final_s_in_the_file_and_its_errors(tmp_path):
    assert config("id,get,put\na,20,21\n", tmp_path).orders.keep_final_s == KEEP_FINAL_S
    base = f'[plant]\nfile = "{WORKSHOP}"\n[[vehicles]]\nid = 1\nstart = 0\n'
    only = parse_config(base + "[orders]\nkeep_final_s = 3600\n", "k.toml", tmp_path)
    assert only.orders.keep_final_s == 3600 and only.orders.file is None
    with pytest.raises(ConfigError, match=r"k.toml.*orders.keep_final_s"):
        parse_config(base + "[orders]\nkeep_final_s = -5\n", "k.toml", tmp_path)
    with pytest.raises(ConfigError, match="give orders.file"):
        parse_config(base + "[orders]\nlead_s = 5\n", "k.toml", tmp_path)


def test_the_apis_pages_skip_swept_orders_and_say_where_the_next_starts():
    """``GET /orders`` (the web desk's pages): a client that pages on from ``next_offset``
    reads every order still in the book once, whatever left the book meanwhile."""
    book = OrderBook({20: "in", 21: "out"}, keep_final_s=0.0)
    orders = [book.add(TransportOrder(f"o{k}", 20, 21), 0.0) for k in range(7)]
    desk = OrderDesk(SimpleNamespace(book=book))  # type: ignore[arg-type]

    def page(offset: int):
        asked = desk.ask_page(offset, 2)
        desk.answer()
        return asked.result(0)

    first = page(0)
    assert [o.id for o in first.orders] == ["o0", "o1"] and first.next_offset == 2
    for k in (0, 1, 2, 3):  # read already, and the next two, leave the book
        finish(book, orders[k], 1.0)
    book.sweep(1.0, 100)
    second = page(first.next_offset)
    assert [o.id for o in second.orders] == ["o4", "o5"] and second.next_offset == 6
    assert second.total == 3
    last = page(second.next_offset)
    assert [o.id for o in last.orders] == ["o6"] and last.next_offset == 7
    assert page(7).orders == () and page(7).next_offset == 7
    assert page(50).next_offset == 50  # nothing from there on: the client stops


def test_an_order_that_leaves_the_book_while_waiting_to_be_checked_again_is_passed_over(
    tmp_path, made, monkeypatch
):
    """A blockade makes the dispatcher check every waiting order's routes again, a budget's
    worth a scan; one withdrawn and swept meanwhile is skipped, not looked up (the scan
    would fault on the missing order)."""
    from blocks.dispatch import dispatcher as dispatcher_module

    monkeypatch.setattr(dispatcher_module, "ROUTE_BUDGET", 1)
    rows = "".join(f"w{k},{20 + k},{29 - k},5000\n" for k in range(6))
    cfg = config("id,get,put,start_s\n" + rows, tmp_path)
    cfg.orders.keep_final_s, cfg.orders.lead_s = 0.0, 1e6  # all known now, none startable
    cfg.dispatch.strategy = "dhht"
    p = start(cfg, made)
    run(p, 1.0)
    assert len(p.orders.book) == 6
    p.blockades.block(16, 17)  # every waiting order is checked again, one a scan
    run(p, 0.05)
    p.orders.withdraw("w5")  # the last one to be checked again
    run(p, 1.0)  # withdrawn, swept, and then its turn to be checked comes: passed over
    assert "w5" not in p.orders.book and p.orders.book.swept == 1


def test_the_dispatcher_forgets_orders_that_ended_without_their_put(tmp_path, made):
    """Where each order was taken is kept for the orders the vehicles hold only: those
    withdrawn while held do not stay in it for the rest of the run."""
    rows = "".join(f"w{k},{20 + k % 10},{29 - k % 10},{k * 5}\n" for k in range(12))
    p = start(config("id,get,put,start_s\n" + rows, tmp_path), made)
    withdrawn = set()
    for _ in range(60):
        run(p, 2.0)
        for runner in p.orders.runners.values():
            for order in (runner.active, runner.next):
                if order is not None and len(withdrawn) < 6 and order.id not in withdrawn:
                    p.orders.withdraw(order.id)
                    withdrawn.add(order.id)
    assert len(withdrawn) == 6
    d = p.orders.dispatcher
    held = {o.id for r in p.orders.runners.values() for o in (r.active, r.next) if o}
    assert set(d._origin) <= held and {oid for oid, _ in d._deviated} <= held
