"""The order model and the order book: openTCS's life cycle, time-stamped; every bad order
refused with a message naming the order and the field, and the book left as it was."""

import math
import re
from pathlib import Path

import pytest

from blocks.dispatch.orders import (
    FINAL_STATES,
    HISTORY_KEPT,
    SECTIONS,
    OrderBook,
    OrderError,
    OrderState,
    TransportOrder,
)

S = OrderState
STATIONS = {10: "receiving-1", 11: "receiving-2", 20: "hrl-1", 21: "hrl-2"}

# the life cycle as the brief and docs/orders.md state it, written out independently of the
# module's table so a wrong table fails here
ALLOWED = {
    (S.RAW, S.DISPATCHABLE),
    (S.RAW, S.UNROUTABLE),
    (S.RAW, S.WITHDRAWN),
    (S.DISPATCHABLE, S.BEING_PROCESSED),
    (S.DISPATCHABLE, S.UNROUTABLE),
    (S.DISPATCHABLE, S.WITHDRAWN),
    (S.DISPATCHABLE, S.FAILED),
    (S.BEING_PROCESSED, S.FINISHED),
    (S.BEING_PROCESSED, S.FAILED),
    (S.BEING_PROCESSED, S.WITHDRAWN),
    (S.BEING_PROCESSED, S.DISPATCHABLE),
}


def test_the_documented_life_cycle_is_the_real_one():
    page = (Path(__file__).parent.parent / "docs" / "orders.md").read_text(encoding="utf-8")
    table = page[page.index("## Life cycle") : page.index("### Sections")]
    documented = {
        (S(src), S(dst.strip()))
        for src, dsts in re.findall(r"^\| ([A-Z_]+) \| ([A-Z_, ]+) \|", table, re.M)
        for dst in dsts.split(",")
    }
    assert documented == ALLOWED


def book(vehicles=None) -> OrderBook:
    return OrderBook(STATIONS, vehicles=vehicles)


def order(oid="o1", get=10, put=20, **kw) -> TransportOrder:
    return TransportOrder(oid, get, put, **kw)


def processing(b: OrderBook, oid="o1", now=0.0) -> TransportOrder:
    o = b.add(order(oid), now)
    o.assigned = 3
    b.transition(o, S.BEING_PROCESSED, now + 1)
    return o


def snapshot(b: OrderBook):
    """Everything an add or a transition could change, to compare before and after."""
    return [
        (o.id, o.state, list(o.history), {k: list(v) for k, v in o.sections.items()}, o.assigned)
        for o in b
    ]


# ----- the model ---------------------------------------------------------------------------
def test_states_are_the_opentcs_names_and_the_final_ones_are_final():
    assert [s.value for s in S] == [
        "RAW",
        "DISPATCHABLE",
        "BEING_PROCESSED",
        "FINISHED",
        "FAILED",
        "WITHDRAWN",
        "UNROUTABLE",
    ]
    assert (
        {s for s in S if s.final}
        == FINAL_STATES
        == {
            S.FINISHED,
            S.FAILED,
            S.WITHDRAWN,
            S.UNROUTABLE,
        }
    )
    assert f"{S.BEING_PROCESSED}" == "BEING_PROCESSED"  # messages and CSV show the name
    assert SECTIONS == (
        "Go_To_Cluster",
        "Go_To_Get",
        "Get_Queue",
        "Get",
        "Go_To_Put",
        "Put_Queue",
        "Put",
    )


def test_defaults_are_no_deadline_no_priority_no_intended_vehicle():
    o = order()
    assert (o.start_s, o.end_s, o.priority, o.vehicle) == (0.0, math.inf, 0, None)
    assert (o.state, o.history, o.sections, o.assigned, o.reason) == (S.RAW, [], {}, None, "")
    assert o.created_s is None and o.finished_s is None


