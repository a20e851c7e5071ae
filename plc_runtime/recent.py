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
from typing import TypeVar

T = TypeVar("T")


class RecentList(list[T]):
    """The newest entries appended (at least ``capacity`` of them, at most twice that), and
    ``total``: how many were ever appended, trimmed or not.

    Only ``append`` and ``extend`` add entries: a record is written at its end; changing an
    entry in place (``rec[i] = x``) is allowed, inserting elsewhere is not counted."""

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

    def _trim(self) -> None:
        """Keep the newest ``capacity`` entries."""
        del self[: len(self) - self.capacity]
