"""The allocation strategies on small scenarios where the right answer is worked out by hand.

Distances come from a table given in the test (metres, 1 m/s), so every cost below can be
checked with pencil and paper."""

from __future__ import annotations

import math

import pytest

from blocks.dispatch.estimates import SectionEstimates
from blocks.dispatch.orders import TransportOrder
from blocks.dispatch.station_schedule import StationSchedule
from blocks.dispatch.strategies import Candidate, StationStats, dhht, nearest_idle, two_stage

# positions on a line, in metres: vehicles stand at nodes 0 and 100, stations at 10..90
POSITION = {0: 0.0, 100: 100.0, 10: 10.0, 20: 20.0, 50: 50.0, 80: 80.0, 90: 90.0}


def distance(a: int, b: int) -> float:
    return abs(POSITION[a] - POSITION[b])


def finish(round_):
    """Run a strategy's round to its end; also how many evaluations it yielded."""
    steps = 0
    while True:
        try:
            next(round_)
            steps += 1
        except StopIteration as done:
            return done.value, steps


def order(oid, get, put, start=0.0, end=math.inf, priority=0, vehicle=None):
    return TransportOrder(oid, get, put, start, end, priority, vehicle)


def test_nearest_idle_gives_each_order_in_urgency_order_the_nearest_free_vehicle():
    vehicles = [Candidate(1, 0, 0.0, "active"), Candidate(2, 100, 0.0, "active")]
    orders = [order("a", 90, 10), order("b", 20, 80, priority=1), order("c", 50, 10)]
    # b is the most urgent (priority 1): nearest to its Get 20 is vehicle 1 (20 m vs 80 m);
    # then a (end inf, id "a" before "c"): only vehicle 2 is left
    got, steps = finish(nearest_idle(vehicles, orders, distance))
    assert [(a.vehicle, a.order.id) for a in got] == [(1, "b"), (2, "a")]
    assert steps == 3  # b against both vehicles, a against the one left


def test_nearest_idle_respects_an_intended_vehicle():
    vehicles = [Candidate(1, 0, 0.0, "active"), Candidate(2, 100, 0.0, "active")]
    got, _ = finish(nearest_idle(vehicles, [order("a", 10, 90, vehicle=2)], distance))
    assert [(a.vehicle, a.order.id) for a in got] == [(2, "a")]


def test_dhht_pulls_from_the_station_with_the_smallest_weighted_log_distance():
    # vehicle 1 at 0. Station 10: 10 m away, 1 open order, 5 loads delivered, pickup
    # efficiency e = 30/60 = 0.5 -> w = (1/0.5) * 1 / 5 = 0.4, D = log(11) / 0.4 = 5.99.
    # Station 90: 90 m away, 3 open orders, nothing delivered yet (counts as 1), e at its
    # floor 0.05 -> w = 20 * 3 / 1 = 60, D = log(91) / 60 = 0.075: the starved station wins.
    vehicles = [Candidate(1, 0, 0.0, "active")]
    orders = [order("near", 10, 50), order("f1", 90, 50), order("f2", 90, 20), order("f3", 90, 10)]
    now = 3600.0
    stats = {
        10: StationStats(delivered=5, pickups_s=[now - 60 * k for k in range(5)], supply_per_h=60),
        90: StationStats(delivered=0, pickups_s=[], supply_per_h=60),
    }
    got, _ = finish(dhht(vehicles, orders, distance, stats, now, capacity_per_h=60, window_s=600))
    assert [(a.vehicle, a.order.id) for a in got] == [(1, "f1")]
    # with station 90 as busy as station 10, distance decides
    stats[90] = StationStats(delivered=5, pickups_s=list(stats[10].pickups_s), supply_per_h=60)
    orders = [order("near", 10, 50), order("far", 90, 50)]
    got, _ = finish(dhht(vehicles, orders, distance, stats, now, capacity_per_h=60, window_s=600))
    assert [a.order.id for a in got] == ["near"]


