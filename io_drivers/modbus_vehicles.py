"""ModbusVehicleLink: the runtime exchanges with every vehicle's Modbus TCP server.

The alternative to the CAN link (vehicles/modbus_endpoint.py has the register map: the CAN
message set's payloads, one byte per register, with the same end-to-end protection). The
scan never waits for the network: an asyncio worker thread polls all vehicles concurrently
every ``poll_period`` (read the status and info registers, write changed command frames
with one FC16), each request bounded by ``timeout``; the scan and the worker meet in a
double buffer:

* the worker checks every new register block as the CAN driver checks a frame (CRC over
  the CAN frame id and the payload, counter; a block unchanged since the last poll is no
  new frame) and queues what passes;
* ``read_inputs`` (quiet point) hands the queued frames, in order, to the vehicle records
  of the image (docs/protocol.md), which confirm positions and keep the flags: a vehicle
  with no confirmed status for ``stale_after`` seconds is stale;
* ``write_outputs`` (after copy-out) encodes changed command records as frames for the
  worker; StopGo is repeated every ``go_refresh`` seconds, as on CAN.

A vehicle that does not answer, refuses, or drops its connection is counted and retried
at the next poll; nothing of that reaches the scan except its stale flag. Counts:
``crc_errors``, ``malformed``, ``repeated``, ``out_of_sequence``, ``resyncs``, ``lost``
(frames the vehicle produced that no poll saw, or lost on the way), ``unconfirmed``.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Mapping

from pymodbus.client import AsyncModbusTcpClient

from plc_runtime import ConfigError, ProcessImage

from .e2e import ACCEPTED, RESYNC, CounterCheck
from .protocol import (
    INFO,
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
from .vehicle_records import VehicleRecords

STATUS_REGISTERS, INFO_REGISTERS = 8, 3  # input registers 0..7 and 8..10
ROUTE_REGISTERS, STOP_GO_REGISTERS = 8, 2  # holding registers 0..7 and 8..9


class ModbusVehicleLink:
    def __init__(
        self,
        vehicles: Mapping[int, tuple[str, int]],
        poll_period: float = 0.02,
        timeout: float = 0.2,
        stale_after: float = 0.5,
        input_base: int = 1024,
        output_base: int = 1024,
        go_refresh: float = 1.0,
        name: str = "modbus-vehicles",
    ) -> None:
        self.name = name
        self.addresses = dict(vehicles)
        self.poll_period, self.timeout = poll_period, timeout
        self.stale_after_ns = round(stale_after * 1e9)
        self.go_refresh_ns = round(go_refresh * 1e9)
        self.input_base, self.output_base = input_base, output_base
        self.codec = Codec()
        self.records: VehicleRecords | None = None  # made at open (the image's records)
        self.counters = dict.fromkeys(
            ("polls", "reads", "writes", "failures", "malformed", "crc_errors", "bad_commands"),
            0,
        )
        self.checks = CounterCheck(self.counters)  # in the worker thread only
        self._thread: threading.Thread | None = None

    # ----- lifecycle (scan thread) ----------------------------------------------------
    def open(self, image: ProcessImage) -> None:
        self.records = VehicleRecords(
            image, self.addresses, self.input_base, self.output_base, self.stale_after_ns
        )
        self._lock = threading.Lock()
        # written by the worker, taken by read_inputs: accepted frames and whether the
        # counter check resynchronised to them
        self._fresh: dict[int, list[tuple[Status | Info, bool]]] = {}
        # written by write_outputs, taken by the worker: "route" / "stop_go" register values
        self._commands: dict[int, dict[str, list[int]]] = {}
        self._last_block: dict[int, list[int]] = {}  # worker: frame id -> registers last read
        self._sent_go: dict[int, bool] = {}
        self._sent_sequence: dict[int, int] = {}
        self._go_sent_ns: OrderedDict[int, int] = OrderedDict()  # oldest first
        self._counter: dict[int, int] = {}
        self._ready = threading.Event()
        self._thread = threading.Thread(
            target=lambda: asyncio.run(self._worker()), name=self.name, daemon=True
        )
        self._thread.start()
        if not self._ready.wait(5):
            raise ConfigError(f"{self.name}: the worker did not start")

    def close(self) -> None:
        """The controller goes away: every vehicle is told to stop, and what waits to be
        written (that stop, the runtime's safe state) is delivered before the link closes,
        waiting at most two poll periods and one timeout."""
        if self._thread is None:
            return
        now = time.monotonic_ns()
        for v in self.addresses:
            self._queue_go(v, False, now)
        deadline = time.monotonic() + 2 * self.poll_period + self.timeout
        while time.monotonic() < deadline:
            with self._lock:
                if not self._commands:
                    break
            time.sleep(0.005)
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)
        self._thread = None

    def stats(self) -> dict[str, object]:
        # as of the last tick, so a summary taken after the link closed shows how it ended
        if self.records is None:  # not started
            return {**self.counters, "unconfirmed": 0, "online": 0, "stale": []}
        return self.records.link_stats(self.counters)

    # ----- the scan ---------------------------------------------------------------------
    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        with self._lock:
            fresh, self._fresh = self._fresh, {}
        for frames in fresh.values():
            for message, resync in frames:
                if type(message) is Status:
                    self.records.received(message, now_ns, resync)
                else:
                    self.records.received_info(message, resync)
        self.records.refresh_flags(now_ns)

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        for v in self.records.changed():
            go, sequence, nodes = self.records.command(v)
            if sequence != self._sent_sequence.get(v, 0):  # 0 is "no command yet"
                self._sent_sequence[v] = sequence
                if nodes is None:
                    self.counters["bad_commands"] += 1  # not sendable: wait for the next
                else:
                    route = RouteCommand(v, sequence % 16, nodes)
                    self._queue(v, "route", self.codec.encode(route)[1])
            if self._sent_go.get(v) != go:
                self._queue_go(v, go, now_ns)
        refresh = self._go_sent_ns
        while refresh and now_ns - next(iter(refresh.values())) >= self.go_refresh_ns:
            v = next(iter(refresh))
            self._queue_go(v, self._sent_go[v], now_ns)

    def _queue_go(self, v: int, go: bool, now_ns: int) -> None:
        counter = self._counter[v] = (self._counter.get(v, 0) + 1) % 16
        self._queue(v, "stop_go", self.codec.encode(StopGo(v, go, counter))[1])
        self._sent_go[v] = go
        self._go_sent_ns[v] = now_ns
        self._go_sent_ns.move_to_end(v)

    def _queue(self, v: int, part: str, payload: bytes) -> None:
        """The newest frame of each kind waits for the worker (it replaces an unsent one)."""
        with self._lock:
            self._commands.setdefault(v, {})[part] = list(payload)

    # ----- the worker thread --------------------------------------------------------------
    async def _worker(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        logging.getLogger("pymodbus.logging").setLevel(
            logging.CRITICAL
        )  # failures are counted instead
        self._ready.set()
        # One polling loop per vehicle: a vehicle that does not answer delays only itself.
        await asyncio.gather(
            *(self._poll(v, host, port) for v, (host, port) in self.addresses.items())
        )

    async def _poll(self, v: int, host: str, port: int) -> None:
        client = AsyncModbusTcpClient(host, port=port, timeout=self.timeout, retries=0)
        try:
            while not self._stop.is_set():
                begin = time.monotonic()
                self.counters["polls"] += 1
                await self._exchange(v, client)
                delay = self.poll_period - (time.monotonic() - begin)
                try:
                    await asyncio.wait_for(self._stop.wait(), timeout=max(delay, 0.0))
                except TimeoutError:
                    pass
        finally:
            client.close()

    async def _exchange(self, v: int, client: AsyncModbusTcpClient) -> None:
        pending, sent = None, False
        try:
            if not client.connected and not await client.connect():
                self.counters["failures"] += 1
                return
            with self._lock:
                pending = self._commands.pop(v, None)
            if pending:
                route, stop_go = pending.get("route"), pending.get("stop_go")
                address = 0 if route else ROUTE_REGISTERS
                values = (route or []) + (stop_go or [])
                reply = await client.write_registers(address, values, device_id=1)
                if reply.isError():
                    self.counters["failures"] += 1
                    self._requeue(v, pending)  # retry at the next poll
                else:
                    sent = True
                    self.counters["writes"] += 1
            reply = await client.read_input_registers(
                0, count=STATUS_REGISTERS + INFO_REGISTERS, device_id=1
            )
            if reply.isError():
                self.counters["failures"] += 1
                return
            self.counters["reads"] += 1
            registers = reply.registers
            self._check(v, STATUS + v, registers[:STATUS_REGISTERS])
            self._check(v, INFO + v, registers[STATUS_REGISTERS:])
        except Exception:  # connection lost, timeout: counted; the next poll tries again
            self.counters["failures"] += 1
            if pending and not sent:
                self._requeue(v, pending)  # not delivered: send it again next poll
            client.close()

    def _requeue(self, v: int, pending: dict[str, list[int]]) -> None:
        with self._lock:
            waiting = self._commands.setdefault(v, {})
            for part, values in pending.items():
                waiting.setdefault(part, values)  # a newer frame of that kind wins

    def _check(self, v: int, frame_id: int, block: list[int]) -> None:
        """One register block read: the same checks as a CAN frame. A block unchanged since
        the last poll is the same frame again, not a new (repeated) one."""
        if block == self._last_block.get(frame_id):
            return
        self._last_block[frame_id] = block
        try:
            message = self.codec.decode(frame_id, bytes(block))
        except CorruptFrame:
            self.counters["crc_errors"] += 1
            return
        except (MalformedFrame, UnknownFrame, ValueError):  # ValueError: a register > 255
            self.counters["malformed"] += 1
            return
        verdict = self.checks.check(frame_id, message.counter)
        if verdict is ACCEPTED or verdict is RESYNC:
            with self._lock:
                self._fresh.setdefault(v, []).append((message, verdict is RESYNC))