# ----- adding ------------------------------------------------------------------------------
def test_an_added_order_is_dispatchable_at_once_with_both_steps_time_stamped():
    b = book()
    o = b.add(order(start_s=30.0, end_s=900.0), 12.5)
    assert o.state is S.DISPATCHABLE
    assert o.history == [(12.5, S.RAW), (12.5, S.DISPATCHABLE)]
    assert o.created_s == 12.5 and o.finished_s is None
    assert b.get("o1") is o and "o1" in b and "o2" not in b and ["o1"] not in b
    assert list(b) == [o] and len(b) == 1
    assert b.dispatchable() == [o]


def test_a_whole_life_is_time_stamped_and_counted():
    b = book()
    o = processing(b)
    b.start_section(o, "Go_To_Get", 2.0)  # already in the cluster zone: Go_To_Cluster skipped
    b.end_section(o, "Go_To_Get", 5.0)
    b.start_section(o, "Get", 5.0)
    b.end_section(o, "Get", 15.0)
    b.start_section(o, "Go_To_Put", 15.0)
    b.end_section(o, "Go_To_Put", 40.0)
    b.start_section(o, "Put", 40.0)
    b.end_section(o, "Put", 50.0)
    b.transition(o, S.FINISHED, 50.0)
    assert o.history == [
        (0.0, S.RAW),
        (0.0, S.DISPATCHABLE),
        (1.0, S.BEING_PROCESSED),
        (50.0, S.FINISHED),
    ]
    assert o.sections == {
        "Go_To_Get": [2.0, 5.0],
        "Get": [5.0, 15.0],
        "Go_To_Put": [15.0, 40.0],
        "Put": [40.0, 50.0],
    }
    assert o.finished_s == 50.0 and o.assigned == 3
    assert b.counts() == {
        "RAW": 0,
        "DISPATCHABLE": 0,
        "BEING_PROCESSED": 0,
        "FINISHED": 1,
        "FAILED": 0,
        "WITHDRAWN": 0,
        "UNROUTABLE": 0,
    }


def test_counts_name_every_state_and_dispatchable_skips_assigned_ones():
    b = book()
    a, c = b.add(order("a"), 0.0), b.add(order("c"), 0.0)
    processing(b, "p")
    c.assigned = 2  # a dispatcher's tentative choice: not offered to others
    assert b.dispatchable() == [a]
    assert b.counts() == dict.fromkeys(s.value for s in S) | {
        "RAW": 0,
        "DISPATCHABLE": 2,
        "BEING_PROCESSED": 1,
        "FINISHED": 0,
        "FAILED": 0,
        "WITHDRAWN": 0,
        "UNROUTABLE": 0,
    }


BAD = [
    # (order, vehicles of the book, field, words of the message)
    (order(get=99), None, "get", "node 99 is not a Get/Put station"),
    (order(put=98), None, "put", "node 98 is not a Get/Put station"),
    (order(get=20, put=20), None, "put", "is the Get station"),
    (order(start_s=100.0, end_s=50.0), None, "end_s", "before the start"),
    (order(start_s=math.nan), None, "start_s", "finite number"),
    (order(start_s=math.inf), None, "start_s", "finite number"),
    (order(start_s=-1.0), None, "start_s", ">= 0"),
    (order(end_s=math.nan), None, "end_s", "number of seconds"),
    (order(end_s="600"), None, "end_s", "number of seconds"),
    (order(start_s=True), None, "start_s", "finite number"),
    (order(priority=1.5), None, "priority", "must be an integer"),
    (order(priority="2"), None, "priority", "must be an integer"),
    (order(priority=True), None, "priority", "must be an integer"),
    (order(vehicle=7), {1, 2, 3}, "vehicle", "there is no vehicle 7"),
    (order(vehicle="1"), {1, 2, 3}, "vehicle", "must be a vehicle id"),
    (order(get=True), None, "get", "must be a station node id"),
    (order(get=-10), None, "get", "must be a station node id"),
    (order(get="10"), None, "get", "must be a station node id"),
    (order(oid=""), None, "id", "non-empty string"),
    (order(oid=7), None, "id", "non-empty string"),
    (order(oid="x" * 65), None, "id", "longer than 64"),
    (order(oid="a\nb"), None, "id", "control characters"),
    (order(oid=" o9"), None, "id", "leading/trailing spaces"),
    (order(state=S.FINISHED), None, "state", "must be RAW"),
    (order(history=[(0.0, S.RAW)]), None, "state", "must be RAW"),
    (order(assigned=0), None, "state", "must be RAW"),
    # whatever a field holds, the answer is an OrderError naming it (no OverflowError,
    # no TypeError), and an integer has at most the 18 digits an order file can hold
    (order(oid=["x"]), None, "id", "non-empty string"),
    (order(start_s=10**400), None, "start_s", "got an integer of about 10^400"),
    (order(end_s=10**400), None, "end_s", "number of seconds"),
    (order(end_s=-(10**400)), None, "end_s", "number of seconds"),
    (order(start_s=[0]), None, "start_s", "finite number"),
    (order(get=1.5), None, "get", "must be a station node id"),
    (order(get=10**19), None, "get", "not an integer of at most 18 digits: '10000000000000000000'"),
    (order(put=None), None, "put", "must be a station node id"),
    (order(priority=10**19), None, "priority", "not an integer of at most 18 digits"),
    (order(priority=-(10**19)), None, "priority", "not an integer of at most 18 digits"),
    (order(priority=10**5000), None, "priority", "at most 18 digits: an integer of about 10^5000"),
    (order(priority=None), None, "priority", "must be an integer"),
    (order(vehicle=True), {1, 2, 3}, "vehicle", "must be a vehicle id"),
    (order(vehicle=10**19), None, "vehicle", "not an integer of at most 18 digits"),
    (order(state="RAW"), None, "state", "must be RAW"),
]


