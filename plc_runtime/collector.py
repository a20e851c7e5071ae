"""The garbage collector's young-generation threshold during the cyclic phase.

CPython runs a young collection every 700 net allocations of container objects. One scan
of a large program allocates tens of thousands of short-lived ones, so young collections
run in the middle of scans, while the scan's temporaries are still alive. They survive,
are promoted to the oldest generation, die there, and count towards the next full
collection. A full collection traverses every object the program holds (tens of
milliseconds for a program of several thousand function-block instances) and lands in
whichever scan happens to allocate then: the scan-time spikes a cycle has to absorb.

Raising the generation-0 threshold above what a scan allocates lets reference counting
free the temporaries before a young collection sees them. Few objects are promoted, and
full collections become rare. Each young collection traverses more objects, but the total
work falls, since it no longer copies the same temporaries scan after scan.

The threshold is process-wide. The runtime raises it when its cyclic phase begins (never
lowers it) and puts the old value back when it stops, unless something else changed it
meanwhile.
"""

from __future__ import annotations

import gc

from .errors import ConfigError

# Above what one scan of the largest program measured allocates (several thousand
# function-block instances): a full collection then no longer lands in its scans
# (docs/runtime.md)
DEFAULT_YOUNG_THRESHOLD = 10_000


def _checked(value: object) -> int | None:
    """``value`` as a generation-0 threshold: an int >= 1, or None (Python's own)."""
    if value is None:
        return None
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return value
    raise ConfigError(
        f"gc_threshold must be a whole number of allocations >= 1, or None, got {value!r}"
    )


class YoungThreshold:
    """Raises the generation-0 threshold for a cyclic phase and restores it afterwards."""

    def __init__(self, threshold: int | None) -> None:
        self.threshold = _checked(threshold)
        self._saved: tuple[int, ...] | None = None
        self._set: tuple[int, ...] | None = None

    def enter(self) -> None:
        current = gc.get_threshold()
        if self.threshold is None or self.threshold <= current[0]:
            return
        self._saved = current
        self._set = (self.threshold, *current[1:])
        gc.set_threshold(*self._set)

    def exit(self) -> None:
        if self._set is not None and gc.get_threshold() == self._set:
            gc.set_threshold(*self._saved)
        self._saved = self._set = None
