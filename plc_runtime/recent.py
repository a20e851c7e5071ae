"""A list that keeps only its newest entries, and counts every entry ever appended.

A controller runs for months: a record appended to once per event (a node reached, a job
finished, a conflict seen) would grow with the run time until memory runs out. Such a record
is wanted for its newest entries (a drawing, a report of the last hours) and for exact
counts; ``RecentList`` keeps the first bounded and the second exact (``total``).

It is a ``list``, so indexing, slicing, iteration and comparison with a list work as before,
over the entries kept. It trims the oldest entries in one slice deletion once it holds twice
its ``capacity``: appending stays amortised O(1) (a ``deque`` with ``maxlen`` would drop one
per append but cannot be sliced), and it never holds more than ``2 * capacity`` entries.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import SupportsIndex, TypeVar

T = TypeVar("T")


class RecentList(list[T]):
    """The newest entries appended (at least ``capacity`` of them, at most twice that), and
    ``total``: how many were ever appended, trimmed or not.

    Only ``append``, ``extend`` and ``+=`` add entries: a record is written at its end.
    Changing entries in place (``rec[i] = x``, a slice assigned as many) is allowed; adding
    them any other way (``insert``, a slice assigned more, ``*=``) is a TypeError, as it
    would be neither counted nor trimmed. A copy (``copy``, ``deepcopy``, ``pickle``) keeps
    the entries, ``capacity`` and ``total``."""

    def __init__(self, capacity: int, entries: Iterable[T] = ()) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        super().__init__()
        self.capacity = capacity
        self.total = 0
        self.extend(entries)

    @property
    def dropped(self) -> int:
        """Entries appended and no longer kept (the oldest ones)."""
        return self.total - len(self)

    def append(self, entry: T) -> None:
        super().append(entry)
        self.total += 1
        if len(self) > 2 * self.capacity:
            self._trim()

    def extend(self, entries: Iterable[T]) -> None:
        before = len(self)
        super().extend(entries)
        self.total += len(self) - before
        if len(self) > 2 * self.capacity:
            self._trim()

    def __iadd__(self, entries: Iterable[T]) -> RecentList[T]:  # type: ignore[override]
        self.extend(entries)
        return self

    def insert(self, index: SupportsIndex, entry: T) -> None:
        raise TypeError("a RecentList is written at its end: append or extend")

    def __setitem__(self, index, value) -> None:  # type: ignore[override]
        if isinstance(index, slice):
            value = list(value)
            if len(range(*index.indices(len(self)))) != len(value):
                raise TypeError("a RecentList is written at its end: append or extend")
        super().__setitem__(index, value)

    def __imul__(self, n: SupportsIndex) -> RecentList[T]:  # type: ignore[override]
        raise TypeError("a RecentList is written at its end: append or extend")

    def __reduce__(self):
        # list's own reduction appends the entries to a copy not yet initialised (pickle)
        # or after its total was copied (copy): counted twice, or no total to count in
        return (_restore, (type(self), self.capacity, list(self), self.total))

    def _trim(self) -> None:
        """Keep the newest ``capacity`` entries."""
        del self[: len(self) - self.capacity]


def _restore(cls: type[RecentList], capacity: int, entries: list, total: int) -> RecentList:
    """A copy of a ``RecentList`` (``RecentList.__reduce__``)."""
    kept = cls(capacity)
    list.extend(kept, entries)
    kept.total = total
    return kept