@pytest.mark.parametrize(("bad", "vehicles", "field", "words"), BAD)
def test_a_bad_order_is_named_and_changes_nothing(bad, vehicles, field, words):
    b = book(vehicles)
    b.add(order("o0"), 0.0)
    processing(b, "p0")
    before, own = snapshot(b), (bad.state, list(bad.history))
    with pytest.raises(OrderError) as err:
        b.add(bad, 5.0)
    assert err.value.field == field
    message = str(err.value)
    assert message.startswith(f"order {bad.id!r}: field '{field}': ") and words in message
    assert "\n" not in message
    assert snapshot(b) == before
    if isinstance(bad.id, str) and bad.id:
        assert bad.id not in b
    assert (bad.state, bad.history) == own


def test_the_largest_integers_an_order_file_holds_are_taken():
    big = 10**18 - 1
    b = book({1, big})
    added = b.add(order(priority=big, vehicle=big), 0.0)
    assert (added.priority, b.add(order("o2", priority=-big), 0.0).priority) == (big, -big)


@pytest.mark.parametrize("bad", [None, "o1", {"id": "o1", "get": 10, "put": 20}])
def test_what_is_no_order_at_all_is_an_order_error(bad):
    b = book()
    with pytest.raises(OrderError, match="field 'order': must be a TransportOrder, got"):
        b.add(bad, 0.0)
    assert len(b) == 0


def test_a_huge_id_is_named_without_flooding_or_raising():
    with pytest.raises(OrderError) as err:
        book().add(order(oid=10**5000), 0.0)
    assert str(err.value) == (
        "order an integer of about 10^5000: field 'id': must be a non-empty string"
    )


@pytest.mark.parametrize("oid", ['=HYPERLINK("http://x/")', "+1", "-2+3", "@SUM(A1)"])
def test_an_id_a_spreadsheet_would_take_for_a_formula_is_refused(oid):
    """The id is the first cell of the run's orders.csv, which operators open in a
    spreadsheet; one of these would run there as a formula."""
    b = book()
    with pytest.raises(OrderError) as err:
        b.add(order(oid), 0.0)
    assert err.value.field == "id" and "a spreadsheet takes for a formula" in str(err.value)
    assert len(b) == 0
    assert b.add(order("a=b+c"), 0.0).id == "a=b+c"  # inside an id they are plain text


