"""``plc-runtime run [CONFIG]`` for the fleet program: the main job.

Where the vehicles are decides the clock:

* simulated in this process (the default, on the in-process virtual bus): the virtual
  clock as fast as possible, ``--speed X`` to watch it at X simulated seconds per wall
  second (the same run, only paced), or ``--realtime`` on the wall clock;
* simulated in their own process (``--realtime`` with a bus another process reaches:
  SocketCAN, UDP multicast, or ``modbus:HOST:BASE_PORT``): the wall clock; their conflict
  monitor reports back through a file when they stop;
* elsewhere (``--vehicles external``: started with ``plc-runtime vehicles`` or real
  AGVs): the wall clock, and nothing is started here.

A combination in which the vehicles could never answer (the virtual clock with vehicles
outside this process) is refused before anything runs, and so is an output folder that
cannot be written. A live dashboard (rich) shows the cycle statistics, every vehicle and
the event log, fitted to the terminal's width; at the end the summary is printed
(``--json``: one JSON object) and written with the CSV of recipes and the PNG of the routes
into the output folder.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console

from blocks.dispatch.strategies import STRATEGIES
from plc_runtime.cli import (
    EXIT_ERROR,
    CliError,
    StopSignal,
    drive,
    duration_cycles,
    path_name,
    signals_noted,
    stop_on_signals,
)
from plc_runtime.clock import PacedClock, VirtualClock, WallClock
from plc_runtime.errors import ConfigError
from plc_runtime.files import release_lock, same_path
from plc_runtime.retain import claim_retain_file

from .. import liveness
from ..config import (
    DEFAULT_CONFIG,
    LOOPBACK,
    MODBUS,
    TRAFFIC_MODES,
    FleetConfig,
    first_vehicles,
    idle_settings,
    link_problem,
    load_config,
    modbus_endpoint,
    parse_bus,
)
from ..dashboard import dashboard, final_tables
from ..program import FleetProgram
from ..report import (
    MONITORED_IN_VEHICLES,
    OUTPUT_FILES,
    ResultsNotWritten,
    claim_out_dir,
    missing_folders,
    remove_empty,
    summary,
    write_all,
)
from ..web import options as web
from .vehicles import READY_LINE

VEHICLES_READY_TIMEOUT = 20.0
DEFAULT_OUT = "out"


class FleetRunError(ConfigError):
    """The fleet run could not be set up (bus, vehicle process)."""


@dataclass(frozen=True)
class Setup:
    """Where the vehicles are and which clock that needs."""

    bus: tuple[str, str]
    clock: VirtualClock | WallClock
    cosimulate: bool  # the vehicles are simulated in this process
    spawn: bool  # the vehicles are simulated in a child process


def add_options(run: argparse.ArgumentParser) -> None:
    """The fleet's own options of ``run``."""
    run.add_argument(
        "--out",
        type=path_name,
        help="fleet: folder for summary.json, recipes.csv, routes.png and orders.csv "
        "(default: out)",
    )
    run.add_argument(
        "--bus",
        metavar="INTERFACE:CHANNEL",
        help="fleet: the vehicle link, overriding the configuration's: virtual:agv (in this "
        "process), socketcan:vcan0, udp_multicast:239.74.163.2, or modbus:HOST:BASE_PORT "
        "(vehicle v serves Modbus TCP on BASE_PORT + v); one CAN channel per 126 vehicles, "
        "comma-separated (socketcan:vcan0,vcan1)",
    )
    run.add_argument(
        "--vehicles",
        choices=("simulated", "external"),
        default="simulated",
        help="fleet: simulated (default: in this process, or in a child process with "
        "--realtime and a shared bus) or external (attach to vehicles started elsewhere; "
        "implies the wall clock)",
    )
    run.add_argument(
        "--traffic",
        choices=TRAFFIC_MODES,
        help="fleet: the traffic mode, overriding [routing] traffic (docs/fleet-config.md)",
    )
    run.add_argument(
        "--dispatch",
        choices=STRATEGIES,
        help="fleet: the order allocation strategy, overriding [dispatch] strategy",
    )
    run.add_argument(
        "--vehicles-count",
        type=int,
        metavar="N",
        help="fleet: run only the first N vehicles of the configuration (by id)",
    )
    web.add_options(run)


