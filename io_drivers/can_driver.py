"""CanDriver: the vehicles' CAN bus, mapped into the process image.

Inputs (written at the quiet point of every tick, so a scan sees one consistent snapshot):
per vehicle v an 8-byte record at input byte ``input_base + 8 * v``:

    +0 WORD current node      +2 WORD next node (65535: none)
    +4 BYTE state code        +5 BYTE battery %        +6 BYTE speed cm/s
    +7 BYTE flags: bit 0 online, bit 1 stale (no confirmed status for ``stale_after`` s:
            treat the vehicle as an obstacle where it was last seen), bit 2 fault reported,
            bit 3 clear of the current node, bits 4-6 the count (mod 8) of the vehicle's
            counter jumps (a restart, or a second sender: the program makes it suspect)

Outputs (read after copy-out): per vehicle v an 8-byte record at output byte
``output_base + 8 * v``:

    +0/+2/+4 WORD next nodes 1..3 (the released route)
    +6 BYTE bits 0-1 count, bit 7 go
    +7 BYTE sequence: a new value sends the RouteCommand (count 0: cancel the vehicle's
            route); go changes send StopGo

All-zero outputs mean "every vehicle stopped", so the runtime's safe state (outputs 0 on
STOP and FAULT) really stops the fleet; closing the driver also broadcasts a stop. StopGo
is also repeated every ``go_refresh`` seconds, so a lost one is made good and a vehicle
resynchronises to a restarted controller's counter.

Every frame is end-to-end protected (io_drivers/e2e.py). A frame that fails a check is
counted and dropped, never applied: wrong length or out-of-range values (``malformed``), a
CRC mismatch (``crc_errors``), an id outside the plan (``unknown_id``), a repeated or
out-of-sequence counter (``repeated``, ``out_of_sequence``; ``lost`` counts the frames a
counter step skipped, ``resyncs`` the senders whose counter jumped). What the bus interface
cannot make a frame of at all (a datagram udp_multicast cannot unpack) is counted as
``receive_errors``. What passes goes to
the vehicle records, which confirm positions (``unconfirmed``: positions never repeated).
Nothing a frame contains can raise out of the scan. Per tick at most ``max_frames`` frames
are read (the rest waits for the next tick, counted as ``deferred``), so a flooded bus
cannot stretch the scan by more than reading that many costs: some 5 to 10 us a frame
through python-can's virtual bus (bench/io_throughput.py), so the 2,000 of the default
take one to two 10 ms cycles, and a program sizes it to its cycle with
:func:`frames_per_tick`. A sustained flood then delays the vehicles' own
frames behind it until they are stale, which stops them where they are.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterable
from typing import Any

import can

from plc_runtime import ConfigError, ProcessImage

from .can_bus import BusOpenError, frames_carried, open_can_bus
from .e2e import ACCEPTED, RESYNC, CounterCheck
from .protocol import (
    ALL_VEHICLES,
    CONTROLLER,
    HEARTBEAT,
    MAX_VEHICLE_ID,
    STOP_GO,
    Codec,
    CorruptFrame,
    Heartbeat,
    Info,
    MalformedFrame,
    RouteCommand,
    Status,
    StopGo,
    UnknownFrame,
)
from .vehicle_records import (  # noqa: F401 - the record API
    CLEAR,
    FAULT,
    GO_BIT,
    LINK_JUMP_SHIFT,
    LINK_JUMPS,
    ONLINE,
    RECORD,
    STALE,
    VehicleRecords,
)


def frames_per_tick(cycle_s: float, vehicles: int, status_period_s: float) -> int:
    """The frames one tick should read at most: what a 1 Mbit/s bus carries in a cycle, or
    four times the statuses the vehicles send in one (one each per ``status_period_s``; the
    factor leaves room for their less frequent infos and for bursts), whichever is more, so
    that the vehicles' own traffic is never deferred and a flood costs the scan no more than
    a bus's worth."""
    sent = 4 * vehicles * cycle_s / status_period_s
    return max(frames_carried(cycle_s), math.ceil(sent))


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
        go_refresh: float = 1.0,
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
        self.go_refresh_ns = round(go_refresh * 1e9)
        self.max_frames = max_frames
        self.codec = Codec()
        self.bus: can.BusABC | None = None
        self.records: VehicleRecords | None = None  # made at open (the image's records)
        self.counters = dict.fromkeys(
            (
                "frames_in",
                "frames_out",
                "malformed",
                "crc_errors",
                "unknown_id",
                "unknown_vehicle",
                "send_errors",
                "receive_errors",
                "deferred",
                "bad_commands",
            ),
            0,
        )
        self.checks = CounterCheck(self.counters)  # repeated, lost, out_of_sequence, resyncs

    # ----- lifecycle ------------------------------------------------------------------------
    def open(self, image: ProcessImage) -> None:
        self.records = VehicleRecords(
            image, self.vehicles, self.input_base, self.output_base, self.stale_after_ns
        )
        try:
            self.bus = open_can_bus(self.interface, self.channel, **self.bus_kwargs)
        except BusOpenError as exc:
            raise ConfigError(str(exc)) from None
        self._sent_sequence: dict[int, int] = {}
        self._sent_go: dict[int, bool] = {}
        # vehicle -> when its StopGo was last sent, oldest first: the next to refresh
        self._go_sent_ns: OrderedDict[int, int] = OrderedDict()
        self._counter: dict[int, int] = {}  # frame id -> the counter of its last frame sent
        self._next_heartbeat = 0
        self._retry: set[int] = set()  # vehicles whose last send failed: look again next tick

    def close(self) -> None:
        if self.bus is None:
            return
        # the controller goes away: everyone stops
        self._send(StopGo(ALL_VEHICLES, False, self._next_counter(STOP_GO + ALL_VEHICLES)))
        self.bus.shutdown()
        self.bus = None

    def stats(self) -> dict[str, object]:
        # as of the last tick, so a summary taken after the link closed shows how it ended
        if self.records is None:  # not started
            return {**self.counters, "unconfirmed": 0, "online": 0, "stale": []}
        return self.records.link_stats(self.counters)

    # ----- the scan -------------------------------------------------------------------------
    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        recv, handle = self.bus.recv, self._handle
        for _ in range(self.max_frames):
            try:
                msg = recv(timeout=0)
            except can.CanError:
                # what the interface could not make a frame of (a datagram udp_multicast
                # cannot unpack, a socket error): counted, and the reading goes on
                self.counters["receive_errors"] += 1
                continue
            if msg is None:
                break
            handle(msg, now_ns)
        else:
            self.counters["deferred"] += 1  # more frames waiting: read next tick
        self.records.refresh_flags(now_ns)

    def _handle(self, msg: can.Message, now_ns: int) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            self.counters["unknown_id"] += 1  # (not a classic CAN frame of the protocol)
            return
        frame_id = msg.arbitration_id
        try:
            decoded = self.codec.decode(frame_id, msg.data)
        except CorruptFrame:
            self.counters["crc_errors"] += 1
            return
        except UnknownFrame:
            self.counters["unknown_id"] += 1
            return
        except MalformedFrame:
            self.counters["malformed"] += 1
            return
        self.counters["frames_in"] += 1
        kind = type(decoded)
        if kind is not Status and kind is not Info:
            return  # other controllers' commands and heartbeats: not ours to act on
        if decoded.vehicle not in self.records:
            self.counters["unknown_vehicle"] += 1
            return
        verdict = self.checks.check(frame_id, decoded.counter)
        if verdict is not ACCEPTED and verdict is not RESYNC:
            return
        if kind is Status:
            self.records.received(decoded, now_ns, verdict is RESYNC)
        else:
            self.records.received_info(decoded, verdict is RESYNC)

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        todo, self._retry = set(self.records.changed()) | self._retry, set()
        for v in sorted(todo):
            go, sequence, nodes = self.records.command(v)
            if self._sent_go.get(v) != go and not go:
                self._send_go(v, go, now_ns)  # a stop goes out before a new route
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
            if self._sent_go.get(v) != go and go:
                self._send_go(v, go, now_ns)  # a go only after the route it is for
        refresh = self._go_sent_ns
        while refresh and now_ns - next(iter(refresh.values())) >= self.go_refresh_ns:
            v = next(iter(refresh))
            self._send_go(v, self._sent_go[v], now_ns)
        if now_ns >= self._next_heartbeat:
            self._next_heartbeat = now_ns + self.heartbeat_ns
            self._send(Heartbeat(CONTROLLER, self._next_counter(HEARTBEAT + CONTROLLER)))

    def _send_go(self, v: int, go: bool, now_ns: int) -> None:
        """StopGo for vehicle v, a new counter each time; a failed send is retried next tick."""
        if self._send(StopGo(v, go, self._next_counter(STOP_GO + v))):
            self._sent_go[v] = go
            self._go_sent_ns[v] = now_ns
            self._go_sent_ns.move_to_end(v)
        else:  # not sent: nothing is known to be sent, so the next tick sends it again
            self._retry.add(v)
            self._sent_go.pop(v, None)
            self._go_sent_ns.pop(v, None)

    def _next_counter(self, frame_id: int) -> int:
        counter = self._counter[frame_id] = (self._counter.get(frame_id, 0) + 1) % 16
        return counter

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