def test_dhht_guards_a_distance_of_zero():
    vehicles = [Candidate(1, 10, 0.0, "active")]  # standing at the Get station: d = 0
    got, _ = finish(dhht(vehicles, [order("a", 10, 50)], distance, {}, 0.0, capacity_per_h=60))
    assert [a.order.id for a in got] == ["a"]


def estimates(dwell=10.0):
    return SectionEstimates(distance, dwell)  # 1 m/s, every dwell 10 s


def test_two_stage_takes_the_pair_of_least_idle_time_first_and_reevaluates():
    # Idle time = travel to Get + wait at Get + wait at Put (B = 0, nothing reserved yet).
    #   vehicle 1 (at 0):   a (Get 10): 10   b (Get 90): 90
    #   vehicle 2 (at 100): a: 90            b: 10
    # 2 orders, 2 vehicles: the minimum pair is (1, a) at 10 (tie with (2, b), vehicle 1
    # first), committed: vehicle 1 puts at 50 from 60 to 70 (Get 10..20, 40 m to 50). Then
    # (2, b) is evaluated again: it too reaches 50 at 60 and waits 10 s: idle 20.
    vehicles = [Candidate(1, 0, 0.0, "active"), Candidate(2, 100, 0.0, "active")]
    orders = [order("a", 10, 50), order("b", 90, 50)]
    schedule = StationSchedule(0.0)
    got, _ = finish(two_stage(vehicles, orders, schedule, estimates(), 0.0))
    assert [(a.vehicle, a.order.id, a.idle_s) for a in got] == [(1, "a", 10.0), (2, "b", 20.0)]
    puts = schedule.reservations(50)
    assert [(r.vehicle, r.start_s) for r in puts] == [(1, 60.0), (2, 70.0)]


def test_two_stage_counts_the_wait_at_a_busy_put_station_with_its_buffer():
    # One vehicle at 0, two orders with Get 10 and Get 20, both Put 50; station 50 is
    # reserved from 40 to 100 by someone else. B = 20: every visit is padded by 10 s before
    # and after, so the next visit starts B after the reserved one ends, at 120.
    #   a: Get at 10 s, dwell to 20, Put arrival 60: wait 60, idle = 10 + 0 + 60 = 70
    #   b: Get at 20 s, dwell to 30, Put arrival 70: wait 50, idle = 20 + 0 + 50 = 70
    # a tie: the first evaluated pair (a) wins
    schedule = StationSchedule(20.0)
    schedule.reserve(50, 9, "other", 40.0, 60.0)
    vehicles = [Candidate(1, 0, 0.0, "active")]
    got, _ = finish(
        two_stage(vehicles, [order("a", 10, 50), order("b", 20, 50)], schedule, estimates(), 0.0)
    )
    assert [(a.order.id, a.idle_s) for a in got] == [("a", 70.0)]
    # without the buffer the wait is 40 (free from 100): the buffer B is counted
    got, _ = finish(
        two_stage(vehicles, [order("a", 10, 50)], _busy(StationSchedule(0.0)), estimates(), 0.0)
    )
    assert got[0].idle_s == 10.0 + 40.0


def test_two_stage_serves_late_orders_first_by_end_time():
    # "late" cannot be done in time any more (end 5 s, Get->Put alone takes 40 s): it goes
    # first, to the vehicle that finishes it earliest, even though "cheap" idles less.
    vehicles = [Candidate(1, 0, 0.0, "active"), Candidate(2, 100, 0.0, "active")]
    orders = [order("cheap", 10, 50), order("late", 90, 50, end=5.0)]
    got, _ = finish(two_stage(vehicles, orders, StationSchedule(0.0), estimates(), 0.0))
    assert got[0].order.id == "late" and got[0].vehicle == 2