def test_an_order_for_a_vehicle_that_runs_recipes_is_refused_saying_so():
    b = OrderBook(STATIONS, vehicles={2, 3}, recipe_vehicles={1})
    with pytest.raises(OrderError) as err:
        b.add(order(vehicle=1), 0.0)
    assert (err.value.field, str(err.value)) == (
        "vehicle",
        "order 'o1': field 'vehicle': vehicle 1 runs recipes, it takes no orders",
    )
    with pytest.raises(OrderError, match="there is no vehicle 4"):
        b.add(order(vehicle=4), 0.0)
    assert len(b) == 0 and b.add(order(vehicle=2), 0.0).vehicle == 2


def test_an_order_withdrawn_before_it_was_released_goes_in_withdrawn():
    b = book()
    o = b.add(order("w"), 7.0, withdrawn="withdrawn")
    assert (o.state, o.reason, o.history) == (
        S.WITHDRAWN,
        "withdrawn",
        [(7.0, S.RAW), (7.0, S.WITHDRAWN)],
    )
    assert b.dispatchable() == [] and b.counts()["WITHDRAWN"] == 1 and "w" in b
    with pytest.raises(OrderError, match="already used by an order that is WITHDRAWN"):
        b.add(order("w"), 8.0)
    with pytest.raises(OrderError, match="the order is final"):
        b.withdraw("w", 8.0)


def test_duplicate_ids_are_refused_also_against_final_orders():
    b = book()
    done = processing(b, "o1")
    b.transition(done, S.FINISHED, 9.0)
    before = snapshot(b)
    again = order("o1", get=11, put=21)
    with pytest.raises(OrderError, match=r"order 'o1': field 'id': already used .* FINISHED"):
        b.add(again, 10.0)
    assert snapshot(b) == before and again.history == []


def test_intended_vehicles_are_checked_only_when_the_book_knows_the_fleet():
    assert book().add(order(vehicle=42), 0.0).vehicle == 42
    assert book({1, 42}).add(order(vehicle=42), 0.0).vehicle == 42


def test_an_endless_window_and_an_instant_one_are_valid():
    b = book()
    assert b.add(order("a", end_s=math.inf), 0.0).end_s == math.inf
    assert b.add(order("b", start_s=60.0, end_s=60.0), 0.0).end_s == 60.0


def test_long_ids_are_shortened_in_messages():
    with pytest.raises(OrderError) as err:
        book().add(order(oid="y" * 5000), 0.0)
    assert len(str(err.value)) < 120


# ----- the life cycle ----------------------------------------------------------------------
def reach(b: OrderBook, state: OrderState) -> TransportOrder:
    """A fresh order of ``b`` in ``state`` by allowed steps (a RAW one is made by hand)."""
    oid = f"o{len(b)}"
    if state is S.RAW:
        o = order(oid)
        b._orders[oid] = o  # RAW lasts no time in add(); here it is held to test its arrows
        o.history.append((0.0, S.RAW))
        return o
    o = b.add(order(oid), 0.0)
    if state in (S.BEING_PROCESSED, S.FINISHED):
        b.transition(o, S.BEING_PROCESSED, 1.0)
    if state is not o.state:
        b.transition(o, state, 2.0)
    return o


@pytest.mark.parametrize("src", list(S), ids=str)
@pytest.mark.parametrize("dst", list(S), ids=str)
def test_exactly_the_allowed_transitions_happen(src, dst):
    b = book()
    o = reach(b, src)
    assert o.state is src
    before = snapshot(b)
    if (src, dst) in ALLOWED:
        b.transition(o, dst, 3.0, "because")
        assert o.state is dst and o.history[-1] == (3.0, dst) and o.reason == "because"
    else:
        with pytest.raises(OrderError, match=f"field 'state': cannot go from {src} to {dst}"):
            b.transition(o, dst, 3.0)
        assert snapshot(b) == before


