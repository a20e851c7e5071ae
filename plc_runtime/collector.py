"""The garbage collector during the cyclic phase: young collections rarer, full ones between
scans.

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

A program that holds many objects makes a full collection long whatever it allocates: a
program that keeps 700,000 container objects (100,000 records of some seven objects each)
makes one full pass take 0.1-0.4 s, more than a 150 ms watchdog allows. CPython runs one
whenever the objects that survived into the oldest generation have grown by a quarter
since the last (a program taking in a large file of records grows them so, again and
again).
``FullCollections`` takes that decision out of the scans: automatic full collections are
off while the cyclic phase runs, and the runtime makes one after a scan, outside its time
and watchdog, once the interpreter's allocated memory blocks have grown by a quarter since
the last. On the wall clock its time delays the next release (counted as lateness, as
retain saves are); on a virtual clock it costs wall time only.

Both settings are process-wide. The runtime changes them when its cyclic phase begins
(raising, never lowering) and puts the old values back when it stops, unless something else
changed them meanwhile. While automatic full collections are off, every runtime running
with this policy makes them after its scans; with the garbage collector disabled (the wall
clock's rt mode collects in idle time itself) none does.
"""

from __future__ import annotations

import gc
import sys
from collections.abc import Callable

from .errors import ConfigError

# Above what one scan of the largest program measured allocates (several thousand
# function-block instances): a full collection then no longer lands in its scans
# (docs/runtime.md)
DEFAULT_YOUNG_THRESHOLD = 10_000
# the oldest generation's threshold while full collections are the runtime's: never reached
SUSPENDED = 2**31 - 1
# CPython's own rule: a full collection once what survived has grown by a quarter
GROWTH = 1.25


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


class FullCollections:
    """Suspends automatic full collections for a cyclic phase and makes them between scans.

    ``blocks``: the measure of the heap whose growth calls for a full collection (the
    interpreter's allocated memory blocks; tests give their own).
    """

    def __init__(self, enabled: bool, blocks: Callable[[], int] = sys.getallocatedblocks) -> None:
        self.enabled = enabled
        self.blocks = blocks
        self.collections = 0  # made after a scan by this runtime
        self._saved: tuple[int, ...] | None = None
        self._set: tuple[int, ...] | None = None
        self._baseline = 0
        self._promotions = 0

    def enter(self) -> None:
        if not self.enabled or not gc.isenabled():
            return  # (disabled: whoever disabled it collects)
        self._baseline = self.blocks()
        self._promotions = gc.get_count()[2]
        current = gc.get_threshold()
        if current[2] >= SUSPENDED:
            return  # (another runtime suspended them: it puts them back)
        self._saved = current
        self._set = (*current[:2], SUSPENDED)
        gc.set_threshold(*self._set)

    def after_scan(self) -> bool:
        """Between two scans: a full collection if the heap has grown enough; True if so.

        Objects reach the oldest generation only in a generation-1 collection, so the heap
        is measured (which walks the interpreter's memory arenas) only after one ran."""
        if not self.enabled or not gc.isenabled() or gc.get_threshold()[2] < SUSPENDED:
            return False
        promotions = gc.get_count()[2]  # generation-1 collections since the last full one
        if promotions == self._promotions:
            return False
        self._promotions = promotions
        if self.blocks() < self._baseline * GROWTH:
            return False
        gc.collect()
        self.collections += 1
        self._baseline = self.blocks()
        self._promotions = gc.get_count()[2]
        return True

    def exit(self) -> None:
        if self._set is not None and gc.get_threshold() == self._set:
            gc.set_threshold(*self._saved)
        self._saved = self._set = None
