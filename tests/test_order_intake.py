"""The order intake of the running fleet program (fleet/order_system.py): whatever is
submitted, the Future gets the answer and the scan goes on; a large order file is released a
bounded number of orders per scan, in its order, and a blockade over it is checked a bounded
number per scan; an order for a vehicle that runs recipes is refused; a configured order not
released yet can be withdrawn. The book keeps a copy of a submitted order in built-in
values (a subclass of str, int or float, or a change the caller makes afterwards, reaches no
block), and a request that raises, or was cancelled, is answered without faulting the
scan."""

from __future__ import annotations

import math

import pytest
from test_orders_program import config, run, start

from blocks.dispatch import dispatcher
from blocks.dispatch.order_file import OrderFileError, load_orders, write_orders
from blocks.dispatch.orders import OrderError, OrderState, TransportOrder, check_order
from fleet import order_system
from fleet.order_report import order_summary
from fleet.order_system import RELEASE_BUDGET
from fleet.web.models import OrderIn
from plc_runtime.errors import ConfigError

LATER = "id,get,put,start_s\nlater,20,25,70\n"  # released at 10 s (lead 60 s)
RECIPES = '[[recipes]]\nname = "drill-inspect"\nfunctions = [5, 6, 1]\n'
RECIPE_VEHICLE = '[[vehicles]]\nid = 1\nstart = 0\nrecipes = ["drill-inspect"]\n'


def released(book) -> int:
    return len(book) - book.counts()["WITHDRAWN"]


def ids(book) -> list[str]:
    return [o.id for o in book]


@pytest.mark.parametrize(
    ("bad", "field"),
    [
        (TransportOrder("x", get=20, put=21, start_s=10**400), "start_s"),
        (TransportOrder(["x"], get=20, put=21), "id"),
        (TransportOrder(10**5000, get=20, put=21), "id"),
        (TransportOrder("x", get=True, put=21), "get"),
        (TransportOrder("x", get=20, put="21"), "put"),
        (TransportOrder("x", get=20, put=21, start_s=math.nan), "start_s"),
        (TransportOrder("x", get=20, put=21, end_s=10**400), "end_s"),
        (TransportOrder("x", get=20, put=21, priority=10**19), "priority"),
        (TransportOrder("x", get=20, put=21, vehicle=[1]), "vehicle"),
        ({"id": "x", "get": 20, "put": 21}, "order"),
    ],
)
def test_whatever_is_submitted_the_future_gets_the_refusal_and_the_scan_goes_on(
    bad, field, tmp_path, made
):
    p = start(config(LATER, tmp_path), made)
    run(p, 0.1)
    refused = p.orders.submit(bad)
    withdrawn = p.orders.withdraw(["x"])
    good = p.orders.submit(TransportOrder("good", 20, 25))
    run(p, 0.1)  # asserts the controller still runs
    with pytest.raises(OrderError) as err:
        refused.result(0)
    assert err.value.field == field and "\n" not in str(err.value)
    with pytest.raises(OrderError, match="no such order"):
        withdrawn.result(0)
    assert good.result(0).id == "good" and ids(p.orders.book) == ["good"]


def test_a_large_order_file_is_released_a_budget_a_scan_in_its_order(tmp_path, made):
    n = 20_000
    stations = range(20, 30)
    rows = "".join(f"o{k},{stations[k % 10]},{stations[(k + 3) % 10]}\n" for k in range(n))
    p = start(config("id,get,put\n" + rows, tmp_path), made)  # all due at the first scan
    book, scans = p.orders.book, math.ceil(n / RELEASE_BUDGET)
    assert RELEASE_BUDGET < n
    for scan in range(scans + 2):
        before = released(book)
        run(p, p.cfg.cycle_time)  # one scan; asserts no fault
        assert released(book) - before <= RELEASE_BUDGET, scan
        assert book.counts()["RAW"] == 0, scan
        assert order_summary(p.orders)["orders_pending_release"] == n - len(book), scan
        if scan == 0:  # already due, not yet in the book: withdrawn, it is never released
            last = p.orders.withdraw(f"o{n - 1}")
    assert last.result(0).state is OrderState.WITHDRAWN
    first = 2 * RELEASE_BUDGET  # released in scans 0 and 1, before the withdrawal
    order = [f"o{k}" for k in range(first)] + [f"o{n - 1}"] + [f"o{k}" for k in range(first, n - 1)]
    assert len(book) == n and ids(book) == order
    assert all(o.state is not OrderState.RAW for o in book)
    assert book.counts()["WITHDRAWN"] == 1
    assert book.get(f"o{n - 1}").history[-1][1] is OrderState.WITHDRAWN


