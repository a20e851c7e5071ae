"""The interface between the scan and bus drivers (CAN, Modbus, ...).

The runtime calls every driver once per base tick, in the scan thread: ``read_inputs`` at
the quiet point before copy-in (the driver writes what arrived into the field inputs, so
the program sees it from this cycle's snapshot on) and ``write_outputs`` after copy-out
(the driver sends what the published outputs say). ``now_ns`` is the IEC time of the tick.
A driver must never block: bounded work, no waiting, no retries inside the cycle; bad
frames are counted, not raised. An exception from a driver is a programming error and
faults the runtime like one from a block.
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
