"""CanDriver: the vehicles' CAN bus, mapped into the process image.

Inputs (written at the quiet point of every tick, so a scan sees one consistent snapshot):
per vehicle v an 8-byte record at input byte ``input_base + 8 * v``:

    +0 WORD current node      +2 WORD next node (65535: none)
    +4 BYTE state code        +5 BYTE battery %        +6 BYTE speed cm/s
    +7 BYTE flags: bit 0 online, bit 1 stale (no status for ``stale_after`` s: treat the
            vehicle as an obstacle where it was last seen), bit 2 fault reported

Outputs (read after copy-out): per vehicle v an 8-byte record at output byte
``output_base + 8 * v``:

    +0/+2/+4 WORD next nodes 1..3 (the released route)    +6 BYTE bits 0-1 count, bit 7 go
    +7 BYTE sequence: a new value sends the RouteCommand; go changes send StopGo

All-zero outputs mean "every vehicle stopped", so the runtime's safe state (outputs 0 on
STOP and FAULT) really stops the fleet; closing the driver also broadcasts a stop. Bad
frames (wrong length, out-of-range values, unknown ids) are counted and dropped; nothing a
frame contains can raise out of the scan. Per tick at most ``max_frames`` frames are read,
so a flooded bus cannot stretch the scan (the rest waits for the next tick).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import can
import numpy as np

from plc_runtime import ConfigError, ProcessImage

from .protocol import (
    ALL_VEHICLES,
    CONTROLLER,
    MAX_VEHICLE_ID,
    NO_NODE,
    STATE_CODE,
    Codec,
    Heartbeat,
    MalformedFrame,
    RouteCommand,
    Status,
    StopGo,
    UnknownFrame,
)

RECORD = 8
ONLINE, STALE, FAULT = 0x01, 0x02, 0x04
GO_BIT, COUNT_MASK = 0x80, 0x03


class CanDriver:
    def __init__(
        self,
        vehicles: Iterable[int],
        interface: str = "virtual",
        channel: str = "agv",
        input_base: int = 1024,
        output_base: int = 1024,
        stale_after: float = 0.5,
        heartbeat_period: float = 0.1,
        max_frames: int = 2000,
        name: str = "can",
        **bus_kwargs: Any,
    ) -> None:
        self.vehicles = sorted(set(vehicles))
        for v in self.vehicles:
            if not 1 <= v <= MAX_VEHICLE_ID:
                raise ConfigError(f"CanDriver: vehicle ids are 1..{MAX_VEHICLE_ID}, got {v}")
        if input_base % 2 or output_base % 2:
            raise ConfigError("CanDriver: input_base and output_base must be even (word aligned)")
        self.name = name
        self.interface, self.channel, self.bus_kwargs = interface, channel, bus_kwargs
        self.input_base, self.output_base = input_base, output_base
        self.stale_after_ns = round(stale_after * 1e9)
        self.heartbeat_ns = round(heartbeat_period * 1e9)
        self.max_frames = max_frames
        self.codec = Codec()
        self.bus: can.BusABC | None = None
        self.counters = dict.fromkeys(
            (
                "frames_in",
                "frames_out",
                "malformed",
                "unknown_id",
                "unknown_vehicle",
                "send_errors",
                "deferred",
                "bad_commands",
            ),
            0,
        )
        self.status: dict[int, Status] = {}

    # ----- lifecycle ------------------------------------------------------------------------
    def open(self, image: ProcessImage) -> None:
        last = self.input_base + RECORD * max(self.vehicles, default=0) + RECORD
        if (
            last > image.sizes["I"]
            or self.output_base + RECORD * max(self.vehicles, default=0) + RECORD > image.sizes["Q"]
        ):
            raise ConfigError(
                f"{len(self.vehicles)} vehicle records do not fit the I/Q image sizes {image.sizes}"
            )
        try:
            self.bus = can.Bus(
                interface=self.interface,
                channel=self.channel,
                receive_own_messages=False,
                **self.bus_kwargs,
            )
        except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
            raise ConfigError(
                f"CAN interface {self.interface!r} channel {self.channel!r}: {exc}"
            ) from None
        self._inputs = {v: self._input_writers(image, v) for v in self.vehicles}
        self._outputs = {v: self._output_readers(image, v) for v in self.vehicles}
        self._last_seen: dict[int, int] = {}
        self._sent_sequence: dict[int, int] = {}
        self._sent_go: dict[int, bool] = {}
        self._next_heartbeat = 0
        self._now_ns = 0
        self._flags: dict[int, int] = {}
        first, last = (
            self.output_base + RECORD * self.vehicles[0],
            self.output_base + RECORD * (self.vehicles[-1] + 1),
        )
        self._out_view = image.published_outputs.bytes[first:last]
        self._out_vehicle = {
            (self.output_base + RECORD * v - first) // RECORD: v for v in self.vehicles
        }
        rows = len(self._out_view) // RECORD
        self._out_vehicle = [
            self._out_vehicle.get(r) for r in range(rows)
        ]  # None: an id we do not manage
        self._out_last = np.full(
            (rows, RECORD), -1, dtype=np.int16
        )  # differs from any byte: first tick sends
        self._alive = 0
        self.status = {}

    def close(self) -> None:
        if self.bus is None:
            return
        self._send(StopGo(ALL_VEHICLES, False))  # the controller goes away: everyone stops
        self.bus.shutdown()
        self.bus = None

    def stats(self) -> dict[str, object]:
        stale = (
            [v for v in self.vehicles if v in self._last_seen and self._is_stale(v)]
            if self.bus
            else []
        )
        return {**self.counters, "online": len(self.status) - len(stale), "stale": stale}

    def _input_writers(self, image: ProcessImage, v: int) -> dict[str, Any]:
        base = self.input_base + RECORD * v
        return {
            "current": image.field_writer(f"%IW{base // 2}"),
            "next": image.field_writer(f"%IW{base // 2 + 1}"),
            "state": image.field_writer(f"%IB{base + 4}"),
            "battery": image.field_writer(f"%IB{base + 5}"),
            "speed": image.field_writer(f"%IB{base + 6}"),
            "flags": image.field_writer(f"%IB{base + 7}"),
        }

    def _output_readers(self, image: ProcessImage, v: int) -> dict[str, Any]:
        base = self.output_base + RECORD * v
        return {
            "nodes": [image.output_reader(f"%QW{base // 2 + k}") for k in range(3)],
            "control": image.output_reader(f"%QB{base + 6}"),
            "sequence": image.output_reader(f"%QB{base + 7}"),
        }

    # ----- the scan -------------------------------------------------------------------------
    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        self._now_ns = now_ns
        for _ in range(self.max_frames):
            msg = self.bus.recv(timeout=0)
            if msg is None:
                break
            self._handle(msg, now_ns)
        else:
            self.counters["deferred"] += 1  # more frames waiting: read next tick
        for v in self.vehicles:
            self._write_flags(v)

    def _handle(self, msg: can.Message, now_ns: int) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            self.counters["unknown_id"] += 1
            return
        try:
            decoded = self.codec.decode(msg.arbitration_id, msg.data)
        except UnknownFrame:
            self.counters["unknown_id"] += 1
            return
        except MalformedFrame:
            self.counters["malformed"] += 1
            return
        self.counters["frames_in"] += 1
        if not isinstance(decoded, Status):
            return  # other controllers' commands and heartbeats: not ours to act on
        if decoded.vehicle not in self._inputs:
            self.counters["unknown_vehicle"] += 1
            return
        self.status[decoded.vehicle] = decoded
        self._last_seen[decoded.vehicle] = now_ns
        w = self._inputs[decoded.vehicle]
        w["current"](min(decoded.current_node, NO_NODE))
        w["next"](decoded.next_node)
        w["state"](STATE_CODE[decoded.state])
        w["battery"](decoded.battery)
        w["speed"](min(255, round(decoded.speed * 100)))

    def _is_stale(self, v: int) -> bool:
        return self._now_ns - self._last_seen.get(v, -(2**62)) > self.stale_after_ns

    def _write_flags(self, v: int) -> None:
        status = self.status.get(v)
        if status is None:
            return
        stale = self._is_stale(v)
        flags = (0 if stale else ONLINE) | (STALE if stale else 0) | (FAULT if status.fault else 0)
        if self._flags.get(v) != flags:
            self._flags[v] = flags
            self._inputs[v]["flags"](flags)

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        # The whole output block at once: only vehicles whose record changed need work.
        block = self._out_view.reshape(-1, RECORD)
        changed = np.flatnonzero((block != self._out_last).any(axis=1))
        for row in changed.tolist():
            if self._out_vehicle[row] is not None:
                self._command(self._out_vehicle[row])
        self._out_last[...] = block
        if now_ns >= self._next_heartbeat:
            self._next_heartbeat = now_ns + self.heartbeat_ns
            self._alive = (self._alive + 1) % 256
            self._send(Heartbeat(CONTROLLER, self._alive))

    def _command(self, v: int) -> None:
        r = self._outputs[v]
        control, sequence = r["control"](), r["sequence"]()
        go = bool(control & GO_BIT)
        if self._sent_go.get(v) != go and self._send(StopGo(v, go)):
            self._sent_go[v] = go
        if sequence != self._sent_sequence.get(v, 0):  # outputs start at 0: 0 is "no command yet"
            count = control & COUNT_MASK
            nodes = tuple(reader() for reader in r["nodes"][:count])
            if not count or NO_NODE in nodes:
                self.counters["bad_commands"] += 1
                self._sent_sequence[v] = sequence  # not sendable; wait for the next sequence
            elif self._send(RouteCommand(v, sequence % 16, nodes)):
                self._sent_sequence[v] = sequence

    def _send(self, message: Any) -> bool:
        frame_id, data = self.codec.encode(message)
        try:
            self.bus.send(
                can.Message(arbitration_id=frame_id, data=data, is_extended_id=False), timeout=0
            )
        except can.CanError:
            self.counters["send_errors"] += 1
            return False
        self.counters["frames_out"] += 1
        return True
