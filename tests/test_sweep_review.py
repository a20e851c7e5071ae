"""Orders that leave the book (``OrderBook.sweep``) while something still refers to them:
an allocation round that evaluated one, dhht's supply counts, the live feed, and the
summary's totals. Each run twice on the virtual clock, keeping final orders for no time
and for ever, must come out the same."""

from __future__ import annotations

import math
from types import SimpleNamespace

from test_orders_program import config, run, start

from blocks.dispatch.orders import OrderBook, OrderState, TransportOrder
from fleet.order_report import OrderTotals, order_summary
from fleet.report import summary
from fleet.web.feed import LiveFeed

S = OrderState
SUMMED = ("orders", "mean_order_time_s", "station_wait_s", "makespan_s", "station_utilisation")


def _round_with_a_withdrawal(keep_final_s: float, tmp_path, made, again: bool = False):
    """Three vehicles, four orders, a round of one evaluation a scan: the most urgent order
    is withdrawn while the round runs (and, with ``again``, its id is used by a new order
    once it has left the book). Returns the program once the round has ended."""
    cfg = config("id,get,put,start_s\n", tmp_path)
    cfg.orders.keep_final_s = keep_final_s
    cfg.dispatch.budget = 1
    p = start(cfg, made)
    run(p, 2)
    for k in range(4):
        p.orders.submit(TransportOrder(f"o{k}", 20 + k, 29 - k, priority=10 if k == 0 else 0))
    d = p.orders.dispatcher
    assert p.rt.run_until(lambda: d._round is not None, max_cycles=100)
    p.orders.withdraw("o0")
    run(p, 0.1)
    assert d._round is not None  # (the round is still being evaluated)
    if again:
        assert "o0" not in p.orders.book
        p.orders.submit(TransportOrder("o0", 26, 21))
        run(p, 0.05)
    assert p.rt.run_until(lambda: d._round is None, max_cycles=100)
    return p


def test_an_order_withdrawn_and_swept_while_a_round_runs_is_no_refusal(tmp_path, made):
    """A built-in strategy's round that gives out an order withdrawn meanwhile is not
    wrong: the withdrawn order is passed over whether it is still in the book or has left
    it, and the summary's dispatch counts are the same either way."""
    kept = _round_with_a_withdrawal(math.inf, tmp_path, made)
    run(kept, 60)
    kept_dispatch = summary(kept, 1.0)["dispatch"]
    kept.close()
    swept = _round_with_a_withdrawal(0.0, tmp_path, made)
    assert swept.orders.book.swept == 1
    assert swept.orders.dispatcher.refused == 0, swept.orders.dispatcher.refused_reason
    run(swept, 60)
    assert summary(swept, 1.0)["dispatch"] == kept_dispatch


def test_a_round_does_not_give_out_a_new_order_under_the_id_of_one_it_evaluated(tmp_path, made):
    """The round evaluated o0 (20 -> 29, priority 10); o0 is withdrawn and leaves the book,
    and a new order takes its id (26 -> 21, priority 0) before the round ends. The round's
    assignment of the old o0 is not an assignment of the new one: no round has weighed it."""
    p = _round_with_a_withdrawal(0.0, tmp_path, made, again=True)
    new = p.orders.book.get("o0")
    assert (new.get, new.put) == (26, 21)
    assert new.state is S.DISPATCHABLE and new.assigned is None, new.history
    assert p.orders.dispatcher.refused == 0


def _dhht_run(keep_final_s: float, tmp_path, made):
    """dhht with one vehicle: an order from each of two stations, then 60 orders at the
    first withdrawn as they come (no round sees them waiting: none wait), then one more
    at each station. dhht weighs a station by its supply, the orders it has had."""
    cfg = config("id,get,put,start_s\n", tmp_path, vehicles=((1, 0),))
    cfg.orders.keep_final_s = keep_final_s
    cfg.dispatch.strategy = "dhht"
    cfg.dispatch.capacity_per_h = 100_000.0  # (the supply, not the capacity, bounds it)
    p = start(cfg, made)
    run(p, 1)
    r = p.orders.runners[1]
    a, b = (29, 27), (21, 24)
    for name, (get, put) in (("a1", a), ("b1", b)):
        p.orders.submit(TransportOrder(name, get, put))
        run(p, 0.1)
        assert p.rt.run_until(lambda: r.active is None and r.next is None, max_cycles=20000)
    for k in range(60):
        p.orders.submit(TransportOrder(f"w{k}", *a))
        p.orders.withdraw(f"w{k}")
    run(p, 2)
    p.orders.submit(TransportOrder("a2", *a))
    p.orders.submit(TransportOrder("b2", *b))
    run(p, 0.2)
    first = r.active.id
    supply = dict(p.orders.dispatcher._supply)
    run(p, 300)
    return first, supply, summary(p, 1.0), p