def test_a_configured_order_not_released_yet_can_be_withdrawn(tmp_path, made):
    p = start(config(LATER, tmp_path), made)
    run(p, 2)
    w = p.orders.withdraw("later")
    run(p, 0.1)
    order = w.result(0)
    now = order.history[0][0]
    assert (order.state, order.reason, order.history) == (
        OrderState.WITHDRAWN,
        "withdrawn",
        [(now, OrderState.RAW), (now, OrderState.WITHDRAWN)],
    )
    stored = p.orders.book.get("later")
    assert stored is not order and stored.history == order.history and 2.0 <= now < 10.0
    again = p.orders.withdraw("later")
    reuse = p.orders.submit(TransportOrder("later", 21, 25))
    run(p, 0.1)
    with pytest.raises(OrderError) as err:
        again.result(0)
    assert (err.value.field, err.value.problem) == (
        "state",
        "the order is final (WITHDRAWN) and cannot be withdrawn",
    )
    with pytest.raises(OrderError, match="already used by an order that is WITHDRAWN"):
        reuse.result(0)
    run(p, 80)  # well past its release at 10 s: never released, never taken
    assert ids(p.orders.book) == ["later"] and stored.state is OrderState.WITHDRAWN
    assert len(stored.history) == 2 and stored.assigned is None
    assert p.orders.book.counts()["WITHDRAWN"] == 1


def test_an_order_for_a_vehicle_that_runs_recipes_is_refused(tmp_path, made):
    extra = RECIPES + RECIPE_VEHICLE
    vehicles = ((2, 11), (3, 14))
    cfg = config("id,get,put,vehicle\nv1,20,25,1\n", tmp_path, vehicles, extra)
    assert cfg.order_vehicles == [2, 3]
    with pytest.raises(ConfigError, match="field 'vehicle': vehicle 1 runs recipes, it takes no"):
        start(cfg, made)
    p = start(config("id,get,put\n", tmp_path, vehicles, extra), made)
    refused = p.orders.submit(TransportOrder("x", 20, 25, vehicle=1))
    taken = p.orders.submit(TransportOrder("y", 20, 25, vehicle=2))
    run(p, 0.1)
    with pytest.raises(OrderError) as err:
        refused.result(0)
    assert (
        str(err.value) == "order 'x': field 'vehicle': vehicle 1 runs recipes, it takes no orders"
    )
    assert taken.result(0).vehicle == 2 and ids(p.orders.book) == ["y"]


def test_priority_is_bounded_alike_in_files_over_http_and_at_submit(tmp_path):
    """A priority a JSON file or HTTP takes can be written as CSV and read back; one over 18
    digits is refused everywhere with the same words."""
    big = 10**18 - 1
    order = TransportOrder("p", 20, 21, priority=-big)
    write_orders(tmp_path / "p.json", [order])
    (loaded,) = load_orders(tmp_path / "p.json")
    write_orders(tmp_path / "p.csv", [loaded])
    assert load_orders(tmp_path / "p.csv")[0].priority == -big
    (tmp_path / "too.csv").write_text(f"id,get,put,priority\np,20,21,{10**19}\n")
    with pytest.raises(OrderFileError) as in_file:
        load_orders(tmp_path / "too.csv")
    over_http = OrderIn.model_validate({"id": "p", "get": 20, "put": 21, "priority": 10**19})
    with pytest.raises(OrderError) as checked:
        check_order(over_http.order())
    words = "field 'priority': not an integer of at most 18 digits: '10000000000000000000'"
    assert str(in_file.value).endswith(words) and str(checked.value).endswith(words)


