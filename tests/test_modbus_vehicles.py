"""The Modbus vehicle link: every AGV a Modbus TCP server (own process), the runtime polling
them from a worker thread without blocking the scan. Loopback only."""

import json
import subprocess
import sys
from pathlib import Path

from fleet_helpers import Dispatcher, record
from ports import free_base_port

from io_drivers.modbus_vehicles import ModbusVehicleLink
from io_drivers.vehicle_records import ONLINE, STALE
from plc_runtime import Runtime, WallClock


def test_runtime_drives_vehicles_over_their_modbus_servers():
    script = Path(sys.executable).parent / "plc-runtime"
    for _ in range(3):  # again on other ports if another process took one meanwhile
        base = free_base_port(3)
        cmd = [str(script), "vehicles", "--plant", "model-plant", "--count", "2"]
        cmd += ["--modbus-base-port", str(base), "--duration", "60", "--json"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        ready = proc.stderr.readline()
        if "address already in use" not in ready:
            break
        proc.wait(timeout=30)
    try:
        assert "vehicles ready" in ready, ready
        link = ModbusVehicleLink({1: ("127.0.0.1", base + 1), 2: ("127.0.0.1", base + 2)})
        # real time and a vehicle process beside it: a busy machine must not fault a scan
        rt = Runtime(cycle_time=0.010, clock=WallClock(), watchdog=5.0)
        rt.add_driver(link)
        rt.add_task("program", [Dispatcher({1: [0, 6, 7, 8, 9, 24], 2: [1, 15, 2]})])
        rt.start()
        arrived = rt.run_until(
            lambda: (
                rt.image.read(f"%IW{record(1) // 2}") == 24
                and rt.image.read(f"%IW{record(2) // 2}") == 2
            ),
            max_cycles=3000,
        )
        flags = rt.image.read(f"%IB{record(1) + 7}")
        stats = link.stats()
        proc.terminate()  # the vehicles go away ...
        proc.wait(timeout=30)
        # ... and are stale soon after (on the wall clock: how soon depends on the machine)
        rt.run_until(lambda: rt.image.read(f"%IB{record(1) + 7}") == STALE, max_cycles=2000)
        stale = rt.image.read(f"%IB{record(1) + 7}")
        rt.stop()
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert arrived and flags == ONLINE and stats["reads"] > 0 and stats["writes"] >= 2
    assert stats["crc_errors"] == stats["malformed"] == stats["resyncs"] == 0
    assert stale == STALE
    report = json.loads(out)
    assert report["vehicles"]["1"]["driven"] == [0, 6, 7, 8, 9, 24]
    assert report["vehicles"]["2"]["driven"] == [1, 15, 2]


def test_go_change_does_not_overwrite_a_waiting_route():
    from io_drivers.protocol import ROUTE, STOP_GO, Codec, RouteCommand, StopGo
    from io_drivers.vehicle_records import GO_BIT
    from plc_runtime import ProcessImage

    image = ProcessImage()
    link = ModbusVehicleLink({1: ("127.0.0.1", 1)}, poll_period=60.0, timeout=0.01)  # nobody there
    link.open(image)
    try:
        base = record(1)
        q = image.published_outputs.view("<u2")
        q[base // 2], q[base // 2 + 1] = 6, 7
        image.published_outputs.bytes[base + 6] = 2  # count 2, go 0
        image.published_outputs.bytes[base + 7] = 1  # sequence 1: a new route
        link.write_outputs(image, 0)
        image.published_outputs.bytes[base + 6] = 2 | GO_BIT  # next scan: go
        link.write_outputs(image, 10_000_000)
        with link._lock:
            frames = dict(link._commands[1])
        codec = Codec()
        # the route is still there, and the newest stop/go frame (go, its counter 2) with it
        assert codec.decode(ROUTE + 1, bytes(frames["route"])) == RouteCommand(1, 1, (6, 7))
        assert codec.decode(STOP_GO + 1, bytes(frames["stop_go"])) == StopGo(1, True, 2)
    finally:
        link.close()


def test_stopping_the_runtime_stops_the_vehicles_over_modbus():
    """The safe state (outputs 0) reaches the vehicles before the link closes, and closing
    the link tells every vehicle to stop, as the CAN driver's close does."""
    from topology import model_plant
    from vehicles.fleet import Fleet
    from vehicles.modbus_endpoint import VehicleModbusEndpoints

    fleet = Fleet(model_plant(), {1: 0})
    endpoints = VehicleModbusEndpoints(fleet)
    ports = endpoints.start()
    try:
        link = ModbusVehicleLink({1: ("127.0.0.1", ports[1])})
        # the wall clock and a server thread: a busy machine must not fault a scan
        rt = Runtime(cycle_time=0.010, clock=WallClock(), watchdog=5.0)
        rt.add_driver(link)
        rt.add_task("program", [Dispatcher({1: [0, 6, 7, 8, 9, 24]})])
        rt.start()
        agv = fleet.vehicles[1]
        for _ in range(3000):  # the vehicle process's loop, in this thread
            rt.step()
            endpoints.apply()
            fleet.step(0.01)
            endpoints.publish()
            if agv.target is not None:
                break
        assert agv.target is not None and agv.go
        rt.stop()
        endpoints.apply()
        assert agv.go is False
    finally:
        endpoints.stop()