def test_dhht_counts_the_supply_of_orders_that_left_the_book_before_a_round(tmp_path, made):
    first_kept, supply_kept, kept, p = _dhht_run(math.inf, tmp_path, made)
    p.close()
    first_swept, supply_swept, swept, _ = _dhht_run(0.0, tmp_path, made)
    assert supply_swept == supply_kept
    assert first_swept == first_kept
    for key in SUMMED:
        assert swept[key] == kept[key], key


def test_the_live_feed_tells_the_final_state_of_an_order_that_left_the_book(tmp_path, made):
    """The operator page learns an order's changes from the feed's snapshots: one that
    ended and left the book between two snapshots must still arrive in its final state,
    or the page shows it running for ever."""
    cfg = config("id,get,put,start_s\n", tmp_path, vehicles=((1, 0),))
    cfg.orders.keep_final_s = 0.0
    p = start(cfg, made)
    feed = LiveFeed(p)
    run(p, 1)
    p.orders.submit(TransportOrder("A", 20, 24))
    run(p, 1)
    seen = {o.id: o.state for o in feed._snapshot()["orders"]["changed"]}
    assert seen == {"A": S.BEING_PROCESSED}
    runner = p.orders.runners[1]
    assert p.rt.run_until(lambda: runner.active is None, max_cycles=20000)
    run(p, 0.1)
    assert "A" not in p.orders.book  # finished, and swept
    changed = feed._snapshot()["orders"]["changed"]
    assert [(o.id, o.state) for o in changed] == [("A", S.FINISHED)]


# finished orders (Get start, Put end) whose mean execution time, 102.8875 s, lies on a
# rounding boundary of the summary's three decimals: summed in another order, the float
# sum differs in its last bit, and the rounded mean with it
TIMES = [
    (10.05, 17.75),
    (6.3, 71.3),
    (14.35, 75.4),
    (15.95, 111.75),
    (12.3, 126.35),
    (3.15, 143.3),
    (1.05, 166.1),
    (3.5, 177.8),
]


def _finished_book() -> tuple[OrderBook, list[TransportOrder]]:
    book = OrderBook({20: "in", 21: "out"}, keep_final_s=0.0)
    orders = []
    for k, (get, put) in enumerate(TIMES):
        o = book.add(TransportOrder(f"o{k}", 20, 21), 0.0)
        book.transition(o, S.BEING_PROCESSED, get)
        book.start_section(o, "Get", get)
        book.end_section(o, "Get", get)
        book.start_section(o, "Put_Queue", get)
        book.end_section(o, "Put_Queue", put)
        book.start_section(o, "Put", put)
        book.end_section(o, "Put", put)
        book.transition(o, S.FINISHED, put)
        orders.append(o)
    return book, orders


def _system(book: OrderBook, swept: OrderTotals) -> SimpleNamespace:
    dispatcher = SimpleNamespace(
        strategy="two_stage",
        rounds=0,
        evaluations=0,
        assignments=0,
        reassigned=0,
        deviations=0,
        cut_off=0,
        refused=0,
        refused_reason=None,
    )
    return SimpleNamespace(
        book=book,
        swept=swept,
        intake=SimpleNamespace(pending={}),
        runners={},
        dispatcher=dispatcher,
        cfg=SimpleNamespace(plant=SimpleNamespace(with_role=lambda role: [])),
    )


def test_the_summarys_means_do_not_depend_on_which_orders_left_the_book():
    kept_book, _ = _finished_book()
    kept = order_summary(_system(kept_book, OrderTotals()))  # type: ignore[arg-type]
    swept_book, _ = _finished_book()
    totals = OrderTotals()
    swept_book.keep_final_s = 160.0
    totals.add(swept_book.sweep(300.0, 100))  # the first five ended 160 s ago or more
    assert len(swept_book) == 3
    swept = order_summary(_system(swept_book, totals))  # type: ignore[arg-type]
    for key in ("mean_order_time_s", "station_wait_s", "makespan_s"):
        assert swept[key] == kept[key], key
