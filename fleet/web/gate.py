"""ScanGate: requests enter the application only right after a scan has ended.

The server's thread shares the interpreter with the scan. Whatever it computes while a
scan runs (routing a request, checking its parameters, building its answer) holds the
interpreter's lock that the scan needs, and the scan's execution time grows by it. A PLC
puts its communication load where the cycle has time to spare; this does the same, in two
parts:

* ``plc_runtime.quiet.QuietSelector``: whatever wakes the server's loop (a request
  arriving, a timer), the loop waits until no scan runs (``Runtime.between_scans``) before
  it does anything. A scan pays at most for handing the interpreter over once, not for the
  server's work.
* :class:`ScanGate`: a request that arrives is read and checked by the guard (host, rate,
  token, size: cheap), then waits here until the end of the next scan, and runs its
  handler in the time before the following one, where the scan waits for its release
  anyway. The handler's own question to the scan is answered at the end of the scan after
  that, so a request takes one to two cycles, as a request to a PLC's communication
  processor does. Handlers waiting for their answer are woken through the gate too.

The scan only notes that it has ended (``scan_ended``, no system call); the server's loop
is woken after the scan (``after_scan``, which the runtime calls once the scan's time is
recorded), and only when a request waits or the scan has news for it.

When no scan ends within ``timeout`` seconds (the controller is stopping or stopped, or
its scans are slow), a request goes in anyway; if the scan does not answer it either, the
desks' timeout answers ("controller not scanning").
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable


class ScanGate:
    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.waiting = 0  # requests at the gate; changed only in the server's loop
        self._loop: asyncio.AbstractEventLoop | None = None
        self._open: asyncio.Event | None = None
        self._news: deque[Callable[[], None]] = deque()  # from the scan, for the loop

    # ----- the server's loop ---------------------------------------------------------------
    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self._open = asyncio.Event()
        self._loop = loop

    async def wait(self, timeout: float | None = None) -> bool:
        """Until the end of the next scan, or ``timeout`` (default: the gate's); False at
        once when the gate is closed for good (the run is ending)."""
        opened = self._open
        if opened is None:
            return False
        self.waiting += 1
        try:
            await asyncio.wait_for(opened.wait(), self.timeout if timeout is None else timeout)
        except TimeoutError:
            pass
        finally:
            self.waiting -= 1
        return True

    def _scan_over(self) -> None:
        """The scan's news, then every waiter goes on."""
        while self._news:
            self._news.popleft()()
        self._release()

    def _release(self, again: bool = True) -> None:
        opened, self._open = self._open, asyncio.Event() if again else None
        if opened is not None:
            opened.set()

    # ----- the scan thread -----------------------------------------------------------------
    def scan_ended(self, news: Callable[[], None] | None = None) -> None:
        """In the scan, at its end: ``news`` (the scan's other news for the server) is to
        run in the server's loop before the waiting requests go on. No system call, so the
        scan keeps the interpreter."""
        if news is not None:
            self._news.append(news)

    def after_scan(self) -> None:
        """After the scan (its time recorded): wake the server's loop if a request waits
        (``waiting`` is read without a lock: one that starts waiting just now is let go
        at the next scan's end) or the scan left news."""
        loop = self._loop
        if loop is None or not (self.waiting or self._news):
            return
        try:
            loop.call_soon_threadsafe(self._scan_over)
        except RuntimeError:  # the loop has closed: the run is ending
            pass

    def detach(self) -> None:
        """The run ends: every waiter goes on, and later ones do not wait."""
        loop, self._loop = self._loop, None
        if loop is not None:
            try:
                loop.call_soon_threadsafe(self._release, False)
            except RuntimeError:
                pass
