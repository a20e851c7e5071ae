"""QuietSelector: an event loop whose work falls between scans.

A driver that serves clients from a thread of its own shares the interpreter with the scan:
whatever its loop computes while a scan runs (decoding a request, building its answer)
holds the lock the scan needs, and the scan's execution time grows by it. A PLC puts its
communication load where the cycle has time to spare. This selector does the same for an
asyncio loop: whatever wakes the loop (a request arriving, a timer), the loop waits until
no scan runs (``Runtime.between_scans``) before it does anything, so a scan pays at most
for handing the interpreter over once, not for the server's work. When no scan ends within
``timeout`` seconds (the runtime is stopping, or its scans are slow), the loop goes on;
``release()`` ends the waiting for good, so a server shutting down is not held by scans.

    with asyncio.Runner(
        loop_factory=lambda: asyncio.SelectorEventLoop(QuietSelector(rt.between_scans, 0.5))
    ) as runner:
        runner.run(serve())
"""

from __future__ import annotations

import selectors
import threading


class QuietSelector(selectors.DefaultSelector):
    """A selector that, after every wake-up, waits (at most ``timeout`` seconds) until
    ``between_scans`` is set."""

    def __init__(self, between_scans: threading.Event, timeout: float) -> None:
        super().__init__()
        self._between_scans = between_scans
        self._timeout = timeout
        self._released = False

    def release(self) -> None:
        """Wait no more (from any thread): the server is shutting down, and its loop's
        last wake-ups must not each wait for a scan, however long the cycle."""
        self._released = True

    def select(self, timeout: float | None = None) -> list:
        ready = super().select(timeout)
        if not self._released:
            self._between_scans.wait(self._timeout)
        return ready
