"""The topology commands of ``plc-runtime``: ``plant validate``, ``plant show`` and ``route``."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from plc_runtime.cli import CliError
from topology import SAMPLES, Plant, load
from topology.formats.movingai import MAX_CELL_SIZE_M

from ..config import HIGHWAY_FACTOR
from ..route import find_route, load_plant, parse_segment

EXIT_NO_ROUTE = 1
FILE_HELP = f"plant file or sample name ({', '.join(SAMPLES)})"


def add_parsers(sub: argparse._SubParsersAction, positive: Callable[[type], Any]) -> None:
    plant = sub.add_parser(
        "plant", help="check or show a plant (.toml, .json, .map, .nodes file or a sample name)"
    )
    plant_sub = plant.add_subparsers(dest="plant_command", required=True)
    validate = plant_sub.add_parser(
        "validate", help="validate a plant; errors exit 2, warnings are listed"
    )
    show = plant_sub.add_parser("show", help="summarise a plant, optionally draw it")
    for parser in (validate, show):
        parser.add_argument("file", help=FILE_HELP)
        parser.add_argument(
            "--cell-size",
            type=positive(float, most=MAX_CELL_SIZE_M),
            help="MovingAI maps: metres per cell (default 1)",
        )
    show.add_argument(
        "--png",
        metavar="OUT",
        type=png_file,
        help="draw the plant (ids, roles, edge directions) into a PNG",
    )
    show.add_argument("--json", action="store_true", help="print the summary as JSON")

    route = sub.add_parser(
        "route", help="find a route with the heuristic-table and A* blocks inside a runtime"
    )
    route.add_argument("file", help=FILE_HELP)
    route.add_argument("--from", dest="start", type=int, required=True, help="start node id")
    route.add_argument("--to", dest="goal", type=int, required=True, help="goal node id")
    route.add_argument(
        "--budget", type=positive(int), default=1, help="node expansions per cycle (default 1)"
    )
    route.add_argument(
        "--block", action="append", default=[], metavar="A-B", help="close segment A-B (repeatable)"
    )
    route.add_argument(
        "--heuristic",
        choices=["table", "euclidean", "manhattan", "zero"],
        default="table",
        help="A* heuristic: the exact distance table (default), straight-line or grid "
        "distance, or none (Dijkstra)",
    )
    route.add_argument(
        "--cell-size",
        type=positive(float, most=MAX_CELL_SIZE_M),
        help="MovingAI maps: metres per cell (default 1)",
    )
    route.add_argument(
        "--highway-factor",
        type=positive(float, least=1.0),
        default=HIGHWAY_FACTOR,
        help=f"cost factor against a highway lane, as the fleet's [routing] highway_factor "
        f"(default {HIGHWAY_FACTOR:g}; 1 ignores highways)",
    )
    route.add_argument(
        "--png", metavar="OUT", type=png_file, help="draw the plant with the route into a PNG"
    )
    route.add_argument("--json", action="store_true", help="print the result as one JSON object")


def png_file(text: str) -> Path:
    """An argparse type: the name of the PNG file to draw into."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty file name")
    if Path(text).suffix.lower() != ".png":
        raise argparse.ArgumentTypeError(
            f"the drawing is a PNG: give a name ending in .png, got {text!r}"
        )
    return Path(text)


def _load(args: argparse.Namespace) -> Plant:
    if Path(args.file).suffix.lower() == ".map" and Path(args.file).exists():
        return load(args.file, cell_size=args.cell_size or 1.0)
    if args.cell_size is not None:
        raise CliError(
            f"--cell-size: only for MovingAI .map plants, and {args.file} is not one (its "
            "positions are in metres already)"
        )
    return load_plant(args.file)


def _draw(plant: Plant, out: Path, **kwargs: Any) -> Path:
    """Draw into ``out``; a folder that is missing or not writable is the option's error."""
    from topology.draw import draw  # matplotlib only when a drawing is asked for

    try:
        return draw(plant, out, **kwargs)
    except OSError as exc:
        why = exc.strerror or str(exc)
        raise CliError(f"--png {out}: cannot write the drawing there: {why}") from None


def plant_command(args: argparse.Namespace) -> int:
    plant = _load(args)
    if args.plant_command == "validate":
        print(
            f"{args.file}: valid plant {plant.name!r}: {plant.n} nodes, {len(plant.edges)} edges, "
            f"{len(plant.targets)} targets, fingerprint {plant.fingerprint}"
        )
        for warning in plant.warnings:
            print(f"{args.file}: warning: {warning}")
        return 0
    summary = plant.summary()
    if args.png is not None:
        summary["png"] = str(_draw(plant, args.png))
    if args.json:
        print(json.dumps(summary))
        return 0
    table = Table(title=f"{plant.name}  ({args.file})", show_header=False)
    table.add_column("what")
    table.add_column("value")
    table.add_row(
        "nodes", f"{plant.n}  (" + ", ".join(f"{r} {c}" for r, c in summary["roles"].items()) + ")"
    )
    table.add_row("edges", f"{len(plant.edges)}  ({plant.n_arcs} routable arcs)")
    table.add_row("targets", str(len(plant.targets)))
    for function, info in summary["functions"].items():
        table.add_row(f"function {function}", f"{info['name'] or '-'}: stations {info['stations']}")
    table.add_row("fingerprint", plant.fingerprint)
    for warning in plant.warnings:
        table.add_row("warning", warning)
    if args.png is not None:
        table.add_row("drawing", summary["png"])
    Console().print(table)
    return 0


def route_command(args: argparse.Namespace) -> int:
    plant = _load(args)
    blocked = [parse_segment(text) for text in args.block]
    result = find_route(
        plant,
        args.start,
        args.goal,
        budget=args.budget,
        blocked=blocked,
        heuristic=args.heuristic,
        highway_factor=args.highway_factor,
    )
    if args.png is not None:
        routes = [result["route"]] if result["route"] else []
        title = f"{plant.name}: route {args.start} -> {args.goal}"
        _draw(plant, args.png, routes=routes, title=title, blocked=blocked)
    if args.json:
        print(json.dumps(result))
    elif result["no_route"]:
        print(
            f"no route from {args.start} to {args.goal} ({result['expansions']} expansions in {result['cycles']} cycles)"
        )
    else:
        print(" -> ".join(map(str, result["route"])))
        print(
            f"cost {result['cost']:g}, {result['expansions']} expansions in {result['cycles']} cycles "
            f"(budget {args.budget}/cycle)"
        )
    return EXIT_NO_ROUTE if result["no_route"] else 0
