"""``plc-runtime tags [CONFIG] [--json]``: the fleet program's tag table, for HMI builders.

Every tag with its address, data type, access (``rw``: a client may write it), whether it
is retained, where the Modbus server (``run --modbus``) serves it, and what it means. The
table depends only on the configuration's vehicle ids (docs/hmi-map.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from rich.console import Console
from rich.table import Table

from io_drivers.modbus_server import map_entry
from plc_runtime import Tag

from ..config import load_config
from ..tags import fleet_tags


def add_parsers(sub: argparse._SubParsersAction) -> None:
    tags = sub.add_parser(
        "tags", help="list the fleet program's tags: address, type, access, Modbus register"
    )
    tags.add_argument(
        "config",
        nargs="?",
        help="fleet configuration (TOML); default: the embedded model-plant fleet",
    )
    tags.add_argument("--json", action="store_true", help="print the table as one JSON array")


def entry(tag: Tag) -> dict[str, Any]:
    """One tag as the JSON output lists it."""
    served = map_entry(tag.address)
    return {
        "name": tag.name,
        "address": tag.address.text,
        "type": tag.type.name,
        "writable": tag.writable,
        "retain": tag.retain,
        "modbus": None
        if served is None
        else {
            "table": served.table,
            "first": served.first,
            "count": served.count,
            "bits": list(served.bits) if served.bits else None,
        },
        "comment": tag.comment,
    }


def tags_command(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    table = fleet_tags(cfg.starts)
    if args.json:
        print(json.dumps([entry(t) for t in table]))
        return 0
    out = Table(title=f"tags of the fleet program ({cfg.source}, {len(table)} tags)")
    for column in ("name", "address", "type", "access", "retain", "Modbus"):
        out.add_column(column, no_wrap=True)
    out.add_column("comment")
    for tag in table:
        served = map_entry(tag.address)
        out.add_row(
            tag.name,
            tag.address.text,
            tag.type.name,
            "rw" if tag.writable else "r",
            "yes" if tag.retain else "",
            "-" if served is None else str(served),
            tag.comment,
        )
    # into a file or a pipe: lines as long as they need, not the 80 columns of no terminal
    Console(width=None if sys.stdout.isatty() else 200, markup=False).print(out)
    return 0
