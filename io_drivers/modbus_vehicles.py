"""ModbusVehicleLink: the runtime exchanges with every vehicle's Modbus TCP server.

The alternative to the CAN link (vehicles/modbus_endpoint.py has the register map). The scan
never waits for the network: an asyncio worker thread polls all vehicles concurrently every
``poll_period`` (read the status registers, write a changed command block with one FC16),
each request bounded by ``timeout``; the scan and the worker meet in a double buffer:

* ``read_inputs`` (quiet point) takes the newest statuses the worker has collected and
  writes them into the vehicle records of the image (docs/protocol.md), flags included:
  a vehicle with no fresh status for ``stale_after`` seconds is stale.
* ``write_outputs`` (after copy-out) hands changed command records to the worker.

A vehicle that does not answer, refuses, or drops its connection is counted and retried
at the next poll; nothing of that reaches the scan except its stale flag.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Mapping

from pymodbus.client import AsyncModbusTcpClient

from plc_runtime import ConfigError, ProcessImage

from .protocol import STATES, Status
from .vehicle_records import VehicleRecords

STATUS_REGISTERS, COMMAND_REGISTERS = 8, 6


class ModbusVehicleLink:
    def __init__(
        self,
        vehicles: Mapping[int, tuple[str, int]],
        poll_period: float = 0.02,
        timeout: float = 0.2,
        stale_after: float = 0.5,
        input_base: int = 1024,
        output_base: int = 1024,
        name: str = "modbus-vehicles",
    ) -> None:
        self.name = name
        self.addresses = dict(vehicles)
        self.poll_period, self.timeout = poll_period, timeout
        self.stale_after_ns = round(stale_after * 1e9)
        self.input_base, self.output_base = input_base, output_base
        self.counters = {"polls": 0, "reads": 0, "writes": 0, "failures": 0, "bad_status": 0}
        self._thread: threading.Thread | None = None

    # ----- lifecycle (scan thread) ----------------------------------------------------
    def open(self, image: ProcessImage) -> None:
        self.records = VehicleRecords(
            image, self.addresses, self.input_base, self.output_base, self.stale_after_ns
        )
        self._lock = threading.Lock()
        self._fresh: dict[int, Status] = {}  # written by the worker, taken by read_inputs
        self._commands: dict[int, list[int]] = {}  # written by write_outputs, taken by the worker
        self._sent_go: dict[int, bool] = {}
        self._sent_sequence: dict[int, int] = {}
        self._ready = threading.Event()
        self._thread = threading.Thread(
            target=lambda: asyncio.run(self._worker()), name=self.name, daemon=True
        )
        self._thread.start()
        if not self._ready.wait(5):
            raise ConfigError(f"{self.name}: the worker did not start")

    def close(self) -> None:
        if self._thread is None:
            return
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)
        self._thread = None

    def stats(self) -> dict[str, object]:
        stale = self.records.stale() if self._thread else []
        return {**self.counters, "online": len(self.records.vehicles) - len(stale), "stale": stale}

    # ----- the scan ---------------------------------------------------------------------
    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        with self._lock:
            fresh, self._fresh = self._fresh, {}
        for status in fresh.values():
            self.records.received(status, now_ns)
        self.records.refresh_flags(now_ns)

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        for v in self.records.changed():
            go, sequence, nodes = self.records.command(v)
            new_route = sequence != self._sent_sequence.get(v, 0) and nodes is not None
            if not new_route and self._sent_go.get(v) == go:
                continue
            with self._lock:
                pending = self._commands.get(v)
                if not new_route and pending is not None and pending[3] > 0:
                    pending[4] = int(
                        go
                    )  # go changed while a route waits: keep the route, update go
                else:
                    nodes = nodes if new_route else ()
                    # count 0 (go only) leaves the vehicle's released route alone
                    self._commands[v] = [*nodes, 0, 0, 0][:3] + [len(nodes), int(go), sequence % 16]
            self._sent_go[v], self._sent_sequence[v] = go, sequence

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
        block, sent = None, False
        try:
            if not client.connected and not await client.connect():
                self.counters["failures"] += 1
                return
            with self._lock:
                block = self._commands.pop(v, None)
            if block is not None:
                reply = await client.write_registers(0, block, device_id=1)
                if reply.isError():
                    self.counters["failures"] += 1
                    with self._lock:
                        self._commands.setdefault(v, block)  # retry at the next poll
                else:
                    sent = True
                    self.counters["writes"] += 1
            reply = await client.read_input_registers(0, count=STATUS_REGISTERS, device_id=1)
            if reply.isError():
                self.counters["failures"] += 1
                return
            current, nxt, state, battery, speed, alive, fault, clear = reply.registers
            if state >= len(STATES) or battery > 100:
                self.counters["bad_status"] += 1
                return
            status = Status(
                v,
                current,
                nxt,
                STATES[state],
                battery,
                speed / 100,
                alive,
                bool(fault),
                bool(clear),
            )
            self.counters["reads"] += 1
            with self._lock:
                self._fresh[v] = status
        except Exception:  # connection lost, timeout: counted; the next poll tries again
            self.counters["failures"] += 1
            if block is not None and not sent:
                with self._lock:
                    self._commands.setdefault(v, block)  # not delivered: send it again next poll
            client.close()
