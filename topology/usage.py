"""How often each plant segment was driven: the heat map's counts.

A segment counts both directions together, keyed (lower id, higher id), and a step between
nodes that share no segment (a position lost and found again) is not a segment driven. A
controller that keeps only its vehicles' newest nodes counts step by step as they drive
(``SegmentUsage.step``); a drawing handed whole paths counts them at once
(``segment_usage``). Both count the same way, so a heat map from either agrees.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence
from itertools import pairwise

from .model import Plant

Segment = tuple[int, int]


def segment_key(a: int, b: int) -> Segment:
    """The key of the segment between ``a`` and ``b``, whichever way it is driven."""
    return (min(a, b), max(a, b))


class SegmentUsage:
    """Times each segment of ``plant`` was driven (``counts``), step by step."""

    def __init__(self, plant: Plant) -> None:
        self._segments = frozenset(segment_key(e.source, e.target) for e in plant.edges)
        self.counts: Counter[Segment] = Counter()

    def step(self, a: int, b: int) -> None:
        """A vehicle drove from ``a`` to ``b``: count it if that is a plant segment."""
        if a != b and (key := segment_key(a, b)) in self._segments:
            self.counts[key] += 1

    def add_path(self, path: Sequence[int]) -> None:
        for a, b in pairwise(path):
            self.step(a, b)


def segment_usage(plant: Plant, paths: Iterable[Sequence[int]]) -> dict[Segment, int]:
    """Times each plant segment was driven along ``paths``."""
    usage = SegmentUsage(plant)
    for path in paths:
        usage.add_path(path)
    return dict(usage.counts)