def test_an_order_taken_back_again_and_again_keeps_its_release_and_newest_history():
    """Two-stage allocation may take a next order back at every recompute: its history
    stays at HISTORY_KEPT entries at most, the release and the newest transitions, in the
    life cycle's order, and counts those it dropped; the book's counts and the order's times
    are those of every transition."""
    b = book()
    o = processing(b)  # RAW and DISPATCHABLE at 0 s, BEING_PROCESSED at 1 s
    for k in range(1, 101):
        b.transition(o, S.DISPATCHABLE, 10.0 * k, "recomputed")
        o.assigned = 3
        b.transition(o, S.BEING_PROCESSED, 10.0 * k + 5)
    b.transition(o, S.FINISHED, 2000.0)
    # 1 + 2 * 101 + 1 transitions: the oldest take-backs dropped in pairs, and counted
    assert len(o.history) == HISTORY_KEPT and o.history_dropped == 204 - HISTORY_KEPT
    assert o.history[:2] == [(0.0, S.RAW), (0.0, S.DISPATCHABLE)]
    assert o.history[-3:] == [
        (1000.0, S.DISPATCHABLE),
        (1005.0, S.BEING_PROCESSED),
        (2000.0, S.FINISHED),
    ]
    states = [state for _, state in o.history]
    assert all(pair in ALLOWED for pair in zip(states, states[1:], strict=False))
    times = [t for t, _ in o.history]
    assert times == sorted(times)
    assert (o.created_s, o.finished_s) == (0.0, 2000.0)
    assert b.counts()["FINISHED"] == 1 and b.counts()["BEING_PROCESSED"] == 0


def test_taking_an_order_back_frees_it_and_forgets_its_sections():
    b = book()
    o = processing(b)
    b.start_section(o, "Go_To_Cluster", 1.0)
    b.end_section(o, "Go_To_Cluster", 4.0)
    b.start_section(o, "Go_To_Get", 4.0)
    b.transition(o, S.DISPATCHABLE, 6.0, "reassigned")
    assert (o.state, o.assigned, o.sections, o.reason) == (S.DISPATCHABLE, None, {}, "reassigned")
    assert o.history[-2:] == [(1.0, S.BEING_PROCESSED), (6.0, S.DISPATCHABLE)]
    assert b.dispatchable() == [o]
    o.assigned = 5  # another vehicle takes it and runs its sections afresh
    b.transition(o, S.BEING_PROCESSED, 7.0)
    b.start_section(o, "Go_To_Cluster", 7.0)
    assert o.sections == {"Go_To_Cluster": [7.0]} and o.reason == ""


@pytest.mark.parametrize("started", ["Get", "Go_To_Put", "Put"])
def test_an_order_is_not_taken_back_once_its_load_is_being_picked_up(started):
    b = book()
    o = processing(b)
    for name in SECTIONS[: SECTIONS.index(started) + 1]:
        b.start_section(o, name, 2.0)
        if name != started:
            b.end_section(o, name, 2.0)
    before = snapshot(b)
    with pytest.raises(OrderError, match="field 'sections': taken back after its load"):
        b.transition(o, S.DISPATCHABLE, 3.0)
    with pytest.raises(OrderError, match="taken back after its load"):
        b.abandon_sections(o)
    assert snapshot(b) == before


def test_withdraw_open_orders_and_refuse_final_and_unknown_ones():
    b = book()
    waiting = b.add(order("w"), 0.0)
    running = processing(b, "r")
    assert b.withdraw("w", 5.0) is waiting
    assert waiting.state is S.WITHDRAWN and waiting.reason == "withdrawn"
    assert waiting.finished_s == 5.0
    b.withdraw("r", 6.0, reason="customer cancelled")
    assert (running.state, running.reason, running.assigned) == (
        S.WITHDRAWN,
        "customer cancelled",
        3,  # the executor still knows whose it was
    )
    before = snapshot(b)
    with pytest.raises(
        OrderError, match=r"field 'state': the order is final \(WITHDRAWN\) and cannot be withdrawn"
    ):
        b.withdraw("w", 7.0)
    with pytest.raises(OrderError, match="order 'nope': field 'id': no such order"):
        b.withdraw("nope", 7.0)
    with pytest.raises(OrderError, match="no such order"):
        b.get(["unhashable"])
    assert snapshot(b) == before


