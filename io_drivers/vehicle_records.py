"""The per-vehicle records in the process image (docs/protocol.md), shared by every vehicle
link (CAN, Modbus): one layout, whatever bus carries it.

Inputs at ``input_base + 8 * v``: WORD current node, WORD next node, BYTE state, BYTE
battery %, BYTE speed cm/s, BYTE flags (online, stale, fault, clear of the current node). Outputs at
``output_base + 8 * v``: WORD next nodes 1..3, BYTE count (bits 0-1) | go (bit 7), BYTE
sequence. Input writes happen in the scan thread at the quiet point; outputs are read
after copy-out, and only records that changed since the last tick are looked at.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from plc_runtime import ConfigError, ProcessImage

from .protocol import MAX_VEHICLE_ID, NO_NODE, STATE_CODE, Status

RECORD = 8
ONLINE, STALE, FAULT, CLEAR = 0x01, 0x02, 0x04, 0x08
GO_BIT, COUNT_MASK = 0x80, 0x03


class VehicleRecords:
    def __init__(
        self,
        image: ProcessImage,
        vehicles: Iterable[int],
        input_base: int,
        output_base: int,
        stale_after_ns: int,
    ) -> None:
        self.vehicles = sorted(set(vehicles))
        if not self.vehicles or not all(1 <= v <= MAX_VEHICLE_ID for v in self.vehicles):
            raise ConfigError(f"vehicle ids must be 1..{MAX_VEHICLE_ID}, got {self.vehicles}")
        if input_base % 2 or output_base % 2:
            raise ConfigError("input_base and output_base must be even (word aligned)")
        top = RECORD * (self.vehicles[-1] + 1)
        if input_base + top > image.sizes["I"] or output_base + top > image.sizes["Q"]:
            raise ConfigError(
                f"vehicle records up to id {self.vehicles[-1]} do not fit the I/Q sizes {image.sizes}"
            )
        self._in = {v: self._input_writers(image, input_base + RECORD * v) for v in self.vehicles}
        self._out = {
            v: self._output_readers(image, output_base + RECORD * v) for v in self.vehicles
        }
        first = output_base + RECORD * self.vehicles[0]
        self._block = image.published_outputs.bytes[first : output_base + top].reshape(-1, RECORD)
        owner = {(output_base + RECORD * v - first) // RECORD: v for v in self.vehicles}
        self._row_vehicle = [owner.get(r) for r in range(len(self._block))]
        self._last = np.full(
            self._block.shape, -1, dtype=np.int16
        )  # differs from every byte: first tick sees all
        self._flags: dict[int, int] = {}
        self.stale_after_ns = stale_after_ns
        self.status: dict[int, Status] = {}  # the last status of each vehicle that reported
        self._last_seen: dict[int, int] = {}
        self._first_ns: int | None = None
        self._now_ns = 0

    @staticmethod
    def _input_writers(image: ProcessImage, base: int) -> dict:
        return {
            "current": image.field_writer(f"%IW{base // 2}"),
            "next": image.field_writer(f"%IW{base // 2 + 1}"),
            "state": image.field_writer(f"%IB{base + 4}"),
            "battery": image.field_writer(f"%IB{base + 5}"),
            "speed": image.field_writer(f"%IB{base + 6}"),
            "flags": image.field_writer(f"%IB{base + 7}"),
        }

    @staticmethod
    def _output_readers(image: ProcessImage, base: int) -> dict:
        return {
            "nodes": [image.output_reader(f"%QW{base // 2 + k}") for k in range(3)],
            "control": image.output_reader(f"%QB{base + 6}"),
            "sequence": image.output_reader(f"%QB{base + 7}"),
        }

    def __contains__(self, vehicle: int) -> bool:
        return vehicle in self._in

    # ----- liveness -------------------------------------------------------------------------
    def received(self, status: Status, now_ns: int) -> None:
        """A fresh status arrived (in the tick at ``now_ns``): write it into the record."""
        self.status[status.vehicle] = status
        self._last_seen[status.vehicle] = now_ns
        self.write_status(status)

    def refresh_flags(self, now_ns: int) -> None:
        """Once per tick, after the statuses: online/stale/fault flags of every vehicle. A vehicle
        that never reported goes stale ``stale_after`` after the first tick."""
        self._now_ns = now_ns
        if self._first_ns is None:
            self._first_ns = now_ns
        for v in self.vehicles:
            status = self.status.get(v)
            stale = self.is_stale(v)
            if status is not None or stale:
                self.write_flags(
                    v, stale, bool(status and status.fault), bool(status and status.clear)
                )

    def is_stale(self, vehicle: int) -> bool:
        last = self._last_seen.get(
            vehicle, self._first_ns if self._first_ns is not None else self._now_ns
        )
        return self._now_ns - last > self.stale_after_ns

    def stale(self) -> list[int]:
        return [v for v in self.vehicles if self.is_stale(v)]

    # ----- the records ------------------------------------------------------------------------
    def write_status(self, status: Status) -> None:
        w = self._in[status.vehicle]
        w["current"](min(status.current_node, NO_NODE))
        w["next"](status.next_node)
        w["state"](STATE_CODE[status.state])
        w["battery"](status.battery)
        w["speed"](min(255, round(status.speed * 100)))

    def write_flags(self, vehicle: int, stale: bool, fault: bool, clear: bool = False) -> None:
        flags = (STALE if stale else ONLINE) | (FAULT if fault else 0) | (CLEAR if clear else 0)
        if self._flags.get(vehicle) != flags:
            self._flags[vehicle] = flags
            self._in[vehicle]["flags"](flags)

    def changed(self) -> list[int]:
        """Vehicles whose output record changed since the last call (all on the first)."""
        rows = np.flatnonzero((self._block != self._last).any(axis=1)).tolist()
        self._last[...] = self._block
        return [v for r in rows if (v := self._row_vehicle[r]) is not None]

    def command(self, vehicle: int) -> tuple[bool, int, tuple[int, ...] | None]:
        """(go, sequence, nodes) of a vehicle's output record; nodes None if not sendable."""
        r = self._out[vehicle]
        control, sequence = r["control"](), r["sequence"]()
        count = control & COUNT_MASK
        nodes = tuple(reader() for reader in r["nodes"][:count])
        return bool(control & GO_BIT), sequence, nodes if count and NO_NODE not in nodes else None
