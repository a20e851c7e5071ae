"""A fleet of simulated AGVs with one bus endpoint, stepped deterministically.

Every step: take the commands that arrived on the bus, move every vehicle, evaluate the
front sensors, send status frames (periodically, and on every event: a tag read, or the
clear bit changing; an event is sent twice, at once and at the next step, because the
controller applies a position only when two consecutive statuses agree) and info frames
(battery: every ``info_period`` and on change). The fleet talks to the controller only
through end-to-end protected frames of the message set; received commands pass the same
CRC and counter checks as on the controller's side, and a command the counter check only
resynchronised to is obeyed if it is a stop, never as a go or a route. The vehicles' own physics (front
sensor, turning, battery) is local.

Fault injection (``Faults``, per vehicle) acts on the frames a vehicle sends: lost,
corrupted (one byte replaced by another value), or followed by a spoofed frame. Every
injected fault is counted per kind in ``counters``. Randomness comes from one seeded
generator, so the same seed gives the same run, bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import can
import numpy as np

from io_drivers.can_bus import frames_carried
from io_drivers.e2e import ACCEPTED, CounterCheck
from io_drivers.protocol import (
    ALL_VEHICLES,
    INFO,
    MAX_VEHICLE_ID,
    NO_NODE,
    STATES,
    STATUS,
    Codec,
    CorruptFrame,
    Info,
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
    corrupt_rate: float = 0.0  # fraction of its frames with one byte replaced by another value
    # per status frame it sends, the chance that a faulty or foreign node sends one too:
    # well-formed, passing the CRC, of a random vehicle, random nodes, a random counter
    spoof_rate: float = 0.0
    stall_after: float | None = None  # stops on its segment, reports FAULT
    # random delays, unknown to the controller (a person in the way, a slow load transfer):
    # per second, the chance that it stops where it is for delay_s[0]..delay_s[1] seconds
    delay_rate: float = 0.0
    delay_s: tuple[float, float] = (1.0, 10.0)
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
        info_period: float = 1.0,
        charges: Mapping[int, float] | None = None,
    ) -> None:
        """``charges``: vehicle -> its battery's charge at the start, in % (default 100)."""
        # on a CAN bus an id is 7 bits; without one (each vehicle its own Modbus server)
        # any positive id will do
        most = MAX_VEHICLE_ID if bus is not None else None
        for vehicle in starts:
            if vehicle < 1 or (most is not None and vehicle > most):
                raise ValueError(f"vehicle ids are 1..{most or 'any'}, got {vehicle}")
        self.plant = plant
        self.vehicles = {
            v: AGV(v, plant, node, params, Battery(battery, (charges or {}).get(v, 100.0) / 100.0))
            for v, node in sorted(starts.items())
        }
        self.bus = bus
        self.codec = Codec()
        self.status_period, self.info_period = status_period, info_period
        self.faults = dict(faults or {})
        self.rng = np.random.default_rng(seed)
        self.time = 0.0
        # Each vehicle reports on its own phase within the period, as independent vehicles
        # do: the bus and the controller see a steady stream, not a burst every period.
        self._next_status = {v: status_period * (v % 10) / 10 for v in self.vehicles}
        self._next_info = {v: info_period * (v % 10) / 10 for v in self.vehicles}
        self._battery_sent: dict[int, int] = {}
        self._counter: dict[int, int] = {}  # frame id -> the counter of its last frame
        self._route_ack = dict.fromkeys(self.vehicles, 0)
        self._repeat: set[int] = set()  # vehicles whose event status goes out again next step
        self._announced = False
        self.frames: dict[int, bytes] = {}  # frame id -> the last frame sent (Modbus publishes it)
        self.counters = {
            "sent": 0,
            "dropped": 0,  # injected: lost frames
            "corrupted": 0,  # injected: one byte replaced
            "spoofed": 0,  # injected: well-formed frames of a faulty or foreign node
            "delays": 0,  # injected: random stops
            "received": 0,
            "ignored": 0,  # malformed, an unknown id, or nothing the interface could read
            "crc_errors": 0,
            "rejected": 0,  # route commands that did not fit where the vehicle was
        }
        # the vehicles' side of the controller's counters (repeated route commands are
        # resends of the same command: ignored, not errors)
        self.checks = CounterCheck(self.counters)

    # ----- the simulation step ----------------------------------------------------------
    def announce(self) -> None:
        """Power-on, once: every vehicle reports its status (as an event: twice) and its
        info. Runs by itself before the first step; a Modbus server calls it before serving."""
        if self._announced:
            return
        self._announced = True
        for vehicle in self.vehicles:
            self._send_status(vehicle)
            self._send_info(vehicle)
        self._repeat = set(self.vehicles)

    def step(self, dt: float) -> None:
        self.announce()
        self._receive(dt)
        self._apply_faults(dt)
        self._front_sensors()
        clear_before = {v: agv.clear for v, agv in self.vehicles.items()}
        reached = [v for v, agv in self.vehicles.items() if agv.step(dt)]
        self.time += dt
        repeat, self._repeat = self._repeat, set()
        now = self.time + 1e-12
        for vehicle, agv in self.vehicles.items():
            periodic = now >= self._next_status[vehicle]
            if periodic:
                self._next_status[vehicle] += self.status_period
            # events are reported at once, and again at the next step: a tag read, and
            # leaving a node's crossing zone
            event = vehicle in reached or agv.clear != clear_before[vehicle]
            if periodic or event or vehicle in repeat:
                self._send_status(vehicle)
            if event:
                self._repeat.add(vehicle)
            periodic_info = now >= self._next_info[vehicle]
            if periodic_info:
                self._next_info[vehicle] += self.info_period
            if periodic_info or round(agv.battery.percent) != self._battery_sent[vehicle]:
                self._send_info(vehicle)

    def _apply_faults(self, dt: float) -> None:
        for agv in self.vehicles.values():
            if agv.paused_until is not None and self.time >= agv.paused_until:
                agv.paused_until = None  # a delay ends, also once the faults are gone
        for vehicle, f in self.faults.items():
            agv = self.vehicles[vehicle]
            if f.stall_after is not None and self.time >= f.stall_after:
                agv.stalled = True
            if f.battery_failure_after is not None and self.time >= f.battery_failure_after:
                agv.battery.failed = True
            if f.delay_rate:
                self._delay(agv, f, dt)

    def _delay(self, agv: AGV, f: Faults, dt: float) -> None:
        """Maybe start a random stop (status frames go on as usual: it just stands)."""
        if agv.paused_until is None and self.rng.random() < f.delay_rate * dt:
            agv.paused_until = self.time + float(self.rng.uniform(*f.delay_s))
            self.counters["delays"] += 1

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
    def _status(self, vehicle: int) -> Status:
        agv = self.vehicles[vehicle]
        next_node = agv.next_node
        return Status(
            vehicle,
            agv.node,
            NO_NODE if next_node is None else next_node,
            agv.state,
            agv.speed,
            self._next_counter(STATUS + vehicle),
            agv.state == "FAULT",
            agv.clear,
            self._route_ack[vehicle],
        )

    def _next_counter(self, frame_id: int) -> int:
        counter = self._counter[frame_id] = (self._counter.get(frame_id, 0) + 1) % 16
        return counter

    def _silent(self, vehicle: int) -> bool:
        f = self.faults.get(vehicle)
        return f is not None and f.dead_after is not None and self.time >= f.dead_after

    def _send_status(self, vehicle: int) -> None:
        if self._silent(vehicle):
            return
        self._emit(vehicle, *self.codec.encode(self._status(vehicle)))
        f = self.faults.get(vehicle)
        if f and f.spoof_rate and self.rng.random() < f.spoof_rate:
            self._spoof()

    def _send_info(self, vehicle: int) -> None:
        battery = round(self.vehicles[vehicle].battery.percent)
        self._battery_sent[vehicle] = battery
        if self._silent(vehicle):
            return
        info = Info(vehicle, battery, self._next_counter(INFO + vehicle))
        self._emit(vehicle, *self.codec.encode(info))

    def _emit(self, vehicle: int, frame_id: int, data: bytes) -> None:
        """A vehicle's frame onto the link, through its injected faults."""
        f = self.faults.get(vehicle)
        if f and f.drop_rate and self.rng.random() < f.drop_rate:
            self.counters["dropped"] += 1
            return
        if f and f.corrupt_rate and self.rng.random() < f.corrupt_rate:
            corrupt = bytearray(data)
            at = int(self.rng.integers(len(corrupt)))
            corrupt[at] = (corrupt[at] + int(self.rng.integers(1, 256))) % 256
            data = bytes(corrupt)
            self.counters["corrupted"] += 1
        self._send(frame_id, data)

    def _spoof(self) -> None:
        """A faulty or foreign node's status frame: well-formed and with a valid CRC, for a
        random vehicle of the fleet, with random nodes of the plant and a random counter."""
        rng, ids = self.rng, self.plant.ids
        vehicle = int(rng.choice(list(self.vehicles)))
        state = STATES[int(rng.integers(len(STATES)))]
        status = Status(
            vehicle,
            int(ids[rng.integers(len(ids))]),
            int(ids[rng.integers(len(ids))]),
            state,
            float(rng.integers(0, 256)) / 100,
            int(rng.integers(16)),
            state == "FAULT",
            bool(rng.integers(2)),
            int(rng.integers(16)),
        )
        self.counters["spoofed"] += 1
        self._send(*self.codec.encode(status))

    def _send(self, frame_id: int, data: bytes) -> None:
        self.frames[frame_id] = data
        if self.bus is not None:
            try:
                self.bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
            except can.CanError:
                self.counters["dropped"] += 1
                return
        self.counters["sent"] += 1

    def _receive(self, dt: float) -> None:
        """The frames waiting on the bus, at most what a 1 Mbit/s bus carries in ``dt``: a
        flood on a bus without that limit (virtual, UDP) is read a bus's worth a step, as
        the controller's driver reads it, instead of stalling the step. Classic CAN frames
        only: extended ids, error, remote and CAN FD frames are not the protocol's."""
        if self.bus is None:
            return
        for _ in range(frames_carried(dt)):
            try:
                msg = self.bus.recv(timeout=0)
            except can.CanError:  # a datagram udp_multicast cannot unpack, a socket error
                self.counters["ignored"] += 1
                continue
            if msg is None:
                return
            if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame or msg.is_fd:
                self.counters["ignored"] += 1
                continue
            self.receive(msg.arbitration_id, bytes(msg.data))

    def receive(self, frame_id: int, data: bytes) -> None:
        """A frame from the controller, whatever link carried it (CAN frame, Modbus write):
        checked (CRC, counter) and applied. A route command repeating the last one's
        counter is a resend of it, not a new route. A stop that passes the CRC is obeyed
        whatever its counter (the safe direction). A go and a route need a counter in the
        window of the last one accepted: a frame the check resynchronises to (a restarted
        controller, or replayed old frames) only sets the new reference, so it can stop a
        vehicle but never start one or give it a route; the controller's next frames (the
        go is repeated every second, a route resent when the vehicle shows no sign of it)
        are then in the window. A go for every vehicle (the broadcast id) is not obeyed."""
        try:
            message = self.codec.decode(frame_id, data)
        except CorruptFrame:
            self.counters["crc_errors"] += 1
            return
        except (MalformedFrame, UnknownFrame):
            self.counters["ignored"] += 1
            return
        self.counters["received"] += 1
        if isinstance(message, RouteCommand) and message.vehicle in self.vehicles:
            verdict = self.checks.check(frame_id, message.sequence)
            if verdict is ACCEPTED:  # (a resync only sets the new reference)
                self._route_ack[message.vehicle] = message.sequence
                if not self.vehicles[message.vehicle].command(message.nodes):
                    self.counters["rejected"] += 1
        elif isinstance(message, StopGo):
            if message.go and message.vehicle == ALL_VEHICLES:
                # the broadcast is for stopping everyone (the controller closing): a vehicle
                # sets off only on a go of its own, so one frame cannot start a fleet
                self.counters["ignored"] += 1
                return
            verdict = self.checks.check(frame_id, message.counter)
            if message.go and verdict is not ACCEPTED:
                return
            for vehicle, agv in self.vehicles.items():
                if message.vehicle in (vehicle, ALL_VEHICLES):
                    agv.go = message.go