def test_a_blockade_over_a_large_backlog_is_checked_a_budget_a_scan_and_gives_out_nothing_cut(
    tmp_path, made, monkeypatch
):
    """Station 20 cut off (no way in) with 6,000 orders waiting, half of them to it: while
    their routes are not checked again, the rounds give none of those to the free vehicles;
    then they are checked ROUTE_BUDGET a scan (all at once stretched one scan by a second)
    and every order to or from station 20 is counted as cut off, and waits; once the
    segments reopen, they are given out again."""
    n = 6_000
    rows = "".join(f"o{k},{21 + k % 9},{20 if k % 2 else 21 + (k + 4) % 9}\n" for k in range(n))
    p = start(config("id,get,put\n" + rows, tmp_path), made)
    book = p.orders.book
    run(p, p.cfg.cycle_time * (n // RELEASE_BUDGET + 2))
    assert len(book) == n
    taken = [o.id for o in book if o.assigned is not None]
    withdrawn = [p.orders.withdraw(oid) for oid in taken]  # the vehicles are free again
    run(p, p.cfg.cycle_time)
    assert all(w.result(0).state is OrderState.WITHDRAWN for w in withdrawn)
    for a, b in sorted(p.cfg.plant.arc_index):
        if b == 20:
            p.blockades.block(a, b, both_ways=False)
    cut = {o.id for o in book if 20 in (o.get, o.put) and o.id not in taken}
    monkeypatch.setattr(dispatcher, "ROUTE_BUDGET", 0)  # not checked again for a while
    rounds = p.orders.dispatcher.rounds
    for scan in range(round(30 / p.cfg.cycle_time)):
        run(p, p.cfg.cycle_time)
        assert not {o.id for o in book if o.assigned is not None} & cut, scan
    assert p.orders.dispatcher.rounds >= rounds + 3  # rounds ran over the unchecked orders
    assert book.counts()["UNROUTABLE"] == 0
    budget = 100
    monkeypatch.setattr(dispatcher, "ROUTE_BUDGET", budget)
    counter = p.orders.dispatcher
    for scan in range(math.ceil(n / budget) + 2):
        before = counter.cut_off
        run(p, p.cfg.cycle_time)
        assert counter.cut_off - before <= budget, scan
    assert counter.cut_off == len(cut) and book.counts()["UNROUTABLE"] == 0
    assert all(o.state is OrderState.DISPATCHABLE for o in book if o.id in cut)
    for a, b in sorted(p.cfg.plant.arc_index):
        if b == 20:
            p.blockades.unblock(a, b, both_ways=False)
    run(p, 30)
    assert {o.id for o in book if o.assigned is not None} & cut
    assert counter.cut_off == 0


class HashFails(str):
    """A str whose hash raises: the book's dict would call it in the scan."""

    def __hash__(self) -> int:
        raise RuntimeError("hash")


class PrintableFails(str):
    def isprintable(self) -> bool:
        raise RuntimeError("isprintable")


class IntHashFails(int):
    def __hash__(self) -> int:
        raise RuntimeError("hash")


class Incomparable(float):
    """Passes check_order (it reads float(value)) but no block can compare it."""

    def _fails(self, other: object) -> bool:
        raise RuntimeError("compare")

    __lt__ = __le__ = __gt__ = __ge__ = _fails


class StateFails(TransportOrder):
    @property
    def state(self) -> OrderState:
        raise RuntimeError("state")

    @state.setter
    def state(self, value: OrderState) -> None:
        pass


class Unhashable:
    def __hash__(self) -> int:
        raise RuntimeError("hash")


@pytest.mark.parametrize(
    "order",
    [
        TransportOrder(HashFails("s1"), 20, 25),
        TransportOrder(PrintableFails("s2"), 20, 25),
        TransportOrder("s3", IntHashFails(20), 25),
        TransportOrder("s4", 20, 25, start_s=Incomparable(1.0)),
        TransportOrder("s5", 20, 25, end_s=Incomparable(900.0), priority=IntHashFails(2)),
        TransportOrder("s6", 20, 25, vehicle=IntHashFails(2)),
    ],
    ids=["id-hash", "id-isprintable", "get-hash", "start-compare", "end-priority", "vehicle"],
)
def test_a_subclass_of_a_builtin_is_stored_as_the_builtin_and_the_scan_goes_on(
    order, tmp_path, made
):
    p = start(config(LATER, tmp_path), made)
    taken = p.orders.submit(order)
    run(p, 30)  # released, dispatched and driven: the blocks hash and compare what is stored
    oid = str.__str__(order.id)
    stored = p.orders.book.get(oid)
    assert taken.result(0).id == oid
    for name in ("id", "get", "put", "start_s", "end_s", "priority", "vehicle"):
        assert type(getattr(stored, name)) in (str, int, float, type(None)), name


def test_an_order_whose_field_cannot_be_read_is_refused_naming_it(tmp_path, made):
    p = start(config(LATER, tmp_path), made)
    refused = p.orders.submit(StateFails("odd", 20, 25))
    good = p.orders.submit(TransportOrder("good", 20, 25))
    run(p, 0.1)
    with pytest.raises(OrderError) as err:
        refused.result(0)
    assert str(err.value) == "order 'odd': field 'state': cannot be read (RuntimeError)"
    assert good.result(0).id == "good" and ids(p.orders.book) == ["good"]


def test_a_withdrawal_of_an_odd_id_is_answered_and_the_scan_goes_on(tmp_path, made):
    p = start(config(LATER, tmp_path), made)
    p.orders.submit(TransportOrder("w1", 20, 25))
    run(p, 0.1)
    unhashable = p.orders.withdraw(Unhashable())
    subclass = p.orders.withdraw(HashFails("w1"))
    run(p, 0.1)
    with pytest.raises(OrderError, match="field 'id': no such order"):
        unhashable.result(0)
    assert subclass.result(0).state is OrderState.WITHDRAWN
    assert p.orders.book.get("w1").state is OrderState.WITHDRAWN


def test_the_caller_cannot_change_an_order_it_submitted(tmp_path, made):
    p = start(config(LATER, tmp_path), made)
    mine = TransportOrder("mine", 21, 23, start_s=1000.0)  # waits in the book a while
    taken = p.orders.submit(mine)
    mine.put = 99999  # before the scan took it in
    run(p, 0.1)
    answer = taken.result(0)
    mine.get, mine.start_s = 99998, math.nan
    answer.get = 99997  # the answer is a copy too
    answer.history.clear()
    run(p, 5)  # the dispatcher reads the stored order every round
    stored = p.orders.book.get("mine")
    assert stored is not mine and stored is not answer
    assert (stored.get, stored.put, stored.start_s) == (21, 23, 1000.0)
    assert [state for _, state in stored.history] == [OrderState.RAW, OrderState.DISPATCHABLE]


def test_a_request_that_raises_gets_its_error_and_the_next_one_is_taken(
    tmp_path, made, monkeypatch
):
    p = start(config(LATER, tmp_path), made)
    book = p.orders.book
    add = book.add

    def add_or_fail(order, now_s, withdrawn=None):
        if order.id == "fails":
            raise RuntimeError("a fault in the book")
        return add(order, now_s, withdrawn)

    monkeypatch.setattr(book, "add", add_or_fail)
    failing = p.orders.submit(TransportOrder("fails", 20, 25))
    good = p.orders.submit(TransportOrder("good", 20, 25))
    run(p, 0.1)
    with pytest.raises(RuntimeError, match="a fault in the book"):
        failing.result(0)
    assert good.result(0).id == "good" and ids(book) == ["good"]


def test_a_request_cancelled_before_the_scan_took_it_is_never_applied(tmp_path, made):
    p = start(config(LATER, tmp_path), made)
    given_up = p.orders.submit(TransportOrder("given-up", 20, 25))
    assert given_up.cancel()
    kept = p.orders.submit(TransportOrder("kept", 20, 25))
    run(p, 0.1)
    assert kept.result(0).id == "kept" and ids(p.orders.book) == ["kept"]
    assert not kept.cancel()  # decided: too late to cancel


def test_orders_from_outside_are_refused_while_the_book_holds_its_most_open_ones(
    tmp_path, made, monkeypatch
):
    """A client may add orders as fast as its rate lets it: past the open orders the book
    takes from outside (configured ones not released yet counted), the next is refused
    naming the book, and takes nothing; one finished or withdrawn makes room again. The
    run's own configured order is released all the same."""
    monkeypatch.setattr(order_system, "MAX_OPEN_ORDERS", 3)
    p = start(config(LATER, tmp_path), made)  # "later": configured, not released yet
    run(p, 0.1)
    first = [p.orders.submit(TransportOrder(f"o{k}", 20, 25)) for k in range(3)]
    run(p, 0.1)
    assert [f.result(0).id for f in first[:2]] == ["o0", "o1"]
    with pytest.raises(OrderError) as err:
        first[2].result(0)
    assert err.value.field == "book" and "3 orders are open already" in str(err.value)
    assert ids(p.orders.book) == ["o0", "o1"]
    withdrawn = p.orders.withdraw("o0")
    run(p, 0.1)
    assert withdrawn.result(0).state is OrderState.WITHDRAWN
    again = p.orders.submit(TransportOrder("o2", 20, 25))
    run(p, 0.1)
    assert again.result(0).id == "o2"
    run(p, 10)  # the configured order's release is never refused for it
    assert "later" in p.orders.book and p.orders.book.open_count() == 3
