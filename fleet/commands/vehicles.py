"""``plc-runtime vehicles``: simulated AGVs in their own process, on the wall clock, talking to
the runtime over a CAN bus or each through its own Modbus TCP server."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from plc_runtime.cli import MAX_DURATION_S, path_name, whole
from plc_runtime.errors import ConfigError
from plc_runtime.files import is_special, same_path

from ..config import LOOPBACK, MODBUS, link_problem, modbus_endpoint, parse_bus
from ..report import INJECTED
from ..route import load_plant

# A simulation step: below a tenth of a millisecond the loop only spins; above a second a
# vehicle would jump whole segments between its reports, and Ctrl-C waits for the step.
MIN_PERIOD_S, MAX_PERIOD_S = 1e-4, 1.0
# The line a starting ``run --realtime`` waits for on the vehicle process's stderr. Matched
# whole, at a line's start: an error text such as "address already in use" must not pass.
READY_LINE = re.compile(r"^plc-runtime: \d+ vehicles ready, ", re.MULTILINE)
# conflicts in the --monitor-out report: the newest (the monitor keeps only its newest)
MONITOR_EVENTS_REPORTED = 100


def add_parsers(sub: argparse._SubParsersAction, positive: Callable[..., Any]) -> None:
    p = sub.add_parser("vehicles", help="run simulated AGVs in this process, talking over a bus")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--plant", help="plant file or sample name")
    source.add_argument(
        "--config", help="fleet configuration: its plant, vehicles and start nodes, status period"
    )
    p.add_argument(
        "--count",
        type=positive(int),
        help="with --plant: number of vehicles (ids 1..N, default 4)",
    )
    p.add_argument(
        "--monitor-out",
        metavar="FILE",
        type=path_name,
        help="count head-on and node conflicts from the true positions; write them here (JSON) at exit",
    )
    link = p.add_mutually_exclusive_group()
    link.add_argument(
        "--bus",
        help="INTERFACE:CHANNEL the controller listens on, e.g. socketcan:vcan0 or "
        "udp_multicast:239.74.163.2; one channel per 126 vehicles, comma-separated "
        "(socketcan:vcan0,vcan1) (default with --config: its [bus])",
    )
    link.add_argument(
        "--modbus-base-port",
        type=positive(int),
        metavar="PORT",
        help="instead of a bus: vehicle v serves Modbus TCP on 127.0.0.1:PORT+v",
    )
    p.add_argument(
        "--period",
        type=positive(float, least=MIN_PERIOD_S, most=MAX_PERIOD_S),
        default=0.01,
        help=f"simulation step in seconds, {MIN_PERIOD_S:g}..{MAX_PERIOD_S:g} (default 0.01)",
    )
    p.add_argument(
        "--duration",
        type=positive(float, most=MAX_DURATION_S),
        help="wall-clock seconds to run (default: until Ctrl-C)",
    )
    p.add_argument(
        "--seed", type=whole, default=0, help="seed of the injected faults and delays (default 0)"
    )
    p.add_argument(
        "--json", action="store_true", help="print the final state of every vehicle as JSON"
    )


def check_writable(name: str, inputs: dict[str, Path]) -> None:
    """ConfigError unless a file can be written at ``name``: the monitor's report is written
    at exit, and a run of hours must not find out only then that its folder is missing.
    A device or a pipe (which could block the exit for ever) is refused, and so is one of
    the command's ``inputs`` (what it is -> path), which the report would replace."""
    path = Path(name)
    folder = path.parent
    if path.is_dir():
        raise ConfigError(f"--monitor-out {name}: a folder, not a file")
    if (what := is_special(path)) is not None:
        raise ConfigError(f"--monitor-out {name}: {what}, not a file")
    for what, given in inputs.items():
        if same_path(path, given):
            raise ConfigError(f"--monitor-out {name}: that is {what}; name a file of its own")
    if not folder.is_dir():
        raise ConfigError(f"--monitor-out {name}: no folder {str(folder)!r}")
    if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ConfigError(f"--monitor-out {name}: not writable")


def shared_link(
    bus: tuple[str, str] | None, modbus_base_port: int | None, where: str
) -> tuple[str | None, str | None, int | None]:
    """(interface, channel, Modbus base port) of a link a controller in another process can
    reach: the in-process virtual bus is refused (nobody could ever talk to the vehicles),
    and ``modbus:HOST:PORT``, as ``run --bus`` takes it, means a Modbus server per vehicle."""
    if modbus_base_port is not None:
        return None, None, modbus_base_port
    if bus is None:
        raise ConfigError(
            "no link: give the bus the controller uses (--bus socketcan:vcan0, --bus "
            "udp_multicast:239.74.163.2) or --modbus-base-port PORT"
        )
    interface, channel = bus
    if interface == "virtual":
        raise ConfigError(
            f"{where} {interface}:{channel}: the virtual bus exists inside one process, so no "
            "controller could reach these vehicles; give a shared bus (--bus socketcan:vcan0, "
            "--bus udp_multicast:239.74.163.2) or --modbus-base-port PORT"
        )
    if interface == MODBUS:
        host, port = modbus_endpoint(channel)
        if host not in LOOPBACK:
            raise ConfigError(
                f"{where} {interface}:{channel}: simulated vehicles serve Modbus on 127.0.0.1 only"
            )
        return None, None, port
    return interface, channel, None


