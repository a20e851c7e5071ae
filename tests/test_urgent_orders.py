"""The dispatcher's urgency index (blocks/dispatch/urgent_orders.py) against the plain
definition it replaces: sort every waiting order by urgency and take the first k.

Orders enter, leave, are taken back and come again, are assigned without leaving, and time
moves on; after every step the index must give exactly what the sort gives.
"""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from blocks.dispatch.orders import OrderState, TransportOrder
from blocks.dispatch.urgent_orders import UrgentOrders, urgency


def make(oid: int, start: float, end: float, priority: int) -> TransportOrder:
    order = TransportOrder(f"o{oid:03d}", 1, 2, start, end, priority)
    order.state = OrderState.DISPATCHABLE
    return order


def by_sort(orders, k, now, startable_only):
    waiting = [
        o
        for o in orders
        if o.state is OrderState.DISPATCHABLE
        and o.assigned is None
        and (not startable_only or o.start_s <= now)
    ]
    return sorted(waiting, key=urgency)[:k]


STEP = st.one_of(
    st.tuples(st.just("add"), st.integers(0, 30)),
    st.tuples(st.just("leave"), st.integers(0, 30)),
    st.tuples(st.just("assign"), st.integers(0, 30)),
    st.tuples(st.just("time"), st.floats(0, 20)),
    st.tuples(st.just("ask"), st.integers(0, 12)),
)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(
    st.booleans(),
    st.lists(
        st.tuples(st.floats(0, 100), st.sampled_from([50.0, 80.0, math.inf]), st.integers(0, 2)),
        min_size=31,
        max_size=31,
    ),
    st.lists(STEP, max_size=120),
)
def test_the_index_gives_what_sorting_every_waiting_order_gives(startable_only, fields, steps):
    orders = [make(i, start, start + span, prio) for i, (start, span, prio) in enumerate(fields)]
    for order in orders:
        order.state = OrderState.RAW
    index = UrgentOrders(startable_only)
    now = 0.0
    for what, arg in steps:
        if what == "add":
            order = orders[arg]
            order.state, order.assigned = OrderState.DISPATCHABLE, None
            index.update(order, now)
        elif what == "leave":
            order = orders[arg]
            order.state = OrderState.BEING_PROCESSED
            index.update(order, now)
        elif what == "assign":
            orders[arg].assigned = 7  # the index must skip it until it is free again
        elif what == "time":
            now += arg
        else:
            assert index.advance(now, len(orders))
            got = index.most_urgent(arg)
            assert [o.id for o in got] == [o.id for o in by_sort(orders, arg, now, startable_only)]
    assert index.advance(now, len(orders))
    got = index.most_urgent(len(orders))
    assert [o.id for o in got] == [o.id for o in by_sort(orders, len(orders), now, startable_only)]


def test_an_order_that_comes_back_is_listed_once():
    order = make(1, 0.0, 10.0, 0)
    index = UrgentOrders(startable_only=False)
    for _ in range(5):
        order.state = OrderState.DISPATCHABLE
        index.update(order, 0.0)
        order.state = OrderState.BEING_PROCESSED
        index.update(order, 0.0)
    order.state = OrderState.DISPATCHABLE
    index.update(order, 0.0)
    index.update(order, 0.0)  # (told twice: still one member)
    assert index.most_urgent(10) == [order]
    assert len(index) == 1


def test_orders_not_yet_startable_wait_for_their_start_time():
    early, late = make(1, 0.0, 500.0, 0), make(2, 100.0, 200.0, 0)
    index = UrgentOrders(startable_only=True)
    for order in (early, late):
        index.update(order, 0.0)
    assert index.advance(50.0, 10) and index.most_urgent(5) == [early]
    assert index.advance(100.0, 10) and index.most_urgent(5) == [late, early]  # late ends sooner
    planning = UrgentOrders(startable_only=False)  # (two_stage plans ahead)
    for order in (early, late):
        planning.update(order, 0.0)
    assert planning.most_urgent(5) == [late, early]


def test_orders_sharing_a_start_time_become_startable_a_budget_at_a_time():
    orders = [make(k, 100.0, 1000.0 - k, 0) for k in range(25)]
    index = UrgentOrders(startable_only=True)
    for order in orders:
        index.update(order, 0.0)
    assert index.advance(99.0, 10) and index.most_urgent(30) == []
    assert not index.advance(100.0, 10) and len(index.most_urgent(30)) == 10
    assert not index.advance(100.0, 10) and len(index.most_urgent(30)) == 20
    assert index.advance(100.0, 10)
    assert index.most_urgent(30) == sorted(orders, key=urgency)


def test_rebuild_starts_from_the_given_orders_only():
    a, b = make(1, 0.0, 10.0, 0), make(2, 0.0, 20.0, 0)
    index = UrgentOrders(startable_only=False)
    index.update(a, 0.0)
    index.rebuild([b], 0.0)
    assert index.most_urgent(5) == [b]


@given(
    st.lists(st.booleans(), min_size=1, max_size=40),
    st.integers(1, 10),
    st.integers(0, 15),
)
def test_orders_that_cannot_be_given_out_are_passed_over_up_to_a_limit(servable, k, limit):
    """``accept`` refuses some orders (their station is held by a vehicle out of service):
    the index gives the k most urgent it accepts, as filtering the sort would, but stops
    looking once it has passed over ``limit`` refused ones; and nothing leaves the index."""
    orders = [make(i, 0.0, float(i), 0) for i in range(len(servable))]
    index = UrgentOrders(startable_only=False)
    for order in orders:
        index.update(order, 0.0)
    ok = {o.id for o, s in zip(orders, servable, strict=True) if s}
    got = index.most_urgent(k, lambda o: o.id in ok, limit)
    expected, passed = [], 0
    for o in sorted(orders, key=urgency):
        if len(expected) == k:
            break
        if o.id in ok:
            expected.append(o)
        else:
            passed += 1
            if passed > limit:
                break
    assert got == expected
    assert index.most_urgent(len(orders)) == sorted(orders, key=urgency)