def test_times_never_go_backwards_and_must_be_finite():
    b = book()
    o = processing(b, now=10.0)
    before = snapshot(b)
    with pytest.raises(OrderError, match=r"field 'history': time 5.0 s is before .* 11.0 s"):
        b.transition(o, S.FINISHED, 5.0)
    for bad in (math.nan, math.inf, None):
        with pytest.raises(OrderError, match="field 'history'"):
            b.transition(o, S.FINISHED, bad)
        with pytest.raises(OrderError, match="field 'history'"):
            b.add(order(f"n{bad}"), bad)
    assert snapshot(b) == before


def test_only_the_books_own_orders_and_real_states_move():
    b, other = book(), book()
    stranger = other.add(order("o1"), 0.0)
    b.add(order("o1"), 0.0)  # same id, another object
    with pytest.raises(OrderError, match="not an order of this book"):
        b.transition(stranger, S.BEING_PROCESSED, 1.0)
    with pytest.raises(OrderError, match="not an order of this book"):
        b.start_section(stranger, "Get", 1.0)
    with pytest.raises(OrderError, match="'FINISHED' is not an order state"):
        b.transition(b.get("o1"), "FINISHED", 1.0)
    assert stranger.state is S.DISPATCHABLE and b.get("o1").state is S.DISPATCHABLE


# ----- sections ----------------------------------------------------------------------------
def test_sections_run_in_the_seeds_order_one_at_a_time():
    b = book()
    o = processing(b)
    b.start_section(o, "Go_To_Cluster", 1.0)
    before = snapshot(b)
    cases = [
        (lambda: b.start_section(o, "Go_To_Get", 2.0), "Go_To_Get starts while Go_To_Cluster"),
        (lambda: b.start_section(o, "Go_To_Cluster", 2.0), "Go_To_Cluster has already run"),
        (lambda: b.start_section(o, "Loading", 2.0), "unknown section 'Loading'"),
        (lambda: b.end_section(o, "Get", 2.0), "Get is not running"),
        (lambda: b.end_section(o, "Go_To_Cluster", 0.5), "cannot end at 0.5 s"),
        (lambda: b.end_section(o, "Go_To_Cluster", math.nan), "cannot end at nan s"),
        (lambda: b.end_section(o, "Go_To_Cluster", math.inf), "cannot end at inf s"),
    ]
    for call, words in cases:
        with pytest.raises(OrderError, match="field 'sections'") as err:
            call()
        assert words in str(err.value)
    assert snapshot(b) == before
    b.end_section(o, "Go_To_Cluster", 3.0)
    with pytest.raises(OrderError, match="Get cannot start at 2.5 s, before Go_To_Cluster ended"):
        b.start_section(o, "Get", 2.5)
    b.start_section(o, "Get", 3.0)  # no queue, straight onto the station
    b.end_section(o, "Get", 4.0)
    with pytest.raises(OrderError, match="Get_Queue cannot start after Get"):
        b.start_section(o, "Get_Queue", 4.0)
    with pytest.raises(OrderError, match="Get is not running"):
        b.end_section(o, "Get", 5.0)


@pytest.mark.parametrize("state", [S.DISPATCHABLE, S.FINISHED, S.WITHDRAWN])
def test_sections_run_only_while_the_order_is_being_processed(state):
    b = book()
    o = reach(b, state)
    with pytest.raises(OrderError, match=f"Go_To_Cluster cannot start: the order is {state}"):
        b.start_section(o, "Go_To_Cluster", 5.0)
    assert o.sections == {}


def test_numpy_ids_and_a_null_deadline_from_python_are_taken_as_plain_values():
    """A station id read from ``plant.ids`` is a numpy integer, and None is "no deadline"
    as null is in an order file or over HTTP: both are what the caller meant."""
    import numpy as np

    from blocks.dispatch.orders import check_order, plain_order

    order = plain_order(TransportOrder("o", get=np.int64(10), put=np.int32(20), end_s=None))
    check_order(order)
    assert (type(order.get), type(order.put), order.end_s) == (int, int, math.inf)
    with pytest.raises(OrderError, match="field 'get'"):
        check_order(plain_order(TransportOrder("b", get=np.bool_(True), put=20)))