def run(args: argparse.Namespace, modbus: Any) -> int:
    cfg = load_config(args.config)
    if args.cycle_time is not None:
        cfg.cycle_time = args.cycle_time
    if args.watchdog is not None:
        cfg.watchdog = args.watchdog / 1e3
    if args.traffic is not None:
        cfg.traffic = args.traffic
    if args.dispatch is not None:
        if not cfg.order_vehicles:
            raise CliError(
                f"--dispatch: {cfg.source} has no vehicles taking transport orders "
                "(docs/fleet-config.md, Transport orders)"
            )
        cfg.dispatch.strategy = args.dispatch
    if args.vehicles_count is not None:
        first_vehicles(cfg, args.vehicles_count)
    for unused in idle_settings(cfg):
        warnings.warn(unused, UserWarning, stacklevel=1)
    total = (
        args.cycles
        if args.cycles is not None
        else duration_cycles(args.duration, cfg.cycle_time)
        if args.duration is not None
        else duration_cycles(cfg.duration_s, cfg.cycle_time, f"{cfg.source}: runtime.duration_s")
    )
    setup = plan(args, cfg)
    web_options = web.web_options(args, cfg)
    if setup.spawn and args.vehicles_count is not None:
        raise ConfigError(
            "--vehicles-count: only with vehicles simulated in this process (the vehicle "
            "process simulates every vehicle of the configuration)"
        )
    out = Path(args.out if args.out is not None else DEFAULT_OUT)
    inputs = cfg.input_files()
    if args.retain is not None:
        # a retain file that holds no retain data is moved aside at start, and the
        # results would write over one of the outputs
        retain = Path(args.retain)
        taken = {**inputs, **{f"the output {out / name}": out / name for name in OUTPUT_FILES}}
        for what, path in taken.items():
            if same_path(retain, path):
                raise CliError(f"--retain {args.retain}: that is {what}; name a file of its own")
        inputs["the retain file"] = retain
    made, out_lock, retain_lock = missing_folders(out), None, None
    try:  # the lock files go however the run ends (a failed start too)
        out_lock = claim_out_dir(out, inputs)
        if args.retain is not None:
            retain_lock = claim_retain_file(args.retain)
        broken = liveness.violations(cfg)
        if broken:
            warnings.warn(
                f"{cfg.source} does not meet the liveness condition (docs/fleet-config.md): "
                f"{'; '.join(broken)}. No conflict can occur, but vehicles may wait without bound.",
                UserWarning,
                stacklevel=1,
            )
        program = FleetProgram(
            cfg,
            clock=setup.clock,
            cosimulate=setup.cosimulate,
            bus=setup.bus,
            retain_file=args.retain,
        )
        try:
            if args.modbus:
                program.rt.add_driver(modbus(args.modbus))
            if web_options is not None:  # stopped with the runtime, like every driver
                program.rt.add_driver(web.web_server(web_options, program))
        except BaseException:
            program.close()  # a bad --modbus address: nothing of the program stays open
            raise
        # from here on Ctrl-C and SIGTERM end the run cleanly, a vehicle process starting
        # or running included, until the results are written
        unwritten = None
        with stop_on_signals(program.rt) as stopped:
            result, state = _run(args, setup, program, total, stopped)
            with signals_noted(stopped):
                try:
                    write_all(program, out, result)
                except ResultsNotWritten as exc:  # the summary still goes to the screen
                    unwritten = exc
                    result.pop("files", None)  # none of them is this run's
    finally:
        if retain_lock is not None:
            release_lock(retain_lock)
        if out_lock is not None:
            release_lock(out_lock)
        remove_empty(made)  # a run refused before it started leaves no folder behind
    if args.json:
        print(json.dumps(result))
    else:
        Console().print(final_tables(result))
    if unwritten is not None:
        print(f"plc-runtime: error: {unwritten}", file=sys.stderr)
        return EXIT_ERROR
    if result["interrupted"]:
        print(
            f"plc-runtime: {stopped.what} at {result['sim_time_s']:.1f} s; results written",
            file=sys.stderr,
        )
        return stopped.exit_code
    if stopped.number is not None:  # only the writing was asked to stop: it finished first
        print(
            f"plc-runtime: {stopped.what} after the run had ended; its results are written whole",
            file=sys.stderr,
        )
    return 1 if state == "FAULT" else 0


