"""The live stream (server-sent events): one snapshot of the fleet at most ``rate_hz`` times
per wall second, shared by every client, so a slow client never slows the scan.

The scan's side, :meth:`LiveFeed.due_snapshot`, runs at the end of every scan
(``WebServer.write_outputs``) and does nothing while nobody listens or before the period
has passed since the last snapshot; otherwise it copies the vehicles (their words and
routes), the scan's counters, the order counts and the orders that changed state since
the last snapshot (from the book's journal, not the whole book) and hands the copy to the
server's event loop. That is all the scan ever pays: the copy is rendered and encoded to
JSON once, in the server's thread, and every client is sent the newest one.

A snapshot names only the vehicles that changed since the one before (``"full": false``;
most vehicles stand or drive on between two snapshots), so a hundred vehicles cost some
kilobytes a snapshot, not fifty. A client gets the whole snapshot (``"full": true``, every
vehicle, and ``"resync": true`` for the orders) when it is new or has missed one, so it can
always rebuild the picture from what it gets. Speeds are not streamed (they change every
snapshot while a vehicle speeds up or brakes); ``GET /vehicles`` has them.

A client that cannot keep up is not queued for: when it is ready again it gets the newest
snapshot, whole, and skips the ones it missed, so its memory is one snapshot, whatever its
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
from collections.abc import AsyncGenerator
from typing import Any

from ..program import FleetProgram
from . import views
from .desk import OrderView

RATE_HZ = 10.0
MAX_STREAMS = 32  # clients streaming at once
KEEPALIVE_S = 15.0
MAX_CHANGED = 500  # orders sent per snapshot; more: the client reloads the list


def _event(snapshot: dict[str, Any]) -> bytes:
    return f"event: snapshot\ndata: {json.dumps(snapshot, separators=(',', ':'))}\n\n".encode()


class Busy(Exception):
    """Every stream place is taken."""


class LiveFeed:
    def __init__(
        self,
        program: FleetProgram,
        rate_hz: float = RATE_HZ,
        max_streams: int = MAX_STREAMS,
        fleet_copy: views.FleetCopy | None = None,
    ) -> None:
        self._program = program
        self._fleet_copy = fleet_copy or views.FleetCopy(program)
        self._segments = views.ClosedSegments(program)
        self.period_s = 1.0 / rate_hz
        self.max_streams = max_streams
        self.streams = 0  # clients now; changed only in the server's loop, read by the scan
        self.published = 0  # snapshots handed over
        self._last = -float("inf")
        self._revision = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._version = 0  # snapshots arrived in the server's loop
        self._base: dict[str, Any] = {}  # the newest snapshot but its vehicles
        self._vehicles: dict[int, dict[str, Any]] = {}  # the newest rendered vehicles
        self._delta = b""  # the newest snapshot, with the vehicles that changed only
        self._whole = b""  # the same with every vehicle (encoded when a client needs it)
        self._changed: asyncio.Event | None = None

    # ----- the scan side --------------------------------------------------------------------
    def due_snapshot(self) -> dict[str, Any] | None:
        """A snapshot for the clients, if any listen and the period has passed (else None):
        the caller hands it to the server's loop (:meth:`arrive`) through the scan gate,
        which wakes the loop after the scan, not inside it."""
        if not self.streams or self._loop is None:
            return None
        now = time.monotonic()
        if now - self._last < 0.9 * self.period_s:  # asked once a cycle: a tenth of slack
            return None  # keeps a 50 ms cycle at 10 Hz, not every third cycle
        self._last = now
        self.published += 1
        return self._snapshot()

    def _snapshot(self) -> dict[str, Any]:
        """The scan's copy: counters, the vehicles' words and routes, the closed segments,
        the orders changed (copies); rendered and encoded in the server's thread."""
        p = self._program
        snap: dict[str, Any] = {
            **views.light_stats(p),
            "fleet": views.fleet_counters(p),
            "vehicles": self._fleet_copy(),
            "blockades": self._segments(),
            "events": p.events.added,
        }
        if p.orders is not None:
            book = p.orders.book
            # (an order that ended and left the book since is told in its final state)
            changed = book.changed_since(self._revision, swept=True)
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

    def arrive(self, snapshot: dict[str, Any]) -> None:
        """A new snapshot from the scan: rendered, and its delta encoded at once (every
        client that kept up gets it); the whole one only when a client needs it."""
        vehicles = views.render_vehicles(snapshot.pop("vehicles"))
        for v in vehicles:
            del v["speed_cm_s"]  # changes every snapshot while a vehicle speeds up or brakes
        if "orders" in snapshot:
            orders = snapshot["orders"]
            orders["changed"] = [views.order(o) for o in orders["changed"]]
        changed = [v for v in vehicles if self._vehicles.get(v["id"]) != v]
        self._vehicles = {v["id"]: v for v in vehicles}
        self._version += 1
        self._base = snapshot
        self._delta = _event({**snapshot, "full": False, "vehicles": changed})
        self._whole = b""
        changed_event, self._changed = self._changed, asyncio.Event()
        if changed_event is not None:
            changed_event.set()

    def _whole_snapshot(self) -> bytes:
        """The newest snapshot with every vehicle, for a client that is new or missed one;
        its orders say ``resync``: the changes it missed are only in the book."""
        if not self._whole:
            whole = {**self._base, "full": True, "vehicles": list(self._vehicles.values())}
            if "orders" in whole:
                whole["orders"] = {**whole["orders"], "resync": True, "changed": []}
            self._whole = _event(whole)
        return self._whole

    def open_stream(self) -> Stream:
        """A client's stream (Busy when every place is taken). Its place is taken here,
        where it is checked, so clients that come all at once cannot all pass the check
        before any stream has started; :meth:`Stream.close` gives it back."""
        if self.streams >= self.max_streams:
            raise Busy(f"{self.streams} clients are streaming already (the limit)")
        return Stream(self)

    async def _events(self) -> AsyncGenerator[bytes, None]:
        yield b"retry: 1000\n\n"
        seen = 0
        while True:
            if self._version != seen:
                kept_up = seen and seen == self._version - 1
                seen = self._version
                yield self._delta if kept_up else self._whole_snapshot()
                continue
            changed = self._changed
            if changed is None:
                return
            try:
                await asyncio.wait_for(changed.wait(), KEEPALIVE_S)
            except TimeoutError:
                yield b": keep-alive\n\n"


class Stream:
    """A client's place among the streams, and its events (``events``). Whoever opens it
    closes it, however the response ends: at its end, on an error, or before it has
    started (a generator never started runs no ``finally``, so it cannot be trusted to
    give the place back itself)."""

    def __init__(self, feed: LiveFeed) -> None:
        feed.streams += 1
        self._feed: LiveFeed | None = feed
        self.events = feed._events()

    async def close(self) -> None:
        """Give the place back (once) and end the events."""
        feed, self._feed = self._feed, None
        if feed is not None:
            feed.streams -= 1
        await self.events.aclose()
