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
answer are woken through the gate too. The server's loop looks every ``poll_s`` (5 ms)
whether a scan has ended; the scan never wakes it (see ``_poll``).

When no scan ends within ``timeout`` seconds (the controller is stopping or stopped, or
its scans are slow), a request goes in anyway; if the scan does not answer it either, the
desks' timeout answers ("controller not scanning").
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable

POLL_S = 0.005  # how often the server's loop looks whether a scan has ended


class ScanGate:
    def __init__(self, timeout: float, poll_s: float = POLL_S) -> None:
        self.timeout = timeout
        self.poll_s = poll_s
        self.waiting = 0  # requests at the gate; changed only in the server's loop
        self._loop: asyncio.AbstractEventLoop | None = None
        self._open: asyncio.Event | None = None
        self._ended = 0  # scans ended; written by the scan thread only
        self._news: deque[Callable[[], None]] = deque()  # from the scan, for the loop
        self._poller: asyncio.Task | None = None

    # ----- the server's loop ---------------------------------------------------------------
    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self._open = asyncio.Event()
        self._loop = loop
        self._poller = loop.create_task(self._poll())

    async def _poll(self) -> None:
        """Every ``poll_s``: if a scan has ended since, hand over its news and let the
        waiters go on. The loop looks for itself rather than being woken by the scan:
        waking it (a byte to its self-pipe) releases the interpreter inside the scan, and
        a server thread that wants it then takes it and works while the scan waits."""
        seen = self._ended
        while self._open is not None:
            await asyncio.sleep(self.poll_s)
            if self._ended != seen:
                seen = self._ended
                while self._news:
                    self._news.popleft()()
                self._release()

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
        """A scan has ended: the waiting requests go on, after ``news`` (the scan's other
        news for the server) runs in the server's loop, at its next look. No system call,
        so the scan keeps the interpreter."""
        if news is not None:
            self._news.append(news)
        self._ended += 1

    def detach(self) -> None:
        """The run ends: every waiter goes on, and later ones do not wait."""
        loop, self._loop = self._loop, None
        if loop is not None:
            try:
                loop.call_soon_threadsafe(self._release, False)
            except RuntimeError:
                pass