def _run(
    args: argparse.Namespace, setup: Setup, program: FleetProgram, total: int, stopped: StopSignal
) -> tuple[dict[str, Any], str]:
    """Start the vehicle process if there is one, run, stop both, and sum up."""
    vehicles_proc, monitor_file = None, None
    if setup.spawn:
        monitor_file = Path(tempfile.mkstemp(prefix="plc-fleet-monitor-", suffix=".json")[1])
        try:
            vehicles_proc = start_vehicles(args.config, setup.bus, monitor_file)
        except BaseException:
            monitor_file.unlink(missing_ok=True)
            program.close()
            raise
    live = sys.stdout.isatty() and not args.json
    wall_start = time.monotonic()
    try:
        program.rt.start()
        if stopped.number is not None:  # asked while the vehicle process was starting
            program.rt.request_stop()
        drive(program.rt, total, live, None, render=lambda: dashboard(program, total))
    except KeyboardInterrupt:  # a second Ctrl-C: the scan aborted, the rest as the first
        stopped.number = signal.SIGINT
    finally:
        # from here on a signal is noted only: the run is over, what is left is summing
        # it up (a third Ctrl-C landed in the summary and nothing was written)
        interrupted = stopped.number is not None
        with signals_noted(stopped):
            wall = time.monotonic() - wall_start
            state = program.rt.state
            try:
                program.close()
            finally:  # the vehicle process goes whatever closing the program raised
                monitor = stop_vehicles(vehicles_proc, monitor_file)
    with signals_noted(stopped):
        return _summed_up(program, wall, state, setup, monitor, interrupted)


def _summed_up(
    program: FleetProgram,
    wall: float,
    state: str,
    setup: Setup,
    monitor: dict[str, Any] | None,
    interrupted: bool,
) -> tuple[dict[str, Any], str]:
    """The run's summary, with the vehicle process's monitor if it had one."""
    result = summary(program, wall, state)
    result["interrupted"] = interrupted
    result["vehicles_mode"] = (
        "in this process" if setup.cosimulate else "child process" if setup.spawn else "external"
    )
    if monitor is not None:
        result["head_on_conflicts"] = monitor.get("head_on_conflicts")
        result["node_conflicts"] = monitor.get("node_conflicts")
        result["area_conflicts"] = monitor.get("area_conflicts")
        result["conflict_monitor"] = MONITORED_IN_VEHICLES
        result["faults"]["injected"] = monitor.get("faults_injected")
    return result, state


