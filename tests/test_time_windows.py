"""TimeWindowTable: the interval rules between vehicles, all-or-nothing booking, queries and expiry."""

import math

import pytest

from blocks.traffic.time_windows import TimeWindowTable, Window, WindowConflict


def table(gap=1.0) -> TimeWindowTable:
    return TimeWindowTable(gap)


def test_a_booking_is_stored_sorted_and_readable_per_node_and_directed_segment():
    t = table()
    t.book(2, [(5, 10.0, 12.0)], [(5, 6, 12.0, 14.0)])
    t.book(1, [(5, 0.0, 3.0)], [(5, 6, 3.0, 5.0)])
    assert t.node_windows(5) == (Window(0.0, 3.0, 1), Window(10.0, 12.0, 2))
    assert t.segment_windows(5, 6) == (Window(3.0, 5.0, 1), Window(12.0, 14.0, 2))
    assert t.segment_windows(6, 5) == ()
    assert len(t) == 4 and t.vehicles == {1, 2}


@pytest.mark.parametrize(
    ("other", "ok"),
    [
        ((4.0, 6.0), True),  # exactly the gap after
        ((3.5, 6.0), False),  # closer than the gap
        ((1.0, 2.0), False),  # inside
        ((-5.0, -1.0), True),  # exactly the gap before
        ((-5.0, -0.5), False),
    ],
)
def test_node_windows_of_two_vehicles_keep_the_gap(other, ok):
    t = table()
    t.book(1, [(7, 0.0, 3.0)], [])
    if ok:
        t.book(2, [(7, *other)], [])
    else:
        with pytest.raises(WindowConflict, match="node 7"):
            t.book(2, [(7, *other)], [])


def test_two_passes_at_the_same_instant_conflict():
    """Windows of no length: only the gap keeps them apart."""
    t = table(gap=1e-3)
    t.book(1, [(3, 5.0, 5.0)], [])
    with pytest.raises(WindowConflict):
        t.book(2, [(3, 5.0, 5.0)], [])


def test_a_gap_of_zero_is_refused():
    with pytest.raises(ValueError, match="gap_s"):
        TimeWindowTable(0.0)


def test_a_segment_is_never_booked_in_opposite_directions_at_overlapping_times():
    t = table()
    t.book(1, [], [(1, 2, 0.0, 5.0)])
    with pytest.raises(WindowConflict, match="head-on"):
        t.book(2, [], [(2, 1, 4.0, 9.0)])
    with pytest.raises(WindowConflict, match="head-on"):
        t.book(2, [], [(2, 1, 5.5, 9.0)])  # inside the gap
    t.book(2, [], [(2, 1, 6.0, 9.0)])  # after the gap: fine


def test_following_on_a_segment_keeps_order_and_distance():
    t = table()
    t.book(1, [], [(1, 2, 0.0, 5.0)])
    t.book(2, [], [(1, 2, 1.0, 6.0)])  # one gap behind at both ends
    with pytest.raises(WindowConflict, match="overtake"):
        t.book(3, [], [(1, 2, 2.5, 5.5)])  # behind at the entry, would catch up at the exit
    with pytest.raises(WindowConflict, match="overtake"):
        t.book(3, [], [(1, 2, 0.5, 8.0)])  # too close behind vehicle 1 at the entry
    t.book(3, [], [(1, 2, -3.0, 2.0)])  # ahead of both: leads them with the gap


def test_a_vehicles_own_windows_never_conflict():
    t = table()
    t.book(1, [(1, 0.0, 2.0), (2, 3.0, 4.0), (1, 5.0, 6.0)], [(1, 2, 2.0, 3.0), (2, 1, 4.0, 5.0)])
    assert len(t) == 5


def test_booking_is_all_or_nothing_and_keeps_the_old_plan_on_a_conflict():
    t = table()
    t.book(1, [(9, 0.0, 10.0)], [])
    t.book(2, [(4, 0.0, 1.0)], [(4, 5, 1.0, 2.0)])
    with pytest.raises(WindowConflict):
        t.book(2, [(8, 0.0, 1.0), (9, 2.0, 3.0)], [])
    assert t.node_windows(4) == (Window(0.0, 1.0, 2),)
    assert t.node_windows(8) == ()
    assert t.segment_windows(4, 5) == (Window(1.0, 2.0, 2),)


