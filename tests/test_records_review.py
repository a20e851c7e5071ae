"""Records that keep their newest entries (``plc_runtime.recent.RecentList``): copies,
entries added other than at the end, and the reports read from them once they were
trimmed."""

from __future__ import annotations

import copy
import pickle

import pytest

from plc_runtime.recent import RecentList


def trimmed() -> RecentList[int]:
    kept = RecentList(3, range(10))
    assert kept == [7, 8, 9] and kept.total == 10
    return kept


@pytest.mark.parametrize(
    "clone",
    [copy.copy, copy.deepcopy, lambda r: pickle.loads(pickle.dumps(r))],
    ids=["copy", "deepcopy", "pickle"],
)
def test_a_copy_of_a_recent_list_keeps_its_entries_count_and_capacity(clone):
    kept = trimmed()
    other = clone(kept)
    assert isinstance(other, RecentList)
    assert other == [7, 8, 9] and other.total == 10 and other.capacity == 3
    other.append(10)
    assert kept.total == 10 and other.total == 11  # a copy, not the same record


@pytest.mark.parametrize(
    "grow",
    [
        lambda r: r.insert(0, 99),
        lambda r: r.__setitem__(slice(len(r), len(r)), range(20)),
        lambda r: r.__imul__(10),
    ],
    ids=["insert", "slice", "imul"],
)
def test_entries_are_added_at_the_end_only_counted_and_trimmed(grow):
    """An entry added another way would be neither counted nor ever trimmed."""
    kept = trimmed()
    with pytest.raises(TypeError):
        grow(kept)
    assert kept == [7, 8, 9] and kept.total == 10


def test_changing_entries_in_place_is_still_allowed():
    kept = trimmed()
    kept[0] = 70
    kept[1:3] = [80, 90]
    assert kept == [70, 80, 90] and kept.total == 10