def plan(args: argparse.Namespace, cfg: FleetConfig) -> Setup:
    """Decide the bus, the clock and where the vehicles run; refuse what cannot work."""
    if not args.realtime and (args.rt or args.spin):
        raise CliError("--rt and --spin only apply with --realtime")
    bus = parse_bus(args.bus) if args.bus else (cfg.bus_interface, cfg.bus_channel)
    where = "--bus" if args.bus else f"{cfg.source}: bus.interface"
    if args.bus and (problem := link_problem(*bus, max(cfg.starts))) is not None:
        raise ConfigError(f"--bus {args.bus}: {problem}")
    in_process = bus[0] == "virtual"
    if args.vehicles == "external":
        if in_process:
            raise FleetRunError(
                f"--vehicles external: vehicles elsewhere cannot reach the in-process virtual bus "
                f"({where} {bus[0]}:{bus[1]}): give their bus, e.g. --bus socketcan:vcan0 or "
                "--bus modbus:127.0.0.1:5100"
            )
        if args.speed is not None:
            raise FleetRunError(
                "--vehicles external: vehicles elsewhere run in real time, so --speed cannot "
                "apply (the wall clock is used)"
            )
        return Setup(bus, WallClock(spin=args.spin / 1e3, rt=args.rt), False, False)
    if in_process:
        if args.realtime:
            clock: VirtualClock | WallClock = WallClock(spin=args.spin / 1e3, rt=args.rt)
        elif args.speed is not None:
            clock = PacedClock(args.speed)
        else:
            clock = VirtualClock()
        return Setup(bus, clock, True, False)
    if not args.realtime:
        how = f"--speed {args.speed:g}" if args.speed is not None else "the virtual clock"
        raise FleetRunError(
            f"{where} {bus[0]}:{bus[1]} reaches vehicles outside this process, which run in "
            f"real time and could never answer on {how}: add --realtime (simulated vehicles "
            "are then started in their own process), or use --bus virtual:agv to simulate "
            "them here"
        )
    if bus[0] == MODBUS and modbus_endpoint(bus[1])[0] not in LOOPBACK:
        raise FleetRunError(
            f"{where} {bus[0]}:{bus[1]}: simulated vehicles serve Modbus on 127.0.0.1 only; "
            "for vehicles on another host use --vehicles external"
        )
    return Setup(bus, WallClock(spin=args.spin / 1e3, rt=args.rt), False, True)


def start_vehicles(
    config: str | None, bus: tuple[str, str], monitor_file: Path
) -> subprocess.Popen:
    """``plc-runtime vehicles`` in a child process; returns once it says it is ready.

    Its stderr goes to a file (never a pipe nobody drains), so if it fails, its own error
    is shown, not only that it did not start."""
    link = (
        ["--modbus-base-port", str(modbus_endpoint(bus[1])[1])]
        if bus[0] == MODBUS
        else ["--bus", f"{bus[0]}:{bus[1]}"]
    )
    cmd = [
        sys.executable,
        "-m",
        "fleet",
        "vehicles",
        "--config",
        str(config or DEFAULT_CONFIG),
        *link,
        "--monitor-out",
        str(monitor_file),
    ]
    log = tempfile.TemporaryFile(mode="w+", prefix="plc-fleet-vehicles-")
    proc = subprocess.Popen(cmd, stderr=log, stdout=subprocess.DEVNULL, text=True)
    deadline = time.monotonic() + VEHICLES_READY_TIMEOUT
    text = ""
    try:
        while time.monotonic() < deadline:
            log.seek(0)
            text = log.read()
            if READY_LINE.search(text) or proc.poll() is not None:
                break
            time.sleep(0.05)
    except BaseException:  # a second Ctrl-C while it starts: it must not be left running
        proc.kill()
        proc.wait()
        log.close()
        raise
    if READY_LINE.search(text) and proc.poll() is None:
        return proc
    if proc.poll() is None:
        proc.kill()
    code = proc.wait()
    log.seek(0)
    lines = [line.strip() for line in log.read().splitlines() if line.strip()]
    log.close()
    reason = lines[-1] if lines else "no output"
    reason = reason.removeprefix("plc-runtime: error: ")
    status = f"exit code {code}" if code >= 0 else f"killed after {VEHICLES_READY_TIMEOUT:.0f} s"
    raise FleetRunError(f"the vehicle process did not start ({status}): {reason}")


def stop_vehicles(proc: subprocess.Popen | None, monitor_file: Path | None) -> dict | None:
    if proc is None:
        return None
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    except BaseException:  # a second Ctrl-C meanwhile: it goes all the same
        proc.kill()
        proc.wait()
        if monitor_file:
            monitor_file.unlink(missing_ok=True)
        raise
    try:
        return json.loads(monitor_file.read_text()) if monitor_file else None
    except (OSError, ValueError):
        return None
    finally:
        if monitor_file:
            monitor_file.unlink(missing_ok=True)
