"""The ``plc-runtime`` command line.

``plc-runtime run`` runs a program headless: on the virtual clock as fast as it can (the
default), or on the wall clock with ``--realtime``. On a terminal it shows a live status
screen; at the end it prints a summary (``--json``: one JSON object on stdout). Errors are
one line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
import warnings
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from topology import TopologyError

from . import cli_topology, cli_vehicles
from .clock import VirtualClock, WallClock
from .errors import PlcError
from .programs import PROGRAMS
from .runtime import Runtime

EXIT_FAULT = 1
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130
REDRAW_INTERVAL = 0.25  # seconds of wall time between two redraws of the live screen


class CliError(Exception):
    """A usage error to report as one line."""


def _positive(kind: type) -> Any:
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a finite number > 0: {text!r}")
        return value

    return parse


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0: {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="plc-runtime", description="A PLC-style scan-cycle runtime for AGV fleets."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a program headless (default: the fleet program)")
    run.add_argument(
        "config",
        nargs="?",
        help="fleet configuration (TOML, docs/fleet-config.md); default: the embedded model-plant fleet",
    )
    run.add_argument(
        "--program",
        default="fleet",
        choices=["fleet", *sorted(PROGRAMS)],
        help="program to run (default: fleet)",
    )
    length = run.add_mutually_exclusive_group()
    length.add_argument("--cycles", type=_positive(int), help="number of base cycles to run")
    length.add_argument(
        "--duration",
        type=_positive(float),
        help="seconds to run (simulated; wall-clock with --realtime)",
    )
    run.add_argument(
        "--realtime", action="store_true", help="run on the wall clock instead of the virtual clock"
    )
    run.add_argument(
        "--cycle-time",
        type=_positive(float),
        help="base cycle time in seconds (default: the fleet configuration's; demo 0.010)",
    )
    run.add_argument(
        "--watchdog",
        type=_positive(float),
        help="maximum cycle time in ms (default: the fleet configuration's; demo 150)",
    )
    run.add_argument(
        "--spin",
        type=_non_negative,
        default=0.0,
        help="realtime: spin the last SPIN ms before each deadline",
    )
    run.add_argument(
        "--rt", action="store_true", help="realtime: SCHED_FIFO, 1 ns timer slack, GC in idle slack"
    )
    run.add_argument("--retain", metavar="FILE", help="retain file (kept across runs)")
    run.add_argument(
        "--json", action="store_true", help="print the summary as one JSON object on stdout"
    )
    run.add_argument(
        "--modbus",
        metavar="HOST:PORT",
        help="serve the process image over Modbus TCP (e.g. 127.0.0.1:5020)",
    )
    run.add_argument(
        "--out", default="out", help="fleet: folder for summary.json, recipes.csv, routes.png"
    )
    run.add_argument(
        "--bus",
        metavar="INTERFACE:CHANNEL",
        help="fleet: the vehicles' CAN bus (e.g. socketcan:vcan0); default: the configuration's",
    )
    cli_topology.add_parsers(sub, _positive)
    cli_vehicles.add_parsers(sub, _positive)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    show_warning = warnings.showwarning
    warnings.showwarning = _one_line_warning
    commands = {
        "run": _run,
        "plant": cli_topology.plant_command,
        "route": cli_topology.route_command,
        "vehicles": cli_vehicles.vehicles_command,
    }
    try:
        return commands[args.command](args)
    except BrokenPipeError:  # stdout closed early (e.g. piped into head): nothing left to report
        return EXIT_ERROR
    except (PlcError, CliError, TopologyError, OSError) as exc:
        print(f"plc-runtime: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        warnings.showwarning = show_warning


def _one_line_warning(message: Warning | str, category: type, *args: Any, **kwargs: Any) -> None:
    print(f"plc-runtime: warning: {message}", file=sys.stderr)


def _run(args: argparse.Namespace) -> int:
    if not args.realtime and (args.rt or args.spin):
        raise CliError("--rt and --spin only apply with --realtime")
    if args.program == "fleet":
        from . import cli_fleet

        return cli_fleet.run(args, _drive, _task_table, _modbus_server)
    if args.config:
        raise CliError(f"a configuration file is for the fleet program, not {args.program!r}")
    if args.cycle_time is None:
        args.cycle_time = 0.010
    if args.watchdog is None:
        args.watchdog = 150.0
    if args.realtime:
        clock: VirtualClock | WallClock = WallClock(spin=args.spin / 1e3, rt=args.rt)
    else:
        clock = VirtualClock()
    rt = PROGRAMS[args.program](
        clock=clock,
        cycle_time=args.cycle_time,
        watchdog=args.watchdog / 1e3,
        retain_file=args.retain,
    )
    if args.modbus:
        rt.add_driver(_modbus_server(args.modbus))
    rt.start()
    total = (
        args.cycles
        if args.cycles is not None
        else (round(args.duration / rt.cycle_time) if args.duration is not None else None)
    )
    live = sys.stdout.isatty() and not args.json
    previous = signal.signal(signal.SIGINT, lambda *_: _interrupt(rt))
    wall_start = time.monotonic()
    try:
        _drive(
            rt,
            total,
            live,
            announce=f"plc-runtime: running {args.program} until Ctrl-C" if total is None else None,
        )
    except KeyboardInterrupt:  # the second Ctrl-C: abort at once, but still stop cleanly
        rt.stop()
        print(f"plc-runtime: interrupted in cycle {rt.ticks}; runtime stopped", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGINT, previous)
    wall = time.monotonic() - wall_start
    final_state = rt.state
    summary = _summary(rt, args.program, final_state, wall)
    rt.stop()
    if args.json:
        print(json.dumps(summary))
    else:
        Console().print(_summary_table(summary))
    return EXIT_FAULT if final_state == "FAULT" else 0


def _modbus_server(spec: str):
    from io_drivers.modbus_server import ModbusServer

    host, sep, port = spec.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise CliError(f"--modbus {spec!r}: expected HOST:PORT, e.g. 127.0.0.1:5020")
    return ModbusServer(host=host, port=int(port))


def _interrupt(rt: Runtime) -> None:
    """First Ctrl-C: finish the current cycle and stop cleanly; a second one aborts."""
    rt.request_stop()
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _drive(
    rt: Runtime,
    total: int | None,
    live: bool,
    announce: str | None,
    render: Any = None,
) -> None:
    """Run in chunks of about a tenth of a second so the screen and Ctrl-C stay responsive.

    ``announce`` goes to stderr once the first chunk has run, so a supervising process
    knows the program is in its cyclic phase."""
    chunk = max(1, round(0.1 / rt.cycle_time)) if not rt.clock.is_virtual else 2000
    done = 0
    # No auto-refresh: rich would redraw from a background thread, and a second Python
    # thread in the scan's process costs milliseconds of lateness (GIL hand-over). The
    # screen is redrawn here, between chunks, in the idle time before the next release.
    render = render or (lambda: _status_table(rt, total))
    display = Live(render(), auto_refresh=False, transient=True) if live else None
    drawn = time.monotonic()
    if display:
        display.start()
    try:
        while rt.state == "RUN" and (total is None or done < total):
            n = chunk if total is None else min(chunk, total - done)
            ran = rt.run(cycles=n)
            done += ran
            if announce:
                print(announce, file=sys.stderr, flush=True)
                announce = None
            if display and time.monotonic() - drawn >= REDRAW_INTERVAL:
                display.update(render(), refresh=True)
                drawn = time.monotonic()
            if ran < n:
                break
    finally:
        if display:
            display.stop()


# Columns of the statistics tables: header -> how to show it from ScanStats.to_dict()
_COLUMNS = {
    "cycles": lambda d: str(d["cycles"]),
    "exec last us": lambda d: f"{d['exec_us']['last']:.1f}",
    "exec mean us": lambda d: f"{d['exec_us']['mean']:.1f}",
    "exec p99 us": lambda d: f"{d['exec_us']['p99']:.1f}",
    "exec max us": lambda d: f"{d['exec_us']['max']:.1f}",
    "late p99 us": lambda d: f"{d['lateness_us']['p99']:.1f}",
    "late max us": lambda d: f"{d['lateness_us']['max']:.1f}",
    "overruns": lambda d: str(d["overruns"]),
    "omitted": lambda d: str(d["omitted"]),
}
_LIVE_COLUMNS = [
    "cycles",
    "exec last us",
    "exec max us",
    "exec p99 us",
    "late p99 us",
    "overruns",
    "omitted",
]
_SUMMARY_COLUMNS = [
    "cycles",
    "exec mean us",
    "exec p99 us",
    "exec max us",
    "late p99 us",
    "late max us",
    "overruns",
    "omitted",
]


def _stats_table(title: str, rows: dict[str, dict[str, Any]], columns: list[str]) -> Table:
    table = Table(title=title)
    table.add_column("task")
    for header in columns:
        table.add_column(header, justify="right")
    for name, d in rows.items():
        table.add_row(name, *(_COLUMNS[header](d) for header in columns))
    return table


def _task_table(title: str, rows: dict[str, dict[str, Any]], live: bool) -> Table:
    return _stats_table(title, rows, _LIVE_COLUMNS if live else _SUMMARY_COLUMNS)


def _status_table(rt: Runtime, total: int | None) -> Table:
    of_total = f"/{total}" if total else ""
    title = (
        f"plc-runtime  state {rt.state}  cycle {rt.ticks}{of_total}  clock {rt.clock_time:.2f} s"
    )
    rows = {name: stats.to_dict() for name, stats in rt.stats.tasks.items()}
    return _stats_table(title, rows, _LIVE_COLUMNS)


def _summary(rt: Runtime, program: str, state: str, wall: float) -> dict[str, Any]:
    stats = rt.stats.to_dict()
    return {
        "program": program,
        "cycles": stats["cycles"],
        "overruns": stats["overruns"],
        "omitted": stats["omitted"],
        "state": state,
        "fault_reason": stats["fault_reason"],
        "clock": "virtual" if rt.clock.is_virtual else "wall",
        "sim_time_s": stats["clock_time_s"],
        "wall_time_s": round(wall, 3),
        "scans_per_s": round(stats["cycles"] / wall, 1) if wall > 0 else None,
        "tags": {tag.name: rt.image.read(tag.name) for tag in rt.image.tags},
        "scan": stats["scan"],
        "tasks": stats["tasks"],
    }


def _summary_table(summary: dict[str, Any]) -> Table:
    title = (
        f"{summary['program']}: {summary['state']} after {summary['cycles']} cycles, "
        f"{summary['sim_time_s']:.2f} s on the {summary['clock']} clock, {summary['wall_time_s']:.2f} s of wall time"
    )
    table = _stats_table(title, {**summary["tasks"], "(scan)": summary["scan"]}, _SUMMARY_COLUMNS)
    if summary["fault_reason"]:
        table.caption = f"FAULT: {summary['fault_reason']}"
    else:
        table.caption = "  ".join(f"{k}={v}" for k, v in summary["tags"].items())
    return table


if __name__ == "__main__":
    sys.exit(main())
