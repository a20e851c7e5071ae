"""The seed's order generator: its relation rates, counts per relation, stations used evenly,
the control-station extra orders, start times and windows, determinism; and the release feed."""

import math
from collections import Counter

import pytest

from blocks.dispatch import generator
from blocks.dispatch.generator import (
    LEAD_S,
    SEED_RELATIONS,
    WINDOW_S,
    OrderFeed,
    Relation,
    generate_orders,
    order_counts,
)
from blocks.dispatch.orders import OrderBook, TransportOrder

UNITS = {
    "receiving": [1, 2, 3],
    "hrl": [10, 11, 12, 13, 14],  # the five aisle transfer points
    "depalletising": [20, 21],
    "picking": [30, 31, 32, 33],
    "empty_pallets": [40],
}
CONTROL = 50
UNIT_OF = {s: unit for unit, stations in UNITS.items() for s in stations} | {CONTROL: "control"}


def relation_of(order: TransportOrder) -> tuple[str, str]:
    return UNIT_OF[order.get], UNIT_OF[order.put]


def test_the_seed_relations_and_rates():
    assert [(r.source, r.target, r.rate_per_h) for r in SEED_RELATIONS] == [
        ("receiving", "hrl", 72.3),
        ("hrl", "depalletising", 103.0),
        ("depalletising", "hrl", 67.9),
        ("depalletising", "empty_pallets", 35.1),
        ("hrl", "picking", 67.0),
        ("picking", "hrl", 42.4),
        ("picking", "empty_pallets", 24.7),
    ]
    assert sum(r.rate_per_h for r in SEED_RELATIONS) == pytest.approx(412.4)
    assert generator.CONTROL == "control" and LEAD_S == 600.0


@pytest.mark.parametrize("duration", [900.0, 3600.0, 7200.0, 12345.0])
def test_orders_per_relation_are_rate_times_duration(duration):
    orders = generate_orders(SEED_RELATIONS, UNITS, duration, seed=1)
    counts = Counter(relation_of(o) for o in orders)
    for r in SEED_RELATIONS:
        assert counts[(r.source, r.target)] == round(r.rate_per_h * duration / 3600)
    assert len(orders) == sum(counts.values())


def test_an_hour_of_the_seed_is_412_orders_plus_two_percent_through_control():
    orders = generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed=1, control_station=CONTROL)
    counts = Counter(relation_of(o) for o in orders)
    plain = sum(n for (_, target), n in counts.items() if target != "control")
    extra = sum(n for (_, target), n in counts.items() if target == "control")
    assert plain == 412  # 72 + 103 + 68 + 35 + 67 + 42 + 25
    # round(n x 2 / 100) per relation: 1 + 2 + 1 + 1 + 1 + 1 + 0
    assert extra == 7
    assert 410 * 1.01 < len(orders) < 414 * 1.03  # about 420 an hour, as the seed says
    by_source = Counter(UNIT_OF[o.get] for o in orders if o.put == CONTROL)
    expected = Counter()
    for r in SEED_RELATIONS:
        expected[r.source] += round(round(r.rate_per_h) * 2 / 100)
    assert by_source == expected


def test_a_long_run_keeps_the_two_percent():
    orders = generate_orders(SEED_RELATIONS, UNITS, 24 * 3600.0, seed=3, control_station=CONTROL)
    extra = sum(o.put == CONTROL for o in orders)
    assert extra / (len(orders) - extra) == pytest.approx(0.02, abs=0.001)


def test_extra_per_100_is_the_control_share():
    orders = generate_orders(
        SEED_RELATIONS, UNITS, 3600.0, seed=1, control_station=CONTROL, extra_per_100=10
    )
    assert sum(o.put == CONTROL for o in orders) == sum(
        round(round(r.rate_per_h) * 10 / 100) for r in SEED_RELATIONS
    )
    assert all(o.put != CONTROL for o in generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed=1))


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_the_stations_of_a_unit_are_used_evenly_per_relation(seed):
    orders = generate_orders(SEED_RELATIONS, UNITS, 7200.0, seed, control_station=CONTROL)
    for r in SEED_RELATIONS:
        mine = [o for o in orders if relation_of(o) == (r.source, r.target)]
        puts = Counter(o.put for o in mine)
        assert set(puts) == set(UNITS[r.target])
        assert max(puts.values()) - min(puts.values()) <= 1, (r, puts)
        gets = Counter(o.get for o in mine)
        assert set(gets) == set(UNITS[r.source])
        assert max(gets.values()) - min(gets.values()) <= 1, (r, gets)
    # receiving has one relation: its Gets, the control-station orders' included, are even
    gets = Counter(o.get for o in orders if UNIT_OF[o.get] == "receiving")
    assert any(o.put == CONTROL for o in orders if UNIT_OF[o.get] == "receiving")
    assert max(gets.values()) - min(gets.values()) <= 1


