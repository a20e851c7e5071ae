"""Each simulated AGV as a Modbus TCP server: the alternative vehicle link to CAN.

Register map of one vehicle (all other addresses answer 0; writes elsewhere are refused):

    input registers   0 current node   1 next node (65535: none)   2 state code
                      3 battery %      4 speed cm/s                5 alive counter   6 fault
                      7 clear of the current node (1/0)
    holding registers 0..2 next nodes  3 count (1..3)  4 go (0/1)  5 sequence (new value: new route)

The controller writes the command block with one FC16 request, so a route never arrives
half written. Writes are queued and applied at the start of the next simulation step;
reads are answered from the status published after the last step.
"""

from __future__ import annotations

import threading
from collections import deque

from io_drivers.modbus_server import _ModbusThread
from io_drivers.protocol import STATE_CODE, RouteCommand, StopGo

from .fleet import Fleet

STATUS_REGISTERS = 8
COMMAND_REGISTERS = 6


class VehicleModbusEndpoints:
    def __init__(self, fleet: Fleet, host: str = "127.0.0.1", base_port: int = 0) -> None:
        self.fleet, self.host, self.base_port = fleet, host, base_port
        self.ports: dict[int, int] = {}
        self._servers: list[_ModbusThread] = []
        self._lock = threading.Lock()
        self._status = {v: [0] * STATUS_REGISTERS for v in fleet.vehicles}
        self._commands = {v: [0] * COMMAND_REGISTERS for v in fleet.vehicles}
        self._queue: deque[tuple[int, list[int]]] = deque()

    def start(self) -> dict[int, int]:
        """Start one server per vehicle (port base_port + vehicle id, or ephemeral with 0)."""
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
        self.publish()
        return self.ports

    def stop(self) -> None:
        for server in self._servers:
            server.stop()
        self._servers.clear()

    def apply(self) -> None:
        """Before a simulation step: hand queued command writes to the fleet."""
        while self._queue:
            v, block = self._queue.popleft()
            nodes, count, go, sequence = block[0:3], block[3], block[4], block[5]
            self.fleet.apply(StopGo(v, bool(go)))
            if 1 <= count <= 3:
                self.fleet.apply(RouteCommand(v, sequence % 16, tuple(nodes[:count])))

    def publish(self) -> None:
        """After a simulation step: the status the servers answer with."""
        with self._lock:
            for v in self.fleet.vehicles:
                s = self.fleet.status(v)
                self._status[v] = [
                    s.current_node,
                    s.next_node,
                    STATE_CODE[s.state],
                    s.battery,
                    min(255, round(s.speed * 100)),
                    s.alive,
                    int(s.fault),
                    int(s.clear),
                ]

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
            if area != "hr" or address + len(values) > COMMAND_REGISTERS:
                return ExcCodes.ILLEGAL_ADDRESS
            with self._lock:
                self._commands[v][address : address + len(values)] = [int(x) for x in values]
                block = list(self._commands[v])
            if (
                address + len(values) == COMMAND_REGISTERS
            ):  # the block is complete with the sequence
                self._queue.append((v, block))
            return None

        return write
