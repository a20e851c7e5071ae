"""Vehicles in their own process on the wall clock (``plc-runtime vehicles``).

Real-time runs keep CPU-heavy simulation out of the runtime's process (a second Python
thread there would cost the scan milliseconds of lateness), so the fleet runs here, on its
own bus endpoint, stepped against absolute monotonic deadlines. SIGINT/SIGTERM end it
cleanly: the bus is shut down, nothing is left behind.
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Mapping

from io_drivers.can_bus import open_can_bus
from plc_runtime.clock import WallClock
from topology import Plant

from .agv import AgvParams
from .fleet import Faults, Fleet
from .modbus_endpoint import VehicleModbusEndpoints


def default_starts(plant: Plant, count: int) -> dict[int, int]:
    """Vehicles 1..count on distinct nodes: entries first, then parking, chargers, transit."""
    order = ("entry", "parking", "charger", "transit", "station", "exit")
    nodes = [n.id for role in order for n in plant.nodes if n.role == role]
    if count > len(nodes) or not 1 <= count <= 126:
        raise ValueError(
            f"--count {count}: the plant has {len(nodes)} nodes, and a bus carries 1..126 vehicles"
        )
    return {v + 1: nodes[v] for v in range(count)}


def run_fleet(
    plant: Plant,
    starts: Mapping[int, int],
    interface: str | None,
    channel: str | None,
    period: float = 0.01,
    duration: float | None = None,
    seed: int = 0,
    faults: Mapping[int, Faults] | None = None,
    modbus_base_port: int | None = None,
    on_ready: Callable[[str], None] | None = None,
    on_step: Callable[[Fleet], None] | None = None,
    status_period: float = 0.1,
    params: AgvParams | None = None,
    charges: Mapping[int, float] | None = None,
) -> Fleet:
    """Step the fleet every ``period`` wall-clock seconds until ``duration`` or a signal.

    The vehicles talk over the CAN bus ``interface:channel``, or, with ``modbus_base_port``,
    each through its own Modbus TCP server on 127.0.0.1:(base port + vehicle id).
    """
    stop = False

    def request_stop(*_: object) -> None:
        nonlocal stop
        stop = True

    bus = None if modbus_base_port else open_can_bus(interface, channel)
    try:
        fleet = Fleet(
            plant,
            starts,
            bus,
            params=params,
            faults=faults,
            seed=seed,
            status_period=status_period,
            charges=charges,
        )
    except BaseException:
        if bus is not None:
            bus.shutdown()
        raise
    endpoints = (
        VehicleModbusEndpoints(fleet, base_port=modbus_base_port) if modbus_base_port else None
    )
    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        if endpoints:
            ports = endpoints.start()
            if on_ready:
                on_ready(f"modbus servers on 127.0.0.1 ports {ports}")
        elif on_ready:
            on_ready(f"bus {interface}:{channel}")
        clock = WallClock(spin=0.0)
        t0, k = clock.now_ns(), 0
        period_ns = round(period * 1e9)
        end = None if duration is None else t0 + round(duration * 1e9)
        while not stop and (end is None or clock.now_ns() < end):
            k += 1
            clock.wait_until(t0 + k * period_ns)
            if endpoints:
                endpoints.apply()
            fleet.step(period)
            if on_step:
                on_step(fleet)
            if endpoints:
                endpoints.publish()
        return fleet
    finally:
        if endpoints:
            endpoints.stop()
        if bus is not None:
            bus.shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