def test_get_put_pairs_vary():
    orders = generate_orders([Relation("hrl", "picking", 200.0)], UNITS, 3600.0, seed=2)
    assert len({(o.get, o.put) for o in orders}) == len(UNITS["hrl"]) * len(UNITS["picking"])


@pytest.mark.parametrize("duration", [60.0, 3600.0, 10_000.0])
def test_start_times_are_spread_over_the_duration_and_windows_follow(duration):
    orders = generate_orders(
        SEED_RELATIONS, UNITS, duration, seed=5, control_station=CONTROL, window_s=1200.0
    )
    assert all(0.0 <= o.start_s < duration for o in orders)
    assert all(o.end_s == o.start_s + 1200.0 for o in orders)
    assert [o.start_s for o in orders] == sorted(o.start_s for o in orders)
    assert [o.id for o in orders] == [f"o{k:05d}" for k in range(1, len(orders) + 1)]
    for r in SEED_RELATIONS:  # each relation's k-th order starts in the k-th of n equal slots
        starts = sorted(o.start_s for o in orders if relation_of(o) == (r.source, r.target))
        slot = duration / len(starts) if starts else 0
        assert [math.floor(s / slot) for s in starts] == list(range(len(starts)))


def test_the_default_window():
    (order,) = generate_orders([Relation("receiving", "hrl", 1.0)], UNITS, 3600.0, seed=0)
    assert order.end_s - order.start_s == WINDOW_S == 900.0


def test_a_start_never_rounds_up_to_the_duration():
    class Highest:  # random() at its largest value, 1 - 2**-53
        def random(self) -> float:
            return math.nextafter(1.0, 0.0)

    assert (2 + Highest().random()) * (1.0 / 3) == 1.0  # what the clamp is there for
    assert max(generator._spread(3, 1.0, Highest())) < 1.0


def key(orders):
    return [(o.id, o.get, o.put, o.start_s, o.end_s) for o in orders]


def test_deterministic_for_a_seed_and_different_for_another():
    def make(seed):
        return key(generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed, control_station=CONTROL))

    assert make(11) == make(11)
    assert make(11) != make(12)


def test_a_relations_orders_do_not_depend_on_the_others():
    alone = generate_orders([SEED_RELATIONS[0]], UNITS, 3600.0, seed=4, control_station=CONTROL)
    mixed = generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed=4, control_station=CONTROL)
    # receiving -> hrl is the only relation from receiving, control-station orders included
    from_mix = [(o.get, o.put, o.start_s) for o in mixed if UNIT_OF[o.get] == "receiving"]
    assert any(put == CONTROL for _, put, _ in from_mix)
    assert [(o.get, o.put, o.start_s) for o in alone] == from_mix


def test_every_generated_order_is_valid_for_the_book():
    stations = {s: UNIT_OF[s] for s in UNIT_OF}
    book = OrderBook(stations)
    for o in generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed=9, control_station=CONTROL):
        book.add(o, 0.0)
    assert book.counts()["DISPATCHABLE"] == 419


BAD = [
    (dict(duration_s=0.0), "duration must be a positive number"),
    (dict(duration_s=math.nan), "duration must be a positive number"),
    (dict(window_s=-1.0), "window_s must be"),
    (dict(extra_per_100=-2), "extra_per_100 must be"),
    (dict(relations=[Relation("hrl", "picking", -1.0)]), "hrl -> picking: rate must be"),
    (dict(relations=[Relation("hrl", "shipping", 5.0)]), "unit 'shipping' has no stations"),
    (dict(units=UNITS | {"picking": []}), "unit 'picking' has no stations"),
    (dict(units=UNITS | {"picking": [30, 30]}), "unit 'picking' lists a station twice"),
    (dict(relations=[Relation("hrl", "hrl", 5.0)]), "station 10 would be Get and Put"),
    (dict(units=UNITS | {"picking": [30, 10]}), "station 10 would be Get and Put"),
    (dict(control_station=1), "relation receiving -> hrl: station 1 would be Get and Put"),
    (dict(seed=1.5), "seed must be an integer, got 1.5"),
    (dict(units=UNITS | {"hrl": 10}), "unit 'hrl': expected a list of station node ids, got 10"),
]


