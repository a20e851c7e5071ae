"""Each simulated AGV as a Modbus TCP server: the alternative vehicle link to CAN.

The registers carry the CAN message set's own payloads, one byte per register, with the same
end-to-end protection (CRC over the frame id of the vehicle's CAN message and the payload,
and its counter), so both links share one definition and one check (docs/protocol.md):

    input registers   0..7   VehicleStatus payload (data id 0x100 + vehicle id)
                      8..10  VehicleInfo payload (data id 0x600 + vehicle id)
    holding registers 0..7   RouteCommand payload (data id 0x200 + vehicle id)
                      8..9   StopGo payload (data id 0x080 + vehicle id)

The input registers hold the last frame of each kind the vehicle produced, faults injected
and all. A write completing a command frame (0..7, 8..9, or 0..9 with both) queues it; the
fleet checks and applies it at the start of the next simulation step, as if it had come
over CAN. Other addresses read 0; writes elsewhere, or of values above 255, are refused.
"""

from __future__ import annotations

import threading
from collections import deque

from io_drivers.modbus_server import _ModbusThread
from io_drivers.protocol import INFO, ROUTE, STATUS, STOP_GO

from .fleet import Fleet

STATUS_REGISTERS, INFO_REGISTERS = 8, 3
ROUTE_REGISTERS, STOP_GO_REGISTERS = 8, 2
COMMAND_REGISTERS = ROUTE_REGISTERS + STOP_GO_REGISTERS


class VehicleModbusEndpoints:
    def __init__(self, fleet: Fleet, host: str = "127.0.0.1", base_port: int = 0) -> None:
        self.fleet, self.host, self.base_port = fleet, host, base_port
        self.ports: dict[int, int] = {}
        self._servers: list[_ModbusThread] = []
        self._lock = threading.Lock()
        self._status = {v: [0] * (STATUS_REGISTERS + INFO_REGISTERS) for v in fleet.vehicles}
        self._commands = {v: [0] * COMMAND_REGISTERS for v in fleet.vehicles}
        self._queue: deque[tuple[int, bytes]] = deque()

    def start(self) -> dict[int, int]:
        """Start one server per vehicle (port base_port + vehicle id, or ephemeral with 0),
        after the vehicles' power-on reports: no client ever reads an empty register block."""
        self.fleet.announce()
        self.publish()
        try:
            for v in self.fleet.vehicles:
                server = _ModbusThread(
                    self._reader(v),
                    self._writer(v),
                    self.host,
                    self.base_port + v if self.base_port else 0,
                )
                self.ports[v] = server.start()
                self._servers.append(server)
        except BaseException:
            self.stop()
            raise
        return self.ports

    def stop(self) -> None:
        for server in self._servers:
            server.stop()
        self._servers.clear()

    def apply(self) -> None:
        """Before a simulation step: hand the queued command frames to the fleet."""
        while self._queue:
            self.fleet.receive(*self._queue.popleft())

    def publish(self) -> None:
        """After a simulation step: the frames the servers answer with."""
        frames = self.fleet.frames
        with self._lock:
            for v in self.fleet.vehicles:
                status = frames.get(STATUS + v, bytes(STATUS_REGISTERS))
                info = frames.get(INFO + v, bytes(INFO_REGISTERS))
                self._status[v] = [*status, *info]

    def _reader(self, v: int):
        def read(area: str, address: int, count: int) -> list:
            with self._lock:
                source = {"ir": self._status[v], "hr": self._commands[v]}.get(area, [])
                return [
                    source[a] if a < len(source) else 0 for a in range(address, address + count)
                ]

        return read

    def _writer(self, v: int):
        from pymodbus.constants import ExcCodes

        def write(area: str, address: int, values: list) -> ExcCodes | None:
            end = address + len(values)
            if area != "hr" or end > COMMAND_REGISTERS:
                return ExcCodes.ILLEGAL_ADDRESS
            if any(not 0 <= int(x) <= 0xFF for x in values):
                return ExcCodes.ILLEGAL_VALUE  # every register carries one payload byte
            with self._lock:
                block = self._commands[v]
                block[address:end] = [int(x) for x in values]
                if address == 0 and end >= ROUTE_REGISTERS:
                    self._queue.append((ROUTE + v, bytes(block[:ROUTE_REGISTERS])))
                if address <= ROUTE_REGISTERS and end == COMMAND_REGISTERS:
                    self._queue.append((STOP_GO + v, bytes(block[ROUTE_REGISTERS:])))
            return None

        return write
