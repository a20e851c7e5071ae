"""Bus I/O throughput of the runtime's drivers.

1. CAN frames per second through ``CanDriver.read_inputs`` (decode, CRC and counter
   check, confirm, write the image), on the virtual bus and, where a private network
   namespace can be made (root), on udp_multicast over loopback. Baseline, same process: a
   bare python-can ``recv`` loop draining the same number of frames without decoding.
2. Decode cost per status frame: the protected path (the codec compiled from the DBC, the
   CRC-8 and the counter check) against cantools decoding the same frames at run time with
   the same range checks and no protection, in the same run.
3. Modbus TCP requests per second against the runtime's server (read 10 holding
   registers, one synchronous pymodbus client on loopback). Baseline: the same pymodbus
   server serving its own plain simulator datastore, no process image behind it.
4. Scan execution time with 10, 100 and 1000 vehicles on the virtual bus (126 vehicles per
   bus, so 1000 vehicles are 8 buses and 8 drivers), every vehicle reporting every 100 ms;
   the fleet is simulated between scans, outside the measured time. Baseline: the same
   runtime and program without drivers.
6. Modbus clients polling without pause (each sends ten reads of 100 registers at a time
   and waits for the answers, in a process of its own) while the default fleet job runs
   paced at real time (10 ms cycle): the scan's execution time with the server serving
   between scans (as a runtime's driver does) against the same server serving whenever a
   request arrives (baseline), and without clients.
5. A flood of valid status frames (each passes the CRC and counter checks): the time one
   tick's ``read_inputs`` takes with the per-tick cap a fleet program sets
   (``frames_per_tick``: what a 1 Mbit/s bus carries in a cycle) against the driver's
   fixed default of 2,000 frames, for the default job's 4 vehicles at 10 ms and a full
   bus of 126 at 50 ms.

The full run takes about 1 minute. ``--quick`` sends a tenth of the frames, requests and
scans and leaves out the 1000-vehicle row (whose fleet alone takes ~10 s to set up and
simulate): about 5 s, the same ratios with fewer samples behind them.

    .venv/bin/python bench/io_throughput.py [--frames 20000] [--scans 500] [--requests 3000]
        [--vehicles 10 100 1000] [--quick]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from io_drivers.can_driver import CanDriver, frames_per_tick  # noqa: E402
from io_drivers.e2e import CounterCheck  # noqa: E402
from io_drivers.protocol import (  # noqa: E402
    DBC_PATH,
    ID_SPAN,
    MAX_VEHICLE_ID,
    NO_NODE,
    STATES,
    STATUS,
    Codec,
    MalformedFrame,
    Status,
)
from plc_runtime import FunctionBlock, ProcessImage, Runtime, VirtualClock  # noqa: E402
from topology import grid  # noqa: E402
from vehicles.fleet import Fleet  # noqa: E402

_channels = itertools.count()
# --quick lowers these defaults; options given on the command line still win.
QUICK = {"frames": 2000, "scans": 50, "requests": 300, "vehicles": [10, 100]}


def status_frames(n: int, vehicles: int) -> list[can.Message]:
    """n status frames, round robin over the vehicles, each vehicle's counter in sequence."""
    codec = Codec()
    frames = []
    for k in range(n):
        v, counter = k % vehicles + 1, (k // vehicles + 1) % 16
        frame_id, data = codec.encode(Status(v, v, NO_NODE, "DRIVING", 0.5, counter))
        frames.append(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
    return frames


def cantools_decoder():
    """The unprotected baseline: cantools decodes the frame at run time, then the same
    range checks and the same Status as the protected path (no CRC, no counter)."""
    import cantools

    message = cantools.database.load_file(str(DBC_PATH)).get_message_by_frame_id(STATUS)

    def decode(frame_id: int, data: bytes) -> Status:
        sender = frame_id & (ID_SPAN - 1)
        if len(data) != message.length:
            raise MalformedFrame(f"0x{frame_id:03X}: {len(data)} data bytes")
        s = message.decode(data, decode_choices=False, scaling=True)
        if s["state"] >= len(STATES) or not 1 <= sender <= MAX_VEHICLE_ID:
            raise MalformedFrame(f"0x{frame_id:03X}: out-of-range status {s}")
        return Status(
            sender,
            s["current_node"],
            s["next_node"],
            STATES[s["state"]],
            s["speed"],
            s["counter"],
            s["fault"] == 1,
            s["clear"] == 1,
            s["route_ack"],
        )

    return decode


def decode_costs(n: int, repeats: int = 5) -> tuple[float, float]:
    """(protected us per frame, unprotected cantools us per frame): best of ``repeats``."""
    frames = [(m.arbitration_id, bytes(m.data)) for m in status_frames(n, 100)]
    codec, baseline = Codec(), cantools_decoder()

    def protected() -> None:
        decode, check = codec.decode, CounterCheck().check
        for frame_id, data in frames:
            check(frame_id, decode(frame_id, data).counter)

    def unprotected() -> None:
        for frame_id, data in frames:
            baseline(frame_id, data)

    best = []
    for run in (protected, unprotected):
        times = []
        for _ in range(repeats):
            begin = time.perf_counter()
            run()
            times.append(time.perf_counter() - begin)
        best.append(min(times) / n * 1e6)
    return best[0], best[1]


def frame_rates(interface: str, channel: str, n: int) -> tuple[float, float]:
    """(driver frames/s, bare recv frames/s) for n status frames from 100 vehicles."""
    frames = status_frames(n, 100)
    results = []
    for use_driver in (True, False):
        sender = can.Bus(interface=interface, channel=channel, receive_own_messages=False)
        image = ProcessImage({"I": 4096, "Q": 4096})
        driver = CanDriver(range(1, 101), interface=interface, channel=channel, max_frames=n + 10)
        driver.open(image)
        try:
            time.sleep(0.2) if interface != "virtual" else None
            for msg in frames:
                sender.send(msg)
            time.sleep(0.5) if interface != "virtual" else None  # let the socket buffer fill
            begin = time.perf_counter()
            if use_driver:
                driver.read_inputs(image, 0)
                got = driver.counters["frames_in"]
            else:
                got = 0
                while driver.bus.recv(timeout=0) is not None:
                    got += 1
            elapsed = time.perf_counter() - begin
            results.append(got / elapsed if got else 0.0)
        finally:
            driver.close()
            sender.shutdown()
    return results[0], results[1]


class Touch(FunctionBlock):
    """A program that reads every vehicle record (what a fleet program does at least)."""

    def __init__(self, refs):
        super().__init__()
        self.refs = refs

    def cycle(self, ctx):
        read = ctx.image.read
        for ref in self.refs:
            read(ref)


def flood_read_ms(vehicles: int, max_frames: int, ticks: int) -> float:
    """Mean ms of one tick's ``read_inputs`` while more valid frames wait than it may read."""
    channel = f"io-flood-{next(_channels)}"
    sender = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    image = ProcessImage({"I": 4096, "Q": 4096})
    driver = CanDriver(range(1, vehicles + 1), channel=channel, max_frames=max_frames)
    driver.open(image)
    try:
        for msg in status_frames(max_frames * ticks + 1, vehicles):
            sender.send(msg)
        begin = time.perf_counter()
        for _ in range(ticks):
            driver.read_inputs(image, 0)
        elapsed = time.perf_counter() - begin
        assert driver.counters["deferred"] == ticks  # every tick left frames waiting
        return elapsed / ticks * 1e3
    finally:
        driver.close()
        sender.shutdown()


POLLER = """
import socket, struct, sys, time
port, seconds = int(sys.argv[1]), float(sys.argv[2])
request = struct.pack(">BHH", 3, 1024, 100)
batch = b"".join(struct.pack(">HHHB", t, 0, len(request) + 1, 1) + request for t in range(10))
answer = 9 + 200
sock = socket.create_connection(("127.0.0.1", port))
done, end = 0, time.monotonic() + seconds
while time.monotonic() < end:
    sock.sendall(batch)
    got = 0
    while got < 10 * answer:
        got += len(sock.recv(65536))
    done += 10
sock.close()
print(done)
"""


def polled_scans(clients: int, seconds: float, between_scans: bool) -> tuple[float, ...]:
    """(scan p50 us, p99 us, max us, requests/s) of the default fleet job paced at real
    time (10 ms cycle, vehicles simulated in the scan) while ``clients`` Modbus clients
    poll; ``between_scans``: the server is a runtime's driver serving between scans, else
    it serves whenever a request arrives."""
    from fleet.config import load_config
    from fleet.program import FleetProgram
    from io_drivers.modbus_server import ModbusServer
    from plc_runtime import PacedClock

    class AnyTime(ModbusServer):
        def added_to(self, runtime):  # the server as it was: no waiting for the scans
            pass

    cfg = load_config()
    cfg.watchdog = 5.0
    cfg.bus_channel = f"io-polled-{next(_channels)}"
    program = FleetProgram(cfg, clock=PacedClock(1.0))
    rt = program.rt
    server = (ModbusServer if between_scans else AnyTime)(port=0)
    rt.add_driver(server)
    rt.start()
    pollers = [
        subprocess.Popen(
            [sys.executable, "-c", POLLER, str(server.port), str(seconds)],
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(clients)
    ]
    try:
        rt.run(duration=seconds + 0.5)
        answered = sum(int(p.communicate(timeout=30)[0]) for p in pollers)
    finally:
        for p in pollers:
            p.kill()
            p.wait()
        stats = rt.stats.scan
        program.close()
    return (
        stats.exec_percentile_ns(50) / 1e3,
        stats.exec_percentile_ns(99) / 1e3,
        stats.exec_max_ns / 1e3,
        answered / seconds,
    )


def scan_times(vehicles: int, scans: int) -> tuple[float, float, float, float]:
    """p50 and p99 scan exec time (us) with and without the drivers."""
    out = []
    for with_drivers in (True, False):
        plant = grid(40, 40, obstacles=0.0, stations=0)
        per_bus = 125
        groups = [
            list(range(1, min(per_bus, vehicles - b * per_bus) + 1))
            for b in range((vehicles + per_bus - 1) // per_bus)
        ]
        rt = Runtime(
            cycle_time=0.010,
            clock=VirtualClock(),
            image_sizes={"I": 8192 * 2, "Q": 8192 * 2},
            watchdog=5.0,
        )
        fleets, buses, refs = [], [], []
        for b, ids in enumerate(groups):
            channel = f"io-bench-{next(_channels)}"
            base = 1024 * (b + 1)
            if with_drivers:
                rt.add_driver(
                    CanDriver(
                        ids,
                        interface="virtual",
                        channel=channel,
                        input_base=base,
                        output_base=base,
                        name=f"can{b}",
                    )
                )
            bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
            starts = {v: int(plant.ids[(b * per_bus + v) % plant.n]) for v in ids}
            fleets.append(Fleet(plant, starts, bus))
            buses.append(bus)
            refs += [f"%IW{(base + 8 * v) // 2}" for v in ids]
        rt.add_task("program", [Touch(refs)])
        rt.start()
        for _ in range(scans):
            for fleet in fleets:
                fleet.step(0.01)
            rt.step()
        stats = rt.stats.scan
        out += [stats.exec_percentile_ns(50) / 1e3, stats.exec_percentile_ns(99) / 1e3]
        rt.stop()
        for bus in buses:
            bus.shutdown()
    return out[0], out[1], out[2], out[3]


def modbus_rates(requests: int) -> tuple[float, float, float]:
    """(ours req/s, baseline req/s, ours median latency us)."""
    import asyncio
    import threading

    from pymodbus.client import ModbusTcpClient
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    from io_drivers.modbus_server import ModbusServer

    def hammer(port: int) -> tuple[float, float]:
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0)
        client.connect()
        lat = []
        begin = time.perf_counter()
        for _ in range(requests):
            t = time.perf_counter()
            assert not client.read_holding_registers(0, count=10).isError()
            lat.append(time.perf_counter() - t)
        rate = requests / (time.perf_counter() - begin)
        client.close()
        return rate, sorted(lat)[len(lat) // 2] * 1e6

    image = ProcessImage()
    ours = ModbusServer(port=0)
    ours.open(image)
    try:
        rate, median = hammer(ours.port)
    finally:
        ours.close()

    ready, port_box, stop_box = threading.Event(), [], []

    async def serve() -> None:
        device = SimDevice(
            id=0,
            simdata=(
                [SimData(0, values=[False] * 16, datatype=DataType.BITS)],
                [SimData(0, values=[False] * 16, datatype=DataType.BITS)],
                [SimData(0, count=64, values=0, datatype=DataType.REGISTERS)],
                [SimData(0, count=64, values=0, datatype=DataType.REGISTERS)],
            ),
        )
        server = ModbusTcpServer(device, address=("127.0.0.1", 0))
        await server.serve_forever(background=True)
        port_box.append(server.transport.sockets[0].getsockname()[1])
        stop = asyncio.Event()
        stop_box.append((asyncio.get_running_loop(), stop))
        ready.set()
        await stop.wait()
        await server.shutdown()

    thread = threading.Thread(target=lambda: asyncio.run(serve()))
    thread.start()
    ready.wait(10)
    try:
        base_rate, _ = hammer(port_box[0])
    finally:
        loop, stop = stop_box[0]
        loop.call_soon_threadsafe(stop.set)
        thread.join(10)
    return rate, base_rate, median


def udp_rows(frames: int) -> list[str]:
    """Run the udp_multicast measurement in a private network namespace (loopback only)."""
    if os.geteuid() != 0 or not shutil.which("unshare"):
        return [
            "| udp_multicast | - | - | - | not measured: needs root for a private network namespace |"
        ]
    inside = (
        "ip link set lo up && ip route add 224.0.0.0/4 dev lo && "
        f"exec {sys.executable} {Path(__file__).resolve()} --udp-only --frames {frames}"
    )
    result = subprocess.run(
        ["unshare", "-n", "sh", "-c", inside],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    if result.returncode:
        return [
            f"| udp_multicast | - | - | - | failed: {result.stderr.strip().splitlines()[-1][:80]} |"
        ]
    driver, bare = json.loads(result.stdout.strip().splitlines()[-1])
    return [
        f"| udp_multicast (loopback, netns) | {driver:,.0f} | {bare:,.0f} | {driver / bare:.2f} | |"
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--scans", type=int, default=500)
    parser.add_argument("--requests", type=int, default=3000)
    parser.add_argument("--vehicles", type=int, nargs="+", default=[10, 100, 1000])
    parser.add_argument("--udp-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--quick",
        action="store_true",
        help="reduced run: --frames 2000 --scans 50 --requests 300 --vehicles 10 100",
    )
    args = parser.parse_args()
    if args.quick:
        parser.set_defaults(**QUICK)
        args = parser.parse_args()
    if args.udp_only:
        print(json.dumps(frame_rates("udp_multicast", "239.74.163.9", min(args.frames, 5000))))
        return
    begin = time.perf_counter()
    print(f"Bus I/O, Python {sys.version.split()[0]}")
    print()
    print("### CAN frames per second through the driver")
    print()
    print(
        "| bus | driver frames/s (decode + validate + image) | bare recv frames/s | driver / bare | note |"
    )
    print("|---|---:|---:|---:|---|")
    driver, bare = frame_rates("virtual", f"io-rate-{next(_channels)}", args.frames)
    print(f"| virtual | {driver:,.0f} | {bare:,.0f} | {driver / bare:.2f} | |")
    for row in udp_rows(args.frames):
        print(row)
    print()
    print("### Decode cost per status frame")
    print()
    print("| path | us per frame | / unprotected |")
    print("|---|---:|---:|")
    protected, unprotected = decode_costs(args.frames)
    print(
        f"| protected: compiled from the DBC + CRC-8 + counter check | {protected:.2f} "
        f"| {protected / unprotected:.2f} |"
    )
    print(f"| unprotected: cantools decode at run time (baseline) | {unprotected:.2f} | 1 |")
    print()
    print("### Modbus TCP requests per second (read 10 holding registers, loopback)")
    print()
    print("| server | requests/s | median latency us | ours / baseline |")
    print("|---|---:|---:|---:|")
    ours, base, median = modbus_rates(args.requests)
    print(
        f"| runtime's ModbusServer (process image) | {ours:,.0f} | {median:,.0f} | {ours / base:.2f} |"
    )
    print(f"| baseline: pymodbus simulator datastore | {base:,.0f} | - | 1 |")
    print()
    print("### Scan execution time with vehicles on the virtual bus")
    print()
    print(
        "| vehicles | buses | scan p50 us | p99 us | without drivers p50 us | p99 us | p50 ratio |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for n in args.vehicles:
        p50, p99, b50, b99 = scan_times(n, args.scans)
        print(
            f"| {n} | {(n + 124) // 125} | {p50:,.1f} | {p99:,.1f} | {b50:,.1f} | {b99:,.1f} | {p50 / b50:.1f} |"
        )
    print()
    print("### Modbus clients polling without pause: the scan's execution time")
    print()
    print(
        "| clients | server serves | scan p50 us | p99 us | max us | requests/s | p99 / any time |"
    )
    print("|---:|---|---:|---:|---:|---:|---:|")
    seconds = 1.0 if args.quick else 5.0
    print("| 0 | - | {:,.0f} | {:,.0f} | {:,.0f} | 0 | - |".format(*polled_scans(0, seconds, True)))
    for clients in (2, 4):
        quiet = polled_scans(clients, seconds, True)
        any_time = polled_scans(clients, seconds, False)
        print(
            f"| {clients} | between scans | {quiet[0]:,.0f} | {quiet[1]:,.0f} | {quiet[2]:,.0f} "
            f"| {quiet[3]:,.0f} | {quiet[1] / any_time[1]:.2f} |"
        )
        print(
            f"| {clients} | any time (baseline) | {any_time[0]:,.0f} | {any_time[1]:,.0f} "
            f"| {any_time[2]:,.0f} | {any_time[3]:,.0f} | 1 |"
        )
    print()
    print("### A flood of valid frames: one tick's input phase")
    print()
    print(
        "| vehicles | cycle ms | frames read per tick | ms per tick | fixed 2,000: ms "
        "| / fixed | / cycle |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    ticks = max(2, args.frames // 2000)
    for vehicles, cycle in ((4, 0.010), (126, 0.050)):
        cap = frames_per_tick(cycle, vehicles, 0.1)
        capped = flood_read_ms(vehicles, cap, ticks)
        fixed = flood_read_ms(vehicles, 2000, ticks)
        print(
            f"| {vehicles} | {cycle * 1e3:g} | {cap} | {capped:.2f} | {fixed:.2f} "
            f"| {capped / fixed:.2f} | {capped / (cycle * 1e3):.2f} |"
        )
    print()
    print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
