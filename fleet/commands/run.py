"""``plc-runtime run [CONFIG]`` for the fleet program: the main job.

On the virtual clock (the default) the vehicles are simulated in this process over the
in-process virtual CAN bus, faster than real time. With ``--realtime`` the scan runs on the
wall clock and the vehicles run in their own process (``plc-runtime vehicles``), on a bus
both processes reach (SocketCAN ``vcan0``, or UDP multicast in a private network
namespace); their conflict monitor reports back through a file when they stop.

A live dashboard (rich) shows cycle statistics and every vehicle; at the end the summary
is printed (``--json``: one JSON object) and written with the CSV of recipes and the PNG
of the routes into the output folder.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rich.console import Console, Group
from rich.table import Table

from plc_runtime.cli import drive, task_table
from plc_runtime.clock import VirtualClock, WallClock
from plc_runtime.errors import ConfigError

from ..config import DEFAULT_CONFIG, load_config
from ..program import FleetProgram
from ..report import summary, write_all

VEHICLES_READY_TIMEOUT = 20.0


class FleetRunError(ConfigError):
    """The fleet run could not be set up (bus, vehicle process)."""


def run(args: argparse.Namespace, modbus: Any) -> int:
    cfg = load_config(args.config)
    if args.cycle_time is not None:
        cfg.cycle_time = args.cycle_time
    if args.watchdog is not None:
        cfg.watchdog = args.watchdog / 1e3
    bus = _parse_bus(args.bus) if args.bus else (cfg.bus_interface, cfg.bus_channel)
    if args.realtime and bus[0] == "virtual":
        raise FleetRunError(
            "--realtime runs the vehicles in their own process, which the in-process virtual "
            "bus cannot reach: give a shared bus, e.g. --bus socketcan:vcan0 or "
            "--bus udp_multicast:239.74.163.2 (docs/fleet-config.md)"
        )
    clock = WallClock(spin=args.spin / 1e3, rt=args.rt) if args.realtime else VirtualClock()
    program = FleetProgram(cfg, clock=clock, cosimulate=not args.realtime, bus=bus)
    if args.modbus:
        program.rt.add_driver(modbus(args.modbus))
    total = (
        args.cycles
        if args.cycles is not None
        else round((args.duration or cfg.duration_s) / cfg.cycle_time)
    )
    vehicles_proc, monitor_file = None, None
    if args.realtime:
        monitor_file = Path(tempfile.mkstemp(prefix="plc-fleet-monitor-", suffix=".json")[1])
        vehicles_proc = _start_vehicles(args.config, bus, monitor_file)
    live = sys.stdout.isatty() and not args.json
    interrupted = False
    previous = signal.signal(signal.SIGINT, lambda *_: program.rt.request_stop())
    wall_start = time.monotonic()
    try:
        program.rt.start()
        drive(program.rt, total, live, None, render=lambda: _dashboard(program, total))
    except KeyboardInterrupt:
        interrupted = True
    finally:
        signal.signal(signal.SIGINT, previous)
        wall = time.monotonic() - wall_start
        state = program.rt.state
        program.close()
        monitor = _stop_vehicles(vehicles_proc, monitor_file)
    result = summary(program, wall, state)
    if monitor is not None:
        result["head_on_conflicts"] = monitor.get("head_on_conflicts")
        result["node_conflicts"] = monitor.get("node_conflicts")
        result["conflict_monitor"] = "simulated positions, in the vehicles' process"
    write_all(program, Path(args.out), result)
    if args.json:
        print(json.dumps(result))
    else:
        Console().print(_final_tables(result))
    if interrupted:
        return 130
    return 1 if state == "FAULT" else 0


def _parse_bus(spec: str) -> tuple[str, str]:
    interface, sep, channel = spec.partition(":")
    if not sep or not interface or not channel:
        raise FleetRunError(f"--bus {spec!r}: expected INTERFACE:CHANNEL, e.g. socketcan:vcan0")
    return interface, channel


def _start_vehicles(
    config: str | None, bus: tuple[str, str], monitor_file: Path
) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-m",
        "fleet",
        "vehicles",
        "--config",
        str(config or DEFAULT_CONFIG),
        "--bus",
        f"{bus[0]}:{bus[1]}",
        "--monitor-out",
        str(monitor_file),
    ]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    deadline = time.monotonic() + VEHICLES_READY_TIMEOUT
    line = ""
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if "ready" in line or not line:
            break
    if "ready" not in line:
        proc.kill()
        proc.wait()
        raise FleetRunError(f"the vehicle process did not start: {line.strip() or 'no output'}")
    return proc


def _stop_vehicles(proc: subprocess.Popen | None, monitor_file: Path | None) -> dict | None:
    if proc is None:
        return None
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    try:
        return json.loads(monitor_file.read_text()) if monitor_file else None
    except (OSError, ValueError):
        return None
    finally:
        if monitor_file:
            monitor_file.unlink(missing_ok=True)


# ----- the dashboard -------------------------------------------------------------------------
VEHICLE_COLUMNS = (
    "vehicle",
    "state",
    "reported",
    "node",
    "target",
    "recipe",
    "step",
    "phase",
    "battery",
    "rounds",
    "waits",
    "replans",
)


def _vehicle_table(program: FleetProgram, limit: int = 30) -> Table:
    table = Table(title="vehicles")
    for col in VEHICLE_COLUMNS:
        table.add_column(
            col, justify="right" if col not in ("state", "reported", "recipe", "phase") else "left"
        )
    rows = program.vehicle_rows()
    for row in rows[:limit]:
        table.add_row(*("-" if row[c] is None else str(row[c]) for c in VEHICLE_COLUMNS))
    if len(rows) > limit:
        table.caption = f"... and {len(rows) - limit} more"
    return table


def _dashboard(program: FleetProgram, total: int | None) -> Group:
    rt = program.rt
    title = (
        f"fleet ({program.cfg.source})  state {rt.state}  cycle {rt.ticks}/{total}  "
        f"clock {rt.clock_time:.1f} s  recipes completed {len(program.completed)}  "
        f"deadlocks resolved {program.resolver.resolved}"
    )
    rows = {name: s.to_dict() for name, s in rt.stats.tasks.items()}
    return Group(task_table(title, rows, live=True), _vehicle_table(program))


def _final_tables(result: dict[str, Any]) -> Group:
    title = (
        f"fleet: {result['state']} after {result['cycles']} cycles, {result['sim_time_s']:.1f} s "
        f"on the {result['clock']} clock, {result['wall_time_s']:.2f} s of wall time"
    )
    tasks = task_table(title, {**result["tasks"], "(scan)": result["scan"]}, live=False)
    fleet = Table(title="fleet")
    fleet.add_column("measure")
    fleet.add_column("value", justify="right")
    for key in (
        "level",
        "recipes_completed",
        "stations_visited",
        "replans",
        "waits",
        "deadlocks_detected",
        "deadlocks_resolved",
        "deadlocks_unresolved",
        "head_on_conflicts",
        "node_conflicts",
    ):
        fleet.add_row(key, str(result[key]))
    util = Table(title="station utilisation")
    for col in ("station", "assigned", "visits", "busy s", "utilisation"):
        util.add_column(col, justify="right")
    for station, u in result["station_utilisation"].items():
        util.add_row(
            station,
            str(u["assigned"]),
            str(u["visits"]),
            f"{u['busy_s']:.0f}",
            f"{u['utilisation']:.1%}",
        )
    files = "  ".join(f"{k}: {v}" for k, v in result.get("files", {}).items())
    if result["fault_reason"]:
        fleet.caption = f"FAULT: {result['fault_reason']}"
    return Group(tasks, fleet, util, f"written: {files}")
