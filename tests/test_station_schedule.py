"""Station reservation lists: next free slot, buffer, waiting time."""

import math
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blocks.dispatch.estimates import SectionEstimates
from blocks.dispatch.orders import TransportOrder
from blocks.dispatch.station_schedule import Reservation, StationSchedule, live_schedule

STATION = 7


def two_visits(buffer_s: float = 10.0) -> StationSchedule:
    """Station 7 busy [100, 110] (vehicle 1, order a) and [140, 150] (vehicle 2, order b)."""
    s = StationSchedule(buffer_s)
    assert s.reserve(STATION, 1, "a", 100.0, 10.0) == Reservation(1, "a", 100.0, 110.0)
    assert s.reserve(STATION, 2, "b", 140.0, 10.0) == Reservation(2, "b", 140.0, 150.0)
    return s


def test_hand_checked_slots():
    """B = 10, visits [100, 110] and [140, 150]; padded by B/2 they block [95, 115], [135, 155].

    * dwell 5 arriving 95: [90, 105] hits [95, 115]; after it the next start is 110 + 10 = 120,
      padded [115, 130], clear of [135, 155]: slot 120, wait 25.
    * dwell 10 arriving 95: slot 120, padded [115, 135] only touches [135, 155]: fits.
    * dwell 11 arriving 95: 120 would end at 131 + 5 = 136 > 135; after the second visit:
      150 + 10 = 160, wait 65.
    * dwell 5 arriving 85: [80, 95] touches [95, 115]: fits before, wait 0; arriving 86 it
      does not ([81, 96]), so 120.
    * dwell 5 arriving 155: the first visit is long past; [150, 165] hits [135, 155], so
      160, wait 5. Arriving 200: free.
    """
    s = two_visits()
    assert s.slot(STATION, 95.0, 5.0) == 120.0
    assert s.wait(STATION, 95.0, 5.0) == 25.0
    assert s.slot(STATION, 95.0, 10.0) == 120.0
    assert s.slot(STATION, 95.0, 11.0) == 160.0
    assert s.wait(STATION, 95.0, 11.0) == 65.0
    assert s.wait(STATION, 85.0, 5.0) == 0.0
    assert s.slot(STATION, 86.0, 5.0) == 120.0
    assert s.wait(STATION, 155.0, 5.0) == 5.0
    assert s.wait(STATION, 200.0, 5.0) == 0.0
    assert s.wait(STATION + 1, 95.0, 5.0) == 0.0  # another station is free


def test_a_visit_fills_a_wide_enough_gap_and_the_list_stays_sorted():
    """The 10 s visit goes into the gap at 120 (see above); after it the gap is gone and a 1 s
    visit arriving at 95 finds 120 taken (padded until 135 > 131) and lands at 160."""
    s = two_visits()
    assert s.reserve(STATION, 3, "c", 95.0, 10.0) == Reservation(3, "c", 120.0, 130.0)
    assert [r.order for r in s.reservations(STATION)] == ["a", "c", "b"]
    assert s.reserve(STATION, 4, "d", 95.0, 1.0).start_s == 160.0
    assert [r.start_s for r in s.reservations(STATION)] == [100.0, 120.0, 140.0, 160.0]


def test_zero_length_visits_without_buffer():
    """B = 0: a 0 s visit arriving at 100 fits at 100 beside [100, 105] (they only touch), and
    a 0 s visit arriving at 102 must still wait for [100, 105] to end."""
    s = StationSchedule(0.0)
    s.reserve(STATION, 1, "a", 100.0, 5.0)
    assert s.reserve(STATION, 2, "b", 100.0, 0.0) == Reservation(2, "b", 100.0, 100.0)
    assert [r.order for r in s.reservations(STATION)] == ["b", "a"]
    assert s.slot(STATION, 102.0, 0.0) == 105.0