def test_two_stage_leaves_an_order_whose_get_arrival_would_be_before_its_start():
    vehicles = [Candidate(1, 0, 0.0, "active")]
    # arrival at Get 10 after 10 s, but the load is ready only at 60 s
    got, _ = finish(
        two_stage(
            vehicles, [order("a", 10, 50, start=60.0)], StationSchedule(0.0), estimates(), 0.0
        )
    )
    assert got == []
    # a vehicle that is busy until 55 s (its next-order slot) arrives at 65 s: it may take it
    later = [Candidate(1, 0, 55.0, "next")]
    got, _ = finish(
        two_stage(later, [order("a", 10, 50, start=60.0)], StationSchedule(0.0), estimates(), 0.0)
    )
    assert [a.order.id for a in got] == ["a"]


def test_two_stage_with_fewer_orders_than_vehicles_gives_each_the_earliest_finisher():
    vehicles = [
        Candidate(1, 0, 0.0, "active"),
        Candidate(2, 100, 0.0, "active"),
        Candidate(3, 50, 30.0, "next"),  # at 50 but busy until 30 s
    ]
    # Put finish of order (Get 90, Put 80), dwell 10 each: vehicle 1: 90+10+10+10 = 120;
    # vehicle 2: 10+10+10+10 = 40; vehicle 3: 30+40+10+10+10 = 100
    got, _ = finish(
        two_stage(vehicles, [order("a", 90, 80)], StationSchedule(0.0), estimates(), 0.0)
    )
    assert [(a.vehicle, a.finish_s) for a in got] == [(2, 40.0)]


def test_two_stage_bottleneck_weight_favours_orders_at_the_pools_busiest_station():
    # One vehicle at 0. Visits per station in the pool: 90 three times, 80 twice, the
    # others once, so the share of the busier station is 1/3 for a (10 -> 20) and 1 for
    # b, c, d. Idle times: a 10, b 50 (Get 50), c 80, d 90.
    vehicles = [Candidate(1, 0, 0.0, "active")]
    orders = [order("a", 10, 20), order("b", 50, 90), order("c", 80, 90), order("d", 90, 80)]

    def chosen(bottleneck_s: float) -> tuple[str, float]:
        round_ = two_stage(vehicles, orders, StationSchedule(0.0), estimates(), 0.0, bottleneck_s)
        (got,), _ = finish(round_)
        return got.order.id, got.idle_s

    assert chosen(0.0) == ("a", 10.0)  # the seed's cost: the least idle time
    # 60 s: a 10 - 20 = -10, b 50 - 60 = -10, a tie: the first evaluated (a) wins
    assert chosen(60.0) == ("a", 10.0)
    # 90 s: a 10 - 30 = -20, b 50 - 90 = -40: b; the idle time it reports is its own
    assert chosen(90.0) == ("b", 50.0)


def _busy(schedule: StationSchedule) -> StationSchedule:
    schedule.reserve(50, 9, "other", 40.0, 60.0)
    return schedule


@pytest.mark.parametrize("strategy", ["nearest_idle", "dhht", "two_stage"])
def test_every_round_is_bounded_and_assigns_an_order_at_most_once(strategy):
    vehicles = [Candidate(v, 0 if v % 2 else 100, 0.0, "active") for v in range(1, 6)]
    stations = [10, 20, 50, 80, 90]
    orders = [order(f"o{k}", stations[k % 5], stations[(k + 2) % 5]) for k in range(12)]
    if strategy == "nearest_idle":
        round_ = nearest_idle(vehicles, orders, distance)
    elif strategy == "dhht":
        round_ = dhht(vehicles, orders, distance, {}, 0.0, capacity_per_h=60)
    else:
        round_ = two_stage(vehicles, orders, StationSchedule(10.0), estimates(), 0.0)
    got, steps = finish(round_)
    assert len(got) == 5
    assert len({a.order.id for a in got}) == 5 and len({a.vehicle for a in got}) == 5
    assert steps <= len(vehicles) ** 2 * len(orders)  # the greedy's worst case, no more
