"""The live stream (server-sent events): one snapshot of the fleet at most ``rate_hz`` times
per wall second, shared by every client, so a slow client never slows the scan.

The scan's side, :meth:`LiveFeed.publish`, runs at the quiet point (``WebServer.read_inputs``)
and does nothing while nobody listens or before the period has passed since the last
snapshot; otherwise it copies the vehicles (their words and routes), the scan's counters,
the order counts and the orders that changed state since the last snapshot (from the book's
journal, not the whole book) and hands the copy to the server's event loop. That is all the
scan ever pays: the copy is rendered and encoded to JSON once, in the server's thread, and
every client is sent the newest one. A client that cannot keep up is not queued for: when it is ready again it gets the
newest snapshot and skips the ones it missed, so its memory is one snapshot, whatever its
speed. Each client gets a comment line every ``KEEPALIVE_S`` seconds when nothing changes,
so a proxy does not close an idle stream.

The period is wall time: the stream is for eyes, which see wall seconds, whatever the run's
``--speed``. It is the only wall-clock read on the scan's path, and it is in a driver, not a
block.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Any

from ..program import FleetProgram
from . import views
from .desk import OrderView

RATE_HZ = 10.0
MAX_STREAMS = 32  # clients streaming at once
KEEPALIVE_S = 15.0
MAX_CHANGED = 500  # orders sent per snapshot; more: the client reloads the list


class Busy(Exception):
    """Every stream place is taken."""


class LiveFeed:
    def __init__(
        self, program: FleetProgram, rate_hz: float = RATE_HZ, max_streams: int = MAX_STREAMS
    ) -> None:
        self._program = program
        self.period_s = 1.0 / rate_hz
        self.max_streams = max_streams
        self.streams = 0  # clients now; changed only in the server's loop, read by the scan
        self.published = 0  # snapshots handed over
        self._last = -float("inf")
        self._revision = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._version = 0
        self._encoded = b""
        self._changed: asyncio.Event | None = None

    # ----- the scan side --------------------------------------------------------------------
    def publish(self) -> bool:
        """A snapshot for the clients, if any listen and the period has passed."""
        loop = self._loop
        if not self.streams or loop is None:
            return False
        now = time.monotonic()
        if now - self._last < 0.9 * self.period_s:  # quiet points come once a cycle: a tenth of
            return False  # slack keeps a 50 ms cycle at 10 Hz, not every third cycle
        self._last = now
        snapshot = self._snapshot()
        try:
            loop.call_soon_threadsafe(self._arrive, snapshot)
        except RuntimeError:  # the server's loop has closed
            return False
        self.published += 1
        return True

    def _snapshot(self) -> dict[str, Any]:
        """The scan's copy: counters, the vehicles' words and routes, the closed segments,
        the orders changed (copies); rendered and encoded in the server's thread."""
        p = self._program
        snap: dict[str, Any] = {
            **views.light_stats(p),
            "fleet": views.fleet_counters(p),
            "vehicles": views.copy_vehicles(p),
            "blockades": views.blockades(p),
            "events": p.events.added,
        }
        if p.orders is not None:
            book = p.orders.book
            changed = book.changed_since(self._revision)
            self._revision = book.revision
            resync = changed is None or len(changed) > MAX_CHANGED
            snap["orders"] = {
                "counts": book.counts(),
                "resync": resync,
                "changed": [] if resync else [OrderView.of(o) for o in changed],
            }
        return snap

    # ----- the server side (its event loop) ----------------------------------------------------
    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        """The server's loop is running: snapshots go there from now on."""
        self._changed = asyncio.Event()
        self._loop = loop

    def detach(self) -> None:
        """The run ends: every stream ends (its client sees the end of the response)."""
        loop, self._loop = self._loop, None
        if loop is not None:
            try:
                loop.call_soon_threadsafe(self._end)
            except RuntimeError:  # the loop has closed already: no stream is left
                pass

    def _end(self) -> None:
        changed, self._changed = self._changed, None
        if changed is not None:
            changed.set()

    def _arrive(self, snapshot: dict[str, Any]) -> None:
        snapshot["vehicles"] = views.render_vehicles(snapshot["vehicles"])
        if "orders" in snapshot:
            orders = snapshot["orders"]
            orders["changed"] = [views.order(o) for o in orders["changed"]]
        self._version += 1
        self._encoded = f"event: snapshot\ndata: {json.dumps(snapshot)}\n\n".encode()
        changed, self._changed = self._changed, asyncio.Event()
        if changed is not None:
            changed.set()

    def open_stream(self) -> AsyncIterator[bytes]:
        """A client's stream (Busy when every place is taken). The place is taken when the
        stream starts and given back when it ends, however it ends."""
        if self.streams >= self.max_streams:
            raise Busy(f"{self.streams} clients are streaming already (the limit)")
        return self._stream()

    async def _stream(self) -> AsyncIterator[bytes]:
        self.streams += 1
        try:
            yield b"retry: 1000\n\n"
            seen = 0
            while True:
                if self._version != seen and self._encoded:
                    seen = self._version
                    yield self._encoded
                    continue
                changed = self._changed
                if changed is None:
                    return
                try:
                    await asyncio.wait_for(changed.wait(), KEEPALIVE_S)
                except TimeoutError:
                    yield b": keep-alive\n\n"
        finally:
            self.streams -= 1