def test_a_new_booking_replaces_the_vehicles_old_windows():
    t = table()
    t.book(1, [(1, 0.0, 1.0), (2, 2.0, 3.0)], [(1, 2, 1.0, 2.0)])
    t.book(1, [(1, 0.0, 1.0), (3, 2.0, 3.0)], [(1, 3, 1.0, 2.0)])
    assert t.node_windows(2) == () and t.segment_windows(1, 2) == ()
    assert len(t) == 3


def test_release_drops_only_that_vehicles_windows():
    t = table()
    t.book(1, [(1, 0.0, 1.0)], [(1, 2, 1.0, 2.0)])
    t.book(2, [(1, 5.0, 6.0)], [])
    t.release(1)
    assert t.node_windows(1) == (Window(5.0, 6.0, 2),)
    assert t.segment_windows(1, 2) == () and t.vehicles == {2}
    t.release(99)  # nothing booked: nothing to do


def test_expire_drops_what_ended_before_now_minus_the_gap_and_bounds_memory():
    t = table()
    for k in range(100):  # a vehicle driving a long line, one node a second
        t.book(1, [(n, float(n), float(n) + 0.5) for n in range(k, k + 10)], [])
        t.expire(float(k))
    assert len(t) <= 12  # only what is still ahead (and within the gap)
    t.book(2, [(0, 0.0, math.inf)], [])
    assert t.expire(1e9) >= 1
    assert t.node_windows(0) == (Window(0.0, math.inf, 2),)  # a stay without end never expires


def test_safe_intervals_are_the_gaps_between_other_vehicles_windows():
    t = table()
    t.book(1, [(5, 2.0, 4.0)], [])
    t.book(2, [(5, 10.0, math.inf)], [])
    assert t.safe_intervals(5) == [(-math.inf, 1.0), (5.0, 9.0)]
    assert t.safe_intervals(5, vehicle=1) == [(-math.inf, 9.0)]  # its own windows do not count
    assert t.safe_intervals(6) == [(-math.inf, math.inf)]


def test_a_cut_off_ignores_later_windows_and_ends_every_window_there():
    """Every window ends at the cut-off at the latest, but one that never ends and began
    before it: that vehicle stands there for good, in the way past the cut-off too
    (unless ``lasting=False``, as for a search's goal)."""
    t = table()
    t.book(1, [(5, 2.0, 4.0)], [])
    t.book(2, [(5, 10.0, math.inf)], [])
    assert t.safe_intervals(5, until=12.0) == [(-math.inf, 1.0), (5.0, 9.0)]
    assert t.safe_intervals(5, until=12.0, lasting=False) == [
        (-math.inf, 1.0),
        (5.0, 9.0),
        (12.0, math.inf),
    ]
    assert t.stands_for_good(5, before=12.0) and not t.stands_for_good(5, 2, 12.0)
    assert not t.stands_for_good(5, before=10.0) and not t.stands_for_good(6)
    assert t.safe_intervals(5, until=10.0) == [(-math.inf, 1.0), (5.0, math.inf)]
    assert t.safe_intervals(5, until=3.0) == [(-math.inf, 1.0), (3.0, math.inf)]
    t.book(3, [], [(2, 1, 0.0, 20.0)])  # a long oncoming traversal
    assert t.earliest_entry(1, 2, 0.0, 3.0) == 21.0
    assert t.earliest_entry(1, 2, 0.0, 3.0, until=8.0) == 8.0  # planned against nobody then
    assert t.earliest_entry(1, 2, 9.0, 3.0, until=8.0) == 9.0
    t.book(4, [], [(1, 2, 30.0, 40.0)])  # a window starting after the cut-off is ignored
    assert t.earliest_entry(1, 2, 25.0, 16.0) == 31.0  # too slow to lead it: behind it
    assert t.earliest_entry(1, 2, 25.0, 16.0, until=28.0) == 25.0


def test_who_stands_for_good_is_known_per_node_and_area_until_released():
    t = TimeWindowTable(0.5, {7: "s", 8: "s"})
    t.book(1, [(7, 1.0, math.inf), (3, 0.0, 1.0)], [(3, 7, 0.0, 1.0)])
    assert t.stands_for_good(8) and t.stands_for_good(7) and not t.stands_for_good(3)
    assert t.safe_intervals(8, until=5.0) == [(-math.inf, 0.5)]
    t.expire(100.0)  # a window that never ends does not expire
    assert t.stands_for_good(7)
    t.book(1, [(7, 1.0, 9.0)], [])
    assert not t.stands_for_good(7)
    t.book(2, [(4, 0.0, math.inf)], [])
    t.release(2)
    assert not t.stands_for_good(4)
    # one that stands only until further notice is expected gone past a cut-off
    t.book(3, [(4, 0.0, math.inf)], [], lasting=False)
    assert not t.stands_for_good(4)
    assert t.safe_intervals(4, until=5.0) == [(-math.inf, -0.5), (5.0, math.inf)]
    assert t.safe_intervals(4) == [(-math.inf, -0.5)]


