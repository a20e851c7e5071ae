"""The per-vehicle records in the process image (docs/protocol.md), shared by every vehicle
link (CAN, Modbus): one layout, and one rule for what a frame may change, whatever bus
carries it.

Inputs at ``input_base + 8 * v``: WORD current node, WORD next node, BYTE state, BYTE
battery %, BYTE speed cm/s, BYTE flags (online, stale, fault, clear of the current node,
bits 4-6 the count of the vehicle's counter jumps, mod 8). Outputs at ``output_base + 8 *
v``: WORD next nodes 1..3, BYTE count (bits 0-1, 0 with a new sequence: cancel the route) |
go (bit 7), BYTE sequence. Input writes happen in the
scan thread at the quiet point; outputs are read after copy-out, and only records that
changed since the last tick are looked at.

Only frames that passed the CRC and counter checks arrive here. Even so, a single frame may
not move a vehicle: its position (current node, next node, clear bit) changes only when two
consecutive status frames (accepted, and consecutive as sent: their counters differ by one)
agree on (current node, clear). The vehicles send every event twice, so this costs one
step of latency (one status period when a frame is lost), and a single well-formed but
false frame (a spoofing node, a corruption the CRC missed) can never take a node from
another vehicle or free one a vehicle still stands on. A fault is taken at once (the safe
direction); its end, like a position, only when two consecutive frames report it. State
and speed are taken at once, a battery level if it is near the one before (a jump of more
than ``BATTERY_STEP`` % only when the next info frame repeats it).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from plc_runtime import ConfigError, ProcessImage

from .e2e import COUNTER_MODULO
from .protocol import BATTERY_UNKNOWN, MAX_VEHICLE_ID, NO_NODE, STATE_CODE, Info, Status

RECORD = 8
BATTERY_STEP = 2  # % a battery level may move from one info frame to the next unconfirmed
ONLINE, STALE, FAULT, CLEAR = 0x01, 0x02, 0x04, 0x08
# the link's count of the vehicle's counter jumps (restart, a second sender), mod 8: the
# program sees a jump as a change of the count, so no jump can hide behind an earlier one
LINK_JUMPS, LINK_JUMP_SHIFT = 0x70, 4
GO_BIT, COUNT_MASK = 0x80, 0x03


@dataclass(frozen=True, slots=True)
class InputWriters:
    """The checked field writers of one vehicle's input record, in record order."""

    current: Callable[[int], None]
    next: Callable[[int], None]
    state: Callable[[int], None]
    battery: Callable[[int], None]
    speed: Callable[[int], None]
    flags: Callable[[int], None]

    @classmethod
    def at(cls, image: ProcessImage, base: int) -> InputWriters:
        """The writers of the record at input byte ``base``."""
        return cls(
            image.field_writer(f"%IW{base // 2}"),
            image.field_writer(f"%IW{base // 2 + 1}"),
            image.field_writer(f"%IB{base + 4}"),
            image.field_writer(f"%IB{base + 5}"),
            image.field_writer(f"%IB{base + 6}"),
            image.field_writer(f"%IB{base + 7}"),
        )


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
        self._in = {v: InputWriters.at(image, input_base + RECORD * v) for v in self.vehicles}
        for writers in self._in.values():  # no reading yet is not an empty battery
            writers.battery(BATTERY_UNKNOWN)
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
        self.status: dict[int, Status] = {}  # the last accepted status of each vehicle
        # ((current, clear), counter, fault) of that status
        self._candidate: dict[int, tuple[tuple[int, bool], int, bool]] = {}
        self._fault: set[int] = set()  # vehicles whose fault was not confirmed gone
        self._position: dict[int, tuple[int, bool]] = {}  # the confirmed (current, clear)
        self._jumps: dict[int, int] = {}  # counter jumps seen per vehicle, mod 8
        self._last_seen: dict[int, int] = {}  # the last confirmed position's tick
        self._first_ns: int | None = None
        self._now_ns = 0
        self._battery: dict[int, int] = {}  # the battery level taken, %
        self._battery_seen: dict[int, int] = {}  # the last info frame's level, taken or not
        self.counters = {"unconfirmed": 0}

    @staticmethod
    def _output_readers(image: ProcessImage, base: int) -> dict:
        return {
            "nodes": [image.output_reader(f"%QW{base // 2 + k}") for k in range(3)],
            "control": image.output_reader(f"%QB{base + 6}"),
            "sequence": image.output_reader(f"%QB{base + 7}"),
        }

    def __contains__(self, vehicle: int) -> bool:
        return vehicle in self._in

    # ----- frames that passed the checks --------------------------------------------------------
    def received(self, status: Status, now_ns: int, resync: bool = False) -> None:
        """An accepted status (in the tick at ``now_ns``); ``resync``: the link resynchronised
        to this vehicle's counter, so its jump count goes up."""
        v = status.vehicle
        if resync:
            self._jumped(v)
        self.status[v] = status
        w = self._in[v]
        w.state(STATE_CODE[status.state])
        w.speed(min(255, round(status.speed * 100)))
        position, counter, fault = (status.current_node, status.clear), status.counter, status.fault
        candidate = self._candidate.get(v)
        self._candidate[v] = (position, counter, fault)
        if fault:
            self._fault.add(v)
        if candidate is None:
            return
        last_position, last_counter, last_fault = candidate
        consecutive = counter == (last_counter + 1) % COUNTER_MODULO
        if consecutive and not fault and not last_fault:
            self._fault.discard(v)
        if last_position == position:
            if consecutive:
                self._position[v] = position
                self._last_seen[v] = now_ns
                w.current(status.current_node)
                w.next(status.next_node)
        elif last_position != self._position.get(v):
            self.counters["unconfirmed"] += 1  # a position nobody repeated: never applied

    def received_info(self, info: Info, resync: bool = False) -> None:
        """An accepted info frame. Its battery level is taken if it is the vehicle's first,
        within ``BATTERY_STEP`` of the level taken before, or confirmed: within that of the
        frame before it. Else it waits for the next frame (``unconfirmed``), as a position
        waits for a second status: one forged or garbled frame that passed the checks must
        not set a level the charging policy learns from (a single 0 % at the end of an order
        taught it that an order empties a battery, and no vehicle took another). A level
        moves about 1 % between frames, and the vehicle sends one on every change."""
        v = info.vehicle
        if resync:
            self._jumped(v)
        level, taken, before = info.battery, self._battery.get(v), self._battery_seen.get(v)
        self._battery_seen[v] = level
        if (
            taken is None
            or abs(level - taken) <= BATTERY_STEP
            or (before is not None and abs(level - before) <= BATTERY_STEP)
        ):
            self._battery[v] = level
            self._in[v].battery(level)
        else:
            self.counters["unconfirmed"] += 1

    def _jumped(self, vehicle: int) -> None:
        self._jumps[vehicle] = (self._jumps.get(vehicle, 0) + 1) % 8

    # ----- liveness -------------------------------------------------------------------------
    def refresh_flags(self, now_ns: int) -> None:
        """Once per tick, after the frames: the flags of every vehicle. A vehicle is online
        once its position is confirmed, and stale when no position was confirmed for
        ``stale_after``; a vehicle that never reported goes stale ``stale_after`` after the
        first tick."""
        self._now_ns = now_ns
        if self._first_ns is None:
            self._first_ns = now_ns
        # is_stale's rule, with its lookups taken out of the loop over every vehicle
        never_seen, stale_after, written = self._first_ns, self.stale_after_ns, self._flags
        positions, last_seen = self._position, self._last_seen
        faults, jumps = self._fault, self._jumps
        for v in self.vehicles:
            position = positions.get(v)
            stale = now_ns - last_seen.get(v, never_seen) > stale_after
            if position is None and not stale:
                continue  # never heard of: the record holds no position, flags stay 0
            flags = (
                (STALE if stale else ONLINE)
                | (FAULT if v in faults else 0)
                | (CLEAR if position is not None and position[1] else 0)
                | (jumps.get(v, 0) << LINK_JUMP_SHIFT)
            )
            if written.get(v) != flags:
                written[v] = flags
                self._in[v].flags(flags)

    def is_stale(self, vehicle: int) -> bool:
        last = self._last_seen.get(
            vehicle, self._first_ns if self._first_ns is not None else self._now_ns
        )
        return self._now_ns - last > self.stale_after_ns

    def link_stats(self, link_counters: Mapping[str, int]) -> dict[str, object]:
        """A link's ``stats()``: its own counters, the records' and who is online or stale."""
        return {
            **link_counters,
            **self.counters,
            "online": len(self.online()),
            "stale": self.stale(),
        }

    def stale(self) -> list[int]:
        return [v for v in self.vehicles if self.is_stale(v)]

    def online(self) -> list[int]:
        """Vehicles whose position is confirmed and not stale, as of the last tick: a
        vehicle never heard from is not online, however young the link."""
        return [v for v in self.vehicles if v in self._position and not self.is_stale(v)]

    # ----- the commands -----------------------------------------------------------------------
    def changed(self) -> list[int]:
        """Vehicles whose output record changed since the last call (all on the first)."""
        rows = np.flatnonzero((self._block != self._last).any(axis=1)).tolist()
        self._last[...] = self._block
        return [v for r in rows if (v := self._row_vehicle[r]) is not None]

    def command(self, vehicle: int) -> tuple[bool, int, tuple[int, ...] | None]:
        """(go, sequence, nodes) of a vehicle's output record; nodes None if not sendable,
        () to cancel the vehicle's route (it stops at the node it reaches next)."""
        r = self._out[vehicle]
        control, sequence = r["control"](), r["sequence"]()
        count = control & COUNT_MASK
        nodes = tuple(reader() for reader in r["nodes"][:count])
        return bool(control & GO_BIT), sequence, nodes if NO_NODE not in nodes else None
