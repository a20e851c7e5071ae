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

from plc_runtime import ConfigError, ProcessImage

from .protocol import (
    ALL_VEHICLES,
    CONTROLLER,
    MAX_VEHICLE_ID,
    Codec,
    Heartbeat,
    MalformedFrame,
    RouteCommand,
    Status,
    StopGo,
    UnknownFrame,
)
from .vehicle_records import FAULT, GO_BIT, ONLINE, RECORD, STALE, VehicleRecords  # noqa: F401 - the record API


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

    # ----- lifecycle ------------------------------------------------------------------------
    def open(self, image: ProcessImage) -> None:
        self.records = VehicleRecords(
            image, self.vehicles, self.input_base, self.output_base, self.stale_after_ns
        )
        try:
            self.bus = can.Bus(
                interface=self.interface,
                channel=self.channel,
                receive_own_messages=False,
                **self.bus_kwargs,
            )
        except (
            can.CanError,
            OSError,
            ValueError,
            ImportError,
        ) as exc:  # CanError covers an unavailable interface
            raise ConfigError(
                f"CAN interface {self.interface!r} channel {self.channel!r}: {exc}"
            ) from None
        self._sent_sequence: dict[int, int] = {}
        self._sent_go: dict[int, bool] = {}
        self._next_heartbeat = 0
        self._retry: set[int] = set()  # vehicles whose last send failed: look again next tick
        self._alive = 0

    def close(self) -> None:
        if self.bus is None:
            return
        self._send(StopGo(ALL_VEHICLES, False))  # the controller goes away: everyone stops
        self.bus.shutdown()
        self.bus = None

    def stats(self) -> dict[str, object]:
        stale = self.records.stale() if self.bus else []
        return {**self.counters, "online": len(self.records.vehicles) - len(stale), "stale": stale}

    # ----- the scan -------------------------------------------------------------------------
    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        for _ in range(self.max_frames):
            msg = self.bus.recv(timeout=0)
            if msg is None:
                break
            self._handle(msg, now_ns)
        else:
            self.counters["deferred"] += 1  # more frames waiting: read next tick
        self.records.refresh_flags(now_ns)

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
        if decoded.vehicle not in self.records:
            self.counters["unknown_vehicle"] += 1
            return
        self.records.received(decoded, now_ns)

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        todo, self._retry = set(self.records.changed()) | self._retry, set()
        for v in sorted(todo):
            go, sequence, nodes = self.records.command(v)
            if self._sent_go.get(v) != go:
                if self._send(StopGo(v, go)):
                    self._sent_go[v] = go
                else:
                    self._retry.add(v)
            if sequence != self._sent_sequence.get(
                v, 0
            ):  # outputs start at 0: 0 is "no command yet"
                if nodes is None:
                    self.counters["bad_commands"] += 1
                    self._sent_sequence[v] = sequence  # not sendable; wait for the next sequence
                elif self._send(RouteCommand(v, sequence % 16, nodes)):
                    self._sent_sequence[v] = sequence
                else:
                    self._retry.add(v)
        if now_ns >= self._next_heartbeat:
            self._next_heartbeat = now_ns + self.heartbeat_ns
            self._alive = (self._alive + 1) % 256
            self._send(Heartbeat(CONTROLLER, self._alive))

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