def vehicles_command(args: argparse.Namespace) -> int:
    from vehicles.monitor import ConflictMonitor
    from vehicles.runner import default_starts, run_fleet

    if args.config and args.count is not None:
        raise ConfigError("--count applies with --plant: a configuration names its vehicles")
    status_period, faults, params, charges = 0.1, None, None, None
    bus = parse_bus(args.bus) if args.bus else None
    where = "--bus"
    if args.config:
        from ..config import load_config

        cfg = load_config(args.config)
        inputs = cfg.input_files()
        plant, starts, status_period = cfg.plant, cfg.starts, cfg.status_period_s
        faults = cfg.faults or None  # the configuration's [faults]: a commissioning test
        params, charges = cfg.agv, cfg.battery.start  # [simulation] and start charges
        if bus is None and args.modbus_base_port is None:
            bus, where = (cfg.bus_interface, cfg.bus_channel), f"{cfg.source}: bus"
    else:
        from ..config import link_node_problem

        plant = load_plant(args.plant)
        inputs = {"the plant file": Path(args.plant)}  # (a sample's name matches no file)
        problem = link_node_problem(plant)
        if problem is not None:
            raise ConfigError(f"{args.plant}: {problem}")
        try:
            starts = default_starts(plant, 4 if args.count is None else args.count)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    if args.monitor_out:
        check_writable(args.monitor_out, inputs)
    interface, channel, modbus_base_port = shared_link(bus, args.modbus_base_port, where)
    link = (MODBUS, f"127.0.0.1:{modbus_base_port}") if modbus_base_port else (interface, channel)
    if (problem := link_problem(*link, max(starts))) is not None:
        if args.modbus_base_port is not None:
            where = f"--modbus-base-port {args.modbus_base_port}"
        elif bus is not None:
            where = f"{where} {bus[0]}:{bus[1]}"
        raise ConfigError(f"{where}: {problem}")
    monitors: list[ConflictMonitor] = []

    def watch(fleets: list[tuple[int, Any]]) -> None:
        if not monitors:
            offsets, each = zip(*fleets, strict=True)
            monitors.append(ConflictMonitor(list(each), list(offsets)))
        monitors[0].check()

    def ready(link: str) -> None:
        print(
            f"plc-runtime: {len(starts)} vehicles ready, {link}, starts {starts}",
            file=sys.stderr,
            flush=True,
        )

    try:
        fleets = run_fleet(
            plant,
            starts,
            interface,
            channel,
            args.period,
            args.duration,
            args.seed,
            modbus_base_port=modbus_base_port,
            on_ready=ready,
            on_step=watch if args.monitor_out else None,
            status_period=status_period,
            faults=faults,
            params=params,
            charges=charges,
        )
    except (OSError, ValueError, ImportError, RuntimeError, TimeoutError) as exc:
        raise ConfigError(f"vehicle link: {exc}") from None
    if args.monitor_out and monitors:
        m = monitors[0]
        report = {
            "head_on_conflicts": m.head_on,
            "node_conflicts": m.node,
            "area_conflicts": m.area,
            "faults_injected": {k: sum(f.counters[k] for _, f in fleets) for k in INJECTED},
            "events": [e.__dict__ for e in m.events[-MONITOR_EVENTS_REPORTED:]],
        }
        try:
            with open(args.monitor_out, "w", encoding="utf-8") as f:
                json.dump(report, f)
        except OSError as exc:
            raise ConfigError(
                f"--monitor-out {args.monitor_out}: cannot write: {exc.strerror or exc}"
            ) from None
    final = {
        v + offset: {
            "node": a.node,
            "state": a.state,
            "battery": round(a.battery.percent, 2),
            "driven": a.driven,
            "nodes_reached": a.driven.total,
        }
        for offset, fleet in fleets
        for v, a in fleet.vehicles.items()
    }
    if args.json:
        counters = Counter()
        for _, fleet in fleets:
            counters.update(fleet.counters)
        time_s = round(fleets[0][1].time, 3)
        print(json.dumps({"time_s": time_s, "vehicles": final, "counters": dict(counters)}))
    else:
        for v, info in final.items():
            print(
                f"vehicle {v}: at node {info['node']}, {info['state']}, battery {info['battery']} %, "
                f"drove {info['driven']}"
            )
    return 0
