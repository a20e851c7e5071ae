"""A fleet of simulated AGVs with one bus endpoint, stepped deterministically.

Every step: take the commands that arrived on the bus, move every vehicle, evaluate the
front sensors, send status frames (periodically and on every tag read). The fleet talks to
the controller only through frames of the message set; the vehicles' own physics (front
sensor, turning, battery) is local. Randomness (frame loss and corruption) comes from one
seeded generator, so the same seed gives the same run, bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import can
import numpy as np

from io_drivers.protocol import (
    ALL_VEHICLES,
    NO_NODE,
    Codec,
    MalformedFrame,
    RouteCommand,
    Status,
    StopGo,
    UnknownFrame,
)
from topology import Plant

from .agv import AGV, AgvParams
from .battery import Battery, BatteryParams


@dataclass
class Faults:
    """Fault injection for one vehicle (times in simulated seconds from the fleet's start)."""

    dead_after: float | None = None  # stops sending anything (a dead vehicle)
    drop_rate: float = 0.0  # fraction of its frames lost
    corrupt_rate: float = 0.0  # fraction of its frames sent with a flipped byte
    stall_after: float | None = None  # stops on its segment, reports FAULT
    battery_failure_after: float | None = None


class Fleet:
    def __init__(
        self,
        plant: Plant,
        starts: Mapping[int, int],
        bus: can.BusABC | None = None,
        params: AgvParams | None = None,
        battery: BatteryParams | None = None,
        status_period: float = 0.1,
        faults: Mapping[int, Faults] | None = None,
        seed: int = 0,
    ) -> None:
        for vehicle in starts:
            if not 1 <= vehicle <= 126:
                raise ValueError(f"vehicle ids are 1..126, got {vehicle}")
        self.plant = plant
        self.vehicles = {
            v: AGV(v, plant, node, params, Battery(battery)) for v, node in sorted(starts.items())
        }
        self.bus = bus
        self.codec = Codec()
        self.status_period = status_period
        self.faults = dict(faults or {})
        self.rng = np.random.default_rng(seed)
        self.time = 0.0
        # Each vehicle reports on its own phase within the period, as independent vehicles
        # do: the bus and the controller see a steady stream, not a burst every period.
        self._next_status = {v: status_period * (v % 10) / 10 for v in self.vehicles}
        self._alive = dict.fromkeys(self.vehicles, 0)
        self._last_sequence: dict[int, int] = {}
        self.counters = {
            "sent": 0,
            "dropped": 0,
            "corrupted": 0,
            "received": 0,
            "ignored": 0,
            "rejected": 0,
        }

    # ----- the simulation step ----------------------------------------------------------
    def step(self, dt: float) -> None:
        self._receive()
        self._apply_faults()
        self._front_sensors()
        clear_before = {v: agv.clear for v, agv in self.vehicles.items()}
        reached = [v for v, agv in self.vehicles.items() if agv.step(dt)]
        self.time += dt
        for vehicle, agv in self.vehicles.items():
            periodic = self.time + 1e-12 >= self._next_status[vehicle]
            if periodic:
                self._next_status[vehicle] += self.status_period
            # events are reported at once: a tag read, and leaving a node's crossing zone
            if periodic or vehicle in reached or agv.clear != clear_before[vehicle]:
                self._send_status(vehicle)

    def _apply_faults(self) -> None:
        for vehicle, f in self.faults.items():
            agv = self.vehicles[vehicle]
            if f.stall_after is not None and self.time >= f.stall_after:
                agv.stalled = True
            if f.battery_failure_after is not None and self.time >= f.battery_failure_after:
                agv.battery.failed = True

    def _front_sensors(self) -> None:
        """A vehicle sees another on the same lane ahead of it, or standing on its target node."""
        at_node: dict[int, list[AGV]] = {}
        for agv in self.vehicles.values():
            at_node.setdefault(agv.node, []).append(agv)
        for agv in self.vehicles.values():
            agv.blocked_ahead = False
            if agv.target is None:
                continue
            # a speed-dependent protective field, like a safety laser scanner's: the free
            # space it wants ahead grows with the braking distance
            p = agv.params
            reach = agv.progress + p.length + p.sensor_range + agv.speed**2 / (2 * p.decel)
            for other in at_node.get(agv.node, []) + at_node.get(agv.target, []):
                if other is agv:
                    continue
                same_lane = (
                    other.target == agv.target
                    and other.node == agv.node
                    and other.progress > agv.progress
                )
                at_target = other.target is None and other.node == agv.target
                # an oncoming vehicle on the same segment: both stop and block each other (the
                # head-on case the reservation must prevent; here at least no pass-through)
                oncoming = other.node == agv.target and other.target == agv.node
                if same_lane:
                    ahead = other.progress - other.params.length
                elif at_target:
                    ahead = agv.length
                elif oncoming:
                    ahead = agv.length - other.progress - other.params.length
                else:
                    continue
                if ahead < reach:
                    agv.blocked_ahead = True
                    break

    # ----- the bus --------------------------------------------------------------------------
    def status(self, vehicle: int) -> Status:
        agv = self.vehicles[vehicle]
        next_node = agv.next_node
        return Status(
            vehicle,
            agv.node,
            NO_NODE if next_node is None else next_node,
            agv.state,
            int(round(agv.battery.percent)),
            agv.speed,
            self._alive[vehicle],
            agv.state == "FAULT",
            agv.clear,
        )

    def _send_status(self, vehicle: int) -> None:
        f = self.faults.get(vehicle)
        if f and f.dead_after is not None and self.time >= f.dead_after:
            return
        self._alive[vehicle] = (self._alive[vehicle] + 1) % 16
        frame_id, data = self.codec.encode(self.status(vehicle))
        if f and f.drop_rate and self.rng.random() < f.drop_rate:
            self.counters["dropped"] += 1
            return
        if f and f.corrupt_rate and self.rng.random() < f.corrupt_rate:
            data = bytearray(data)
            data[int(self.rng.integers(len(data)))] ^= 0xFF
            self.counters["corrupted"] += 1
        self._send(frame_id, bytes(data))

    def _send(self, frame_id: int, data: bytes) -> None:
        if self.bus is None:
            return
        try:
            self.bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
            self.counters["sent"] += 1
        except can.CanError:
            self.counters["dropped"] += 1

    def _receive(self) -> None:
        if self.bus is None:
            return
        while (msg := self.bus.recv(timeout=0)) is not None:
            if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
                self.counters["ignored"] += 1
                continue
            try:
                decoded = self.codec.decode(msg.arbitration_id, msg.data)
            except (MalformedFrame, UnknownFrame):
                self.counters["ignored"] += 1
                continue
            self.counters["received"] += 1
            self.apply(decoded)

    def apply(self, message: object) -> None:
        """A command from the controller, whatever link carried it (CAN frame, Modbus write)."""
        if isinstance(message, RouteCommand) and message.vehicle in self.vehicles:
            if self._last_sequence.get(message.vehicle) == message.sequence:
                return  # a repetition, not a new route
            self._last_sequence[message.vehicle] = message.sequence
            if not self.vehicles[message.vehicle].command(message.nodes):
                self.counters["rejected"] += 1
        elif isinstance(message, StopGo):
            for vehicle, agv in self.vehicles.items():
                if message.vehicle in (vehicle, ALL_VEHICLES):
                    agv.go = message.go
