"""``RecentList``: the newest entries of a record appended to for months, and an exact count
of all of them."""

from __future__ import annotations

import pytest

from plc_runtime.recent import RecentList


def test_a_recent_list_keeps_the_newest_entries_and_counts_all():
    kept = RecentList(3)
    lengths = []
    for k in range(20):
        kept.append(k)
        lengths.append(len(kept))
    assert max(lengths) == 6  # never more than twice the capacity
    assert min(lengths[3:]) == 3  # never fewer than the capacity, once it held that many
    assert kept.total == 20 and kept.dropped == 20 - len(kept)
    assert kept == list(range(20 - len(kept), 20))  # the newest, oldest first
    assert kept[-1] == 19 and kept[-2:] == [18, 19]


def test_a_recent_list_counts_what_is_extended_or_added_and_what_it_starts_with():
    kept = RecentList(2, [1, 2, 3])
    assert kept.total == 3 and kept == [1, 2, 3]
    kept.extend(range(4, 6))
    assert kept.total == 5 and kept == [4, 5]  # five held: more than twice two, trimmed
    kept += [6]
    assert kept.total == 6 and kept == [4, 5, 6]
    assert isinstance(kept, RecentList)  # ``+=`` kept the type, and its capacity
    assert RecentList(4) == [] and RecentList(4).total == 0


def test_a_recent_list_needs_room_for_one_entry():
    with pytest.raises(ValueError, match="capacity"):
        RecentList(0)