@pytest.mark.parametrize("arrival", [0.0, 95.0, 120.0, 151.0])
def test_without_buffer_visits_may_follow_back_to_back(arrival):
    s = two_visits(buffer_s=0.0)
    expected = {0.0: 0.0, 95.0: 110.0, 120.0: 120.0, 151.0: 151.0}[arrival]
    assert s.slot(STATION, arrival, 20.0) == expected


def test_wait_grows_with_the_buffer_at_a_busy_station():
    """Five vehicles booked for 20 s each, all arriving at 0: the sixth waits for five visits
    and five buffers, 5 * (20 + B)."""
    waits = []
    for buffer_s in (8, 18, 28, 38, 48, 58):
        s = StationSchedule(buffer_s)
        for vehicle in range(5):
            s.reserve(STATION, vehicle, f"o{vehicle}", 0.0, 20.0)
        waits.append(s.wait(STATION, 0.0, 20.0))
    assert waits == [5 * (20 + b) for b in (8, 18, 28, 38, 48, 58)]
    assert waits == sorted(waits) and len(set(waits)) == len(waits)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: StationSchedule(-1.0), "buffer_s must be a finite number >= 0, got -1.0"),
        (lambda: StationSchedule(math.nan), "buffer_s must be a finite number >= 0, got nan"),
        (lambda: StationSchedule(10).slot(1, 0.0, -5.0), "slot: dwell_s must be a finite"),
        (lambda: StationSchedule(10).slot(1, math.nan, 5.0), "slot: arrival_s must be a finite"),
        (lambda: StationSchedule(10).wait(1, math.inf, 5.0), "arrival_s must be a finite number"),
        (lambda: StationSchedule(10).reserve(1, 1, "o", 0.0, math.nan), "dwell_s must be"),
        (lambda: StationSchedule(10).slot(1, "10", 5.0), "arrival_s must be a finite number"),
    ],
)
def test_bad_arguments_are_rejected_with_a_clear_message(call, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        call()


def test_a_rejected_reservation_changes_nothing():
    s = two_visits()
    with pytest.raises(ValueError):
        s.reserve(STATION, 3, "c", 95.0, -1.0)
    assert len(s) == 2


times = st.one_of(st.integers(0, 300).map(float), st.floats(0, 300, allow_nan=False))
dwells = st.one_of(st.sampled_from([0.0, 5.0, 20.0]), st.floats(0, 60, allow_nan=False))
visits = st.lists(st.tuples(st.integers(0, 2), times, dwells), max_size=25)
buffers = st.one_of(st.sampled_from([0.0, 8.0, 38.0]), st.floats(0, 60, allow_nan=False))


def earliest_free(existing: tuple[Reservation, ...], b: float, arrival: float, dwell: float):
    """Brute force: the earliest free start is the arrival or the padded end of some visit."""
    candidates = [arrival] + [r.end_s + b for r in existing if r.end_s + b > arrival]
    free = [
        c
        for c in candidates
        if all(c >= r.end_s + b or c + dwell + b <= r.start_s for r in existing)
    ]
    return min(free)


@settings(max_examples=300, deadline=None)
@given(buffers, visits)
def test_reservations_never_overlap_and_never_start_before_arrival(buffer_s, requests):
    s = StationSchedule(buffer_s)
    arrival_of = {}
    for n, (station, arrival, dwell) in enumerate(requests):
        expected = earliest_free(s.reservations(station), buffer_s, arrival, dwell)
        assert s.slot(station, arrival, dwell) == expected
        r = s.reserve(station, n, f"o{n}", arrival, dwell)
        assert r.start_s == expected and r.end_s == r.start_s + dwell
        arrival_of[r.order] = arrival

    assert len(s) == len(requests)
    for station in range(3):
        booked = s.reservations(station)
        assert [r.start_s for r in booked] == sorted(r.start_s for r in booked)
        for r in booked:
            assert r.start_s >= arrival_of[r.order]
        for i, first in enumerate(booked):
            for second in booked[i + 1 :]:
                assert (
                    first.end_s + buffer_s <= second.start_s
                    or second.end_s + buffer_s <= first.start_s
                ), (first, second)


# ----- the lists as the vehicles stand: rebuilt for every allocation round --------------------
GET, PUT, OTHER = 10, 20, 30
METRES = {(1, GET): 40.0, (GET, PUT): 60.0, (PUT, OTHER): 30.0, (OTHER, PUT): 30.0}


def metres(a: int, b: int) -> float:
    return 0.0 if a == b else METRES.get((a, b), 100.0)


def vehicle(phase, current, active=None, next_=None, dwell_until_s=0.0):
    return SimpleNamespace(
        phase=phase,
        current=current,
        active=active,
        next=next_,
        dwell_until_ns=round(dwell_until_s * 1e9),
    )


def live(runners, now_s=0.0, buffer_s=0.0):
    estimates = SectionEstimates(metres, dwell_default_s=10.0, mean_speed=1.0)
    return live_schedule(runners, estimates, buffer_s, now_s)


def test_a_late_vehicle_keeps_its_visits():
    """Long after any plan would have had it at the station, it is booked from where it is."""
    o = TransportOrder("a", GET, PUT)
    schedule, finish = live({1: vehicle("to_get", 1, o)}, now_s=500.0)
    assert schedule.reservations(GET) == (Reservation(1, "a", 540.0, 550.0),)
    assert schedule.reservations(PUT) == (Reservation(1, "a", 610.0, 620.0),)
    assert finish == {1: 620.0}


def test_a_queue_in_front_of_a_station_is_seen():
    """One vehicle at the station until 105, two waiting beside it: served one after the
    other, B apart, and each one's order ends one visit later than the one before."""
    orders = [TransportOrder(f"o{n}", GET, PUT) for n in range(3)]
    runners = {
        1: vehicle("get", GET, orders[0], dwell_until_s=105.0),
        2: vehicle("get_queue", GET, orders[1]),
        3: vehicle("get_queue", GET, orders[2]),
    }
    schedule, finish = live(runners, now_s=100.0, buffer_s=4.0)
    starts = [(r.vehicle, r.start_s, r.end_s) for r in schedule.reservations(GET)]
    assert starts == [(1, 100.0, 105.0), (2, 109.0, 119.0), (3, 123.0, 133.0)]
    # Put stations: 60 s on, 10 s there; 1 at 165, 2 at 179 (just after 1's padded end)
    assert finish == {1: 175.0, 2: 189.0, 3: 203.0}
    # the next vehicle sent there would wait behind all three
    assert schedule.wait(GET, 100.0, 10.0) == 37.0


def test_the_next_order_follows_the_active_one_as_booked():
    active, nxt = TransportOrder("a", GET, PUT), TransportOrder("b", OTHER, PUT)
    runners = {
        1: vehicle("to_put", GET, active, nxt),
        2: vehicle("put", PUT, TransportOrder("c", GET, PUT), dwell_until_s=70.0),
    }
    schedule, finish = live(runners)
    # vehicle 2 holds the Put station until 70, so 1 (due at 60) starts there at 70
    assert [(r.vehicle, r.start_s) for r in schedule.reservations(PUT)] == [
        (2, 0.0),
        (1, 70.0),
        (1, 80.0 + 30.0 + 10.0 + 30.0),  # the next order's Put: via OTHER and back
    ]
    assert schedule.reservations(OTHER) == (Reservation(1, "b", 110.0, 120.0),)
    assert finish == {1: 80.0, 2: 70.0}


def test_vehicles_without_an_order_book_nothing():
    runners = {
        1: vehicle("parked", 5),
        2: vehicle("charging", 6),
        3: vehicle("to_get", None, TransportOrder("a", GET, PUT)),  # position not known yet
    }
    schedule, finish = live(runners)
    assert len(schedule) == 0 and finish == {}