@pytest.mark.parametrize(("change", "words"), BAD)
def test_bad_arguments_are_named(change, words):
    args = dict(
        relations=SEED_RELATIONS, units=UNITS, duration_s=3600.0, seed=0, control_station=CONTROL
    )
    with pytest.raises(ValueError, match=words):
        generate_orders(**(args | change))


def test_too_many_orders_are_refused(monkeypatch):
    monkeypatch.setattr(generator, "MAX_ORDERS", 400)
    with pytest.raises(ValueError, match="412 orders: more than 400"):
        generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed=0)


def test_order_counts_are_exactly_what_is_generated():
    counts = order_counts(SEED_RELATIONS, 3600.0, control=True)
    assert sum(n for n, _ in counts) == 412 and sum(extra for _, extra in counts) == 7
    assert order_counts(SEED_RELATIONS, 3600.0, control=False)[0] == (72, 0)


def no_generating(*args):
    raise AssertionError("orders were generated before they were counted")


@pytest.mark.parametrize(
    ("rate", "duration", "words"),
    [
        (999_999.0, 1e7, "about 2,777,775,000 orders: more than 100,000, the limit"),
        (1e308, 1e7, "too many to count orders: more than 100,000"),  # rate x duration is inf
    ],
)
def test_too_many_orders_are_refused_before_any_is_made(monkeypatch, rate, duration, words):
    monkeypatch.setattr(generator, "_spread", no_generating)
    monkeypatch.setattr(generator, "_dealt", no_generating)
    units = {"a": [1, 2], "b": [3]}
    with pytest.raises(ValueError, match=words):
        generate_orders([Relation("a", "b", rate)], units, duration, seed=0)


def test_the_control_share_counts_towards_the_limit(monkeypatch):
    monkeypatch.setattr(generator, "MAX_ORDERS", 415)
    assert len(generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed=0)) == 412
    with pytest.raises(ValueError, match="419 orders: more than 415"):
        generate_orders(SEED_RELATIONS, UNITS, 3600.0, seed=0, control_station=CONTROL)


def test_generating_stops_once_past_the_limit_whatever_was_counted(monkeypatch):
    monkeypatch.setattr(generator, "MAX_ORDERS", 100)
    monkeypatch.setattr(generator, "order_counts", lambda *args: [(80, 0), (80, 0), (80, 0)])
    made = []
    real_spread = generator._spread
    monkeypatch.setattr(generator, "_spread", lambda n, *a: made.append(n) or real_spread(n, *a))
    with pytest.raises(ValueError, match="160 orders: more than 100"):
        generate_orders(SEED_RELATIONS[:3], UNITS, 3600.0, seed=0)
    assert made == [80, 80]  # the third relation was never made


# ----- the release feed --------------------------------------------------------------------
def test_the_feed_releases_each_order_once_lead_s_before_its_start():
    orders = [TransportOrder(f"o{k}", 1, 10, start_s=s) for k, s in enumerate([900, 0, 601, 600])]
    feed = OrderFeed(orders)  # 600 s ahead, as the seed's warehouse system
    assert [o.start_s for o in feed.due(0.0)] == [0, 600]
    assert feed.pending == 2
    assert feed.due(0.0) == []
    assert [o.start_s for o in feed.due(1.0)] == [601]
    assert [o.start_s for o in feed.due(10_000.0)] == [900]
    assert feed.pending == 0 and feed.due(20_000.0) == []


def test_the_feed_hands_out_at_most_a_limit_a_call_in_start_order():
    orders = [TransportOrder(f"o{k}", 1, 10, start_s=float(k)) for k in range(7)]
    feed = OrderFeed(orders, lead_s=0.0)
    assert [o.id for o in feed.due(100.0, 3)] == ["o0", "o1", "o2"]
    assert [o.id for o in feed.due(100.0, 3)] == ["o3", "o4", "o5"]
    assert [o.id for o in feed.due(4.0, 3)] == []  # o6 is not due before 6 s
    assert [o.id for o in feed.due(6.0, 3)] == ["o6"] and feed.pending == 0


def test_the_feed_keeps_about_70_orders_known_at_420_an_hour():
    orders = generate_orders(SEED_RELATIONS, UNITS, 4 * 3600.0, seed=1, control_station=CONTROL)
    feed = OrderFeed(orders)
    released = 0
    known = []
    for now in range(0, 3 * 3600, 60):
        released += len(feed.due(float(now)))
        started = sum(o.start_s <= now for o in orders)
        known.append(released - started)  # released, not yet startable
    assert 60 <= sum(known[10:]) / len(known[10:]) <= 80


def test_a_negative_lead_is_refused():
    with pytest.raises(ValueError, match="lead_s must be"):
        OrderFeed([], lead_s=-1.0)