def test_earliest_entry_waits_for_the_oncoming_vehicle_and_keeps_behind_the_leader():
    t = table()
    t.book(1, [], [(2, 1, 0.0, 4.0)])  # oncoming
    assert t.earliest_entry(1, 2, 0.0, 3.0) == 5.0
    t.book(2, [], [(1, 2, 5.0, 10.0)])  # a slow leader in our direction
    # behind it: entry >= 6 and exit >= 11 with 3 s of travel -> 8
    assert t.earliest_entry(1, 2, 0.0, 3.0) == 8.0
    assert t.earliest_entry(1, 2, 0.0, 3.0, latest=7.0) is None
    assert t.earliest_entry(1, 2, 0.0, 3.0, vehicle=2) == 5.0  # its own window is no obstacle


def test_earliest_entry_can_lead_a_slower_vehicle_booked_later():
    t = table()
    t.book(1, [], [(1, 2, 10.0, 20.0)])
    assert t.earliest_entry(1, 2, 0.0, 3.0) == 0.0  # through and out well ahead of it
    assert t.earliest_entry(1, 2, 9.0, 3.0) == 9.0  # still a gap ahead of it at both ends
    # too late to lead: it follows, entering a gap after it and leaving a gap after it
    assert t.earliest_entry(1, 2, 9.5, 3.0) == 18.0


@pytest.mark.parametrize(
    ("nodes", "segments", "match"),
    [
        ([(1, 5.0, 4.0)], [], "start <= end"),
        ([(1, math.nan, 4.0)], [], "start <= end"),
        ([(1, math.inf, math.inf)], [], "finite start"),
        ([], [(1, 2, 3.0, 1.0)], "segment 1->2"),
    ],
)
def test_a_malformed_window_is_refused(nodes, segments, match):
    t = table()
    with pytest.raises(ValueError, match=match):
        t.book(1, nodes, segments)
    assert len(t) == 0


def test_the_nodes_of_a_single_vehicle_area_share_their_windows():
    """Nodes 3 and 4 form area "dock": a vehicle on either keeps every other vehicle off
    both, with the gap; a vehicle's own windows inside the area follow each other; node 5,
    outside, is not affected; releasing the vehicle frees the whole area."""
    t = TimeWindowTable(1.0, {3: "dock", 4: "dock"})
    t.book(1, [(3, 0.0, 2.0), (4, 2.0, 6.0)], [(3, 4, 2.0, 3.0)])
    assert t.node_windows(3) == t.node_windows(4) == (Window(0.0, 2.0, 1), Window(2.0, 6.0, 1))
    assert t.safe_intervals(4, vehicle=2) == [(-math.inf, -1.0), (7.0, math.inf)]
    with pytest.raises(WindowConflict, match=r"node 3 \(area dock\)"):
        t.book(2, [(3, 6.5, 8.0)], [])  # node 3 itself is free from 2 s, the area is not
    t.book(2, [(3, 7.0, 8.0), (5, 0.0, 6.5)], [])
    assert t.node_windows(5) == (Window(0.0, 6.5, 2),)
    t.release(1)
    t.book(3, [(4, 0.0, 5.0)], [])
    assert t.vehicles == {2, 3} and len(t) == 3


def test_stored_windows_are_left_out_of_the_garbage_collectors_scans():
    """A thousand vehicles' plans hold tens of thousands of windows; stored as objects the
    collector tracks, every full collection traverses them all (tens of ms a scan)."""
    import gc

    t = table()
    for v in range(20):
        t.book(v, [(v, 2.0 * v, 2.0 * v + 1)], [(v, v + 1, 2.0 * v + 1, 2.0 * v + 1.5)])
    gc.collect()
    stored = [w for windows in (*t._nodes.values(), *t._segments.values()) for w in windows]
    assert len(stored) == 40
    assert not any(gc.is_tracked(w) for w in stored)
    assert t.node_windows(3) == (Window(6.0, 7.0, 3),)  # read back as Windows
