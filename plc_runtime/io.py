"""The interface between the scan and bus drivers (CAN, Modbus, ...).

The runtime calls every driver once per base tick, in the scan thread: ``read_inputs`` at
the quiet point before copy-in (the driver writes what arrived into the field inputs, so
the program sees it from this cycle's snapshot on) and ``write_outputs`` after copy-out
(the driver sends what the published outputs say). ``now_ns`` is the IEC time of the tick.
A driver must never block: bounded work, no waiting, no retries inside the cycle; bad
frames are counted, not raised. An exception from a driver is a programming error and
faults the runtime like one from a block.

A driver that serves clients from a thread of its own (an HMI or web server) may also
define ``after_scan()``: the runtime calls it after each scan, once the scan's time is
recorded, outside the watchdog, just before the scan thread waits for its next release.
That is the moment to wake the server's thread: woken from inside a scan, it would work
while the scan runs and take the interpreter from it. Such a thread should also wait on
``Runtime.between_scans`` before it works, for what wakes it by itself (its sockets), and
the driver may ask for a ``Runtime.ask_quiet_lead``: the event then clears that long
before each scan is due, so work is not started that would run into the scan. For both,
such a driver may define ``added_to(runtime)``: ``Runtime.add_driver`` calls it with the
runtime it was added to (``plc_runtime.quiet`` has a selector for an asyncio loop that
waits on the event).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from .image import ProcessImage


@runtime_checkable
class IoDriver(Protocol):
    name: str

    def open(self, image: ProcessImage) -> None:
        """Connect (called in the startup phase); raise PlcError with a clear message if not possible."""

    def read_inputs(self, image: ProcessImage, now_ns: int) -> None: ...

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None: ...

    def close(self) -> None:
        """Disconnect and release every socket/thread (called on stop, also after a fault)."""

    def stats(self) -> dict[str, object]: ...
