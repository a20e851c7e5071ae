"""The ``plc-runtime`` command line: ``run``, ``plant``, ``route``, ``vehicles``, ``tags`` and
``order``.

``plc-runtime run`` runs the fleet program (or ``--program demo``) headless, with the
generic run machinery of ``plc_runtime.cli``. Errors are one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from functools import partial

from io_drivers.modbus_server import ModbusServer
from plc_runtime.cli import (
    EXIT_ERROR,
    CliError,
    OneLineParser,
    add_run_options,
    one_line_warning,
    positive,
    run_program,
    terminal_text,
)
from plc_runtime.errors import PlcError
from topology import TopologyError

from . import demo_program
from .commands import orders, plant, tags, vehicles
from .commands import run as fleet_run
from .config import host_port

PROGRAMS = {"demo": demo_program.build}
"""Programs other than the fleet that ``run --program`` offers."""


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
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
    add_run_options(run)
    run.add_argument(
        "--modbus",
        metavar="HOST:PORT",
        help="serve the process image over Modbus TCP (e.g. 127.0.0.1:5020)",
    )
    run.add_argument(
        "--modbus-writable",
        metavar="NAMES",
        help="with --modbus: let clients also write these, comma-separated: tag names, "
        "%%M addresses, %%MW ranges (e.g. %%MW450,%%MW900..%%MW909; tag names as "
        "plc-runtime tags lists them); docs/security.md",
    )
    fleet_run.add_options(run)
    plant.add_parsers(sub, positive)
    vehicles.add_parsers(sub, positive)
    tags.add_parsers(sub)
    orders.add_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    show_warning = warnings.showwarning
    warnings.showwarning = one_line_warning
    commands = {
        "run": _run,
        "plant": plant.plant_command,
        "route": plant.route_command,
        "vehicles": vehicles.vehicles_command,
        "tags": tags.tags_command,
        "order": orders.order_command,
    }
    try:
        return commands[args.command](args)
    except BrokenPipeError:  # stdout closed early (e.g. piped into head): nothing left to report
        return EXIT_ERROR
    except (PlcError, CliError, TopologyError, OSError) as exc:
        print(f"plc-runtime: error: {terminal_text(str(exc))}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        warnings.showwarning = show_warning


def _run(args: argparse.Namespace) -> int:
    if args.modbus_writable is not None and not args.modbus:
        raise CliError("--modbus-writable opens writes of the server --modbus HOST:PORT starts")
    if args.program == "fleet":
        return fleet_run.run(args, partial(modbus_server, writable=args.modbus_writable))
    if args.config:
        raise CliError(f"a configuration file is for the fleet program, not {args.program!r}")
    if args.bus or args.vehicles != "simulated":
        raise CliError(f"--bus and --vehicles are for the fleet program, not {args.program!r}")
    if args.web or args.web_token:
        raise CliError(f"--web serves the fleet program's API and page, not {args.program!r}")
    given = [
        "--" + name.replace("_", "-")
        for name in ("traffic", "dispatch", "vehicles_count", "out")
        if getattr(args, name) is not None
    ]
    if given:
        raise CliError(f"{', '.join(given)}: for the fleet program, not {args.program!r}")
    drivers = [modbus_server(args.modbus, args.modbus_writable)] if args.modbus else []
    return run_program(args, args.program, PROGRAMS[args.program], drivers)


def modbus_server(spec: str, writable: str | None = None) -> ModbusServer:
    """The Modbus TCP server of ``--modbus HOST:PORT`` (``--modbus-writable NAMES``)."""
    try:
        host, port = host_port(spec, "127.0.0.1:5020")
    except ValueError as exc:
        raise CliError(f"--modbus: {exc}") from None
    extra = [] if writable is None else [name.strip(" ") for name in writable.split(",")]
    return ModbusServer(host=host, port=port, writable_extra=extra)


if __name__ == "__main__":
    sys.exit(main())
