"""ScanGate: requests enter the application only right after a scan has ended.

The server's thread shares the interpreter with the scan. Whatever it computes while a
scan runs (routing a request, checking its parameters, building its answer) holds the
interpreter's lock that the scan needs, and the scan's execution time grows by it. A PLC
puts its communication load where the cycle has time to spare; this does the same: a
request that arrives is read and checked by the guard (host, rate, token, size: cheap),
then waits here until the end of the next scan, and runs its handler in the time before
the following one, where the scan waits for its release anyway. The handler's own question
to the scan is answered at the end of the scan after that, so a request takes one to two
cycles, as a request to a PLC's communication processor does. Handlers waiting for their
answer are woken through the gate too: once at the end of a scan, never in its middle.

When no scan ends within ``timeout`` seconds (the controller is stopping or stopped, or
its scans are slow), a request goes in anyway; if the scan does not answer it either, the
desks' timeout answers ("controller not scanning").
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable


class ScanGate:
    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.waiting = 0  # requests at the gate; changed only in the server's loop
        self._loop: asyncio.AbstractEventLoop | None = None
        self._open: asyncio.Event | None = None

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

    def _release(self, again: bool = True) -> None:
        opened, self._open = self._open, asyncio.Event() if again else None
        if opened is not None:
            opened.set()

    # ----- the scan thread -----------------------------------------------------------------
    def scan_ended(self, news: Callable[[], None] | None = None) -> None:
        """Let the waiting requests in, after running ``news`` in the server's loop (the
        scan's other news for it): one wake-up, and none when nobody waits and there is no
        news. The wake-up is the last thing the scan does for the server: the moment it
        signals, the server's thread wants the interpreter, and the scan has no more work
        that it would delay."""
        loop = self._loop
        if (self.waiting or news is not None) and loop is not None:
            try:
                loop.call_soon_threadsafe(self._ended, news)
            except RuntimeError:  # the loop has closed: nobody waits any more
                pass

    def _ended(self, news: Callable[[], None] | None) -> None:
        if news is not None:
            news()
        self._release()

    def detach(self) -> None:
        """The run ends: every waiter goes on, and later ones do not wait."""
        loop, self._loop = self._loop, None
        if loop is not None:
            try:
                loop.call_soon_threadsafe(self._release, False)
            except RuntimeError:
                pass
