"""Vehicles in their own process on the wall clock (``plc-runtime vehicles``).

Real-time runs keep CPU-heavy simulation out of the runtime's process (a second Python
thread there would cost the scan milliseconds of lateness), so the fleet runs here, on its
own bus endpoint, stepped against absolute monotonic deadlines. SIGINT/SIGTERM end it
cleanly: the bus is shut down, nothing is left behind.
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Mapping

from io_drivers.can_bus import bus_channels, bus_of, bus_options, by_bus, open_can_bus
from io_drivers.protocol import MAX_VEHICLE_ID
from plc_runtime.clock import WallClock
from topology import Plant

from .agv import AgvParams
from .fleet import Faults, Fleet
from .modbus_endpoint import VehicleModbusEndpoints


def default_starts(plant: Plant, count: int) -> dict[int, int]:
    """Vehicles 1..count on distinct nodes: entries first, then parking, chargers, transit."""
    order = ("entry", "parking", "charger", "transit", "station", "exit")
    nodes = [n.id for role in order for n in plant.nodes if n.role == role]
    if count > len(nodes):
        raise ValueError(f"--count {count}: the plant has {len(nodes)} nodes")
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
    on_step: Callable[[list[tuple[int, Fleet]]], None] | None = None,
    status_period: float = 0.1,
    params: AgvParams | None = None,
    charges: Mapping[int, float] | None = None,
) -> list[tuple[int, Fleet]]:
    """Step the fleet every ``period`` wall-clock seconds until ``duration`` or a signal.

    The vehicles talk over the CAN bus ``interface:channel``, or, with ``modbus_base_port``,
    each through its own Modbus TCP server on 127.0.0.1:(base port + vehicle id). A CAN
    bus carries vehicle ids 1..126: ``channel`` names one channel per bus, comma-separated
    (vcan0,vcan1: vehicles 127..252 on vcan1 as ids 1..126). Returns each bus's fleet
    with the offset of its ids (0 for the first).
    """
    stop = False

    def request_stop(*_: object) -> None:
        nonlocal stop
        stop = True

    # per bus (None: a Modbus link, no buses): its channel and its vehicles' starts, faults
    # and charges by their ids on it
    groups: dict[int | None, tuple[str | None, dict, dict, dict]] = {
        None: (None, dict(starts), dict(faults or {}), dict(charges or {}))
    }
    if not modbus_base_port:
        channels = bus_channels(channel or "")
        needed = bus_of(max(starts))[0] + 1
        if needed > len(channels):
            raise ValueError(
                f"vehicle {max(starts)} needs {needed} buses, and {channel!r} names "
                f"{len(channels)} channel(s)"
            )
        on_bus = [by_bus(values or {}) for values in (starts, faults, charges)]
        groups = {
            k: (channels[k], *(values.get(k, {}) for values in on_bus)) for k in sorted(on_bus[0])
        }
    buses, fleets = [], []
    try:
        for k, (ch, own_starts, own_faults, own_charges) in groups.items():
            bus = None if ch is None else open_can_bus(interface, ch, **bus_options(interface, k))
            if bus is not None:
                buses.append(bus)
            fleet = Fleet(
                plant,
                own_starts,
                bus,
                params=params,
                faults=own_faults or None,
                seed=seed + (k or 0),
                status_period=status_period,
                charges=own_charges or None,
            )
            fleets.append(((k or 0) * MAX_VEHICLE_ID, fleet))
    except BaseException:
        for bus in buses:
            bus.shutdown()
        raise
    endpoints = (
        VehicleModbusEndpoints(fleets[0][1], base_port=modbus_base_port)
        if modbus_base_port
        else None
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
            for _, fleet in fleets:
                fleet.step(period)
            if on_step:
                on_step(fleets)
            if endpoints:
                endpoints.publish()
        return fleets
    finally:
        if endpoints:
            endpoints.stop()
        for bus in buses:
            bus.shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
