"""The fleet's live dashboard and final tables (rich), fitted to the terminal's width.

At 80 columns everything must still be readable: columns are taken in order of what an
operator needs first (vehicle, state, node, target, ...) while they fit, headers are
short, and long texts (event lines, captions) are cut rather than wrapped. Every text is
a rich ``Text``, never a markup string: order ids, station names, reasons and file names
come from users, and ``[/oops]`` would stop the run with a MarkupError.
"""

from __future__ import annotations

from typing import Any

from rich.console import Console, Group
from rich.table import Table
from rich.text import Text

from plc_runtime.cli import StatsTables, task_table

from .program import FleetProgram

MAX_VEHICLE_ROWS = 30
EVENT_LINES = 8

# (key in FleetProgram.vehicle_rows(), short header, left-aligned), most needed first
VEHICLE_COLUMNS = (
    ("vehicle", "agv", False),
    ("state", "state", True),
    ("node", "node", False),
    ("target", "tgt", False),
    ("order", "order/next", True),
    ("step", "step", False),
    ("battery", "bat%", False),
    ("recipe", "recipe", True),
    ("phase", "phase", True),
    ("waits", "waits", False),
    ("replans", "repl", False),
    ("rounds", "rnds", False),
    ("reported", "reported", True),
)
# statistics columns of plc_runtime.cli.task_table, narrowest first when space is short
NARROW_TASK_COLUMNS = ("cycles", "exec p99 us", "exec max us", "late p99 us", "overruns")


def _cell(value: object) -> str:
    return "-" if value is None else str(value)


def chargers_text(charging: dict) -> str:
    """The plant's chargers against what the run's work needs sustained: a run of an hour
    or two, batteries started charged, shows no shortage yet, so the table says it."""
    needed, have = charging.get("chargers_needed"), charging.get("chargers")
    if needed is None:
        return f"{have} in the plant; needed: unknown until a vehicle has charged"
    text = f"{have} in the plant, {needed:g} needed sustained"
    if needed > have:
        text += ": too few, the fleet falls behind once the batteries have run down"
    return text


def _row(table: Table, *cells: object) -> None:
    """A row shown literally (see the module's docstring)."""
    table.add_row(*(Text(_cell(c)) for c in cells))


def vehicle_table(rows: list[dict[str, Any]], width: int) -> Table:
    """The vehicles, with as many columns as fit in ``width`` characters."""
    shown = rows[:MAX_VEHICLE_ROWS]
    chosen, used = [], 1  # the table's left border
    for key, header, left in VEHICLE_COLUMNS:
        need = max([len(header), *(len(_cell(r[key])) for r in shown)]) + 3  # padding + border
        if used + need > width:
            continue  # a narrower column further down may still fit
        chosen.append((key, header, left))
        used += need
    table = Table(title="vehicles", pad_edge=True)
    for _key, header, left in chosen:
        table.add_column(header, justify="left" if left else "right", no_wrap=True)
    for row in shown:
        _row(table, *(row[key] for key, _h, _l in chosen))
    if len(rows) > len(shown):
        table.caption = f"... and {len(rows) - len(shown)} more"
    return table


def event_lines(program: FleetProgram, width: int, n: int = EVENT_LINES) -> Text:
    events = program.events.recent(n)
    if not events:
        return Text("events: none yet", no_wrap=True, overflow="ellipsis")
    text = Text(no_wrap=True, overflow="ellipsis")
    text.append("events (newest last)\n", style="bold")
    for e in events:
        line = e.line()
        text.append((line if len(line) <= width else line[: width - 1] + "…") + "\n")
    return text


def dashboard(program: FleetProgram, total: int | None, width: int | None = None) -> Group:
    """What the live screen shows: a status line, the scan statistics, vehicles, events."""
    width = width or Console().width
    rt = program.rt
    speed = getattr(rt.clock, "speed", None)
    pace = f" x{speed:g}" if speed else ""
    of_total = f"/{total}" if total else ""
    status = (
        f"fleet {program.cfg.source} | {rt.state} | cycle {rt.ticks}{of_total} | "
        f"{rt.clock_time:.1f} s{pace}\nrecipes {program.completed.total} | "
        f"deadlocks resolved {program.resolver.resolved} of {program.resolver.detected}"
    )
    if program.orders is not None:
        counts = program.orders.book.counts()
        status += (
            f" | orders done {counts['FINISHED']}, open "
            f"{counts['DISPATCHABLE'] + counts['BEING_PROCESSED']}"
        )
    if program.monitor is not None:
        m = program.monitor
        status += f" | conflicts {m.head_on + m.node + m.area}"
    rows = {name: s.to_dict() for name, s in rt.stats.tasks.items()}
    return Group(
        Text(status, no_wrap=True, overflow="ellipsis"),
        _tasks(rows, width),
        vehicle_table(program.vehicle_rows(), width),
        event_lines(program, width),
    )


def _tasks(rows: dict[str, dict[str, Any]], width: int) -> Table | StatsTables:
    if width >= 100:
        return task_table("scan statistics", rows, live=True)
    table = Table(title="scan statistics")
    table.add_column("task", no_wrap=True)
    short = {"cycles": "cycles", "exec p99 us": "p99 us", "exec max us": "max us"}
    short |= {"late p99 us": "late us", "overruns": "overrun"}
    for col in NARROW_TASK_COLUMNS:
        table.add_column(short[col], justify="right", no_wrap=True)
    for name, d in rows.items():
        _row(
            table,
            name,
            str(d["cycles"]),
            f"{d['exec_us']['p99']:.0f}",
            f"{d['exec_us']['max']:.0f}",
            f"{d['lateness_us']['p99']:.0f}",
            str(d["overruns"]),
        )
    return table


def final_tables(result: dict[str, Any]) -> Group:
    """The summary printed at the end of a run (without ``--json``)."""
    pace = f" x{result['speed']:g}" if result.get("speed") else ""
    ended = "INTERRUPTED" if result.get("interrupted") else result["state"]
    title = (
        f"fleet: {ended} after {result['cycles']} cycles, {result['sim_time_s']:.2f} s "
        f"on the {result['clock']} clock{pace}, {result['wall_time_s']:.2f} s of wall time"
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
        "area_conflicts",
    ):
        _row(fleet, key, str(result.get(key)))
    util = Table(title="station utilisation")
    for col in ("station", "assigned", "visits", "busy s", "utilisation"):
        util.add_column(col, justify="right")
    for station, u in result["station_utilisation"].items():
        _row(
            util,
            station,
            str(u["assigned"]),
            str(u["visits"]),
            f"{u['busy_s']:.0f}",
            f"{u['utilisation']:.1%}",
        )
    if "orders" in result:
        for key in ("mean_order_time_s", "station_wait_s", "makespan_s"):
            _row(fleet, key, str(result[key]))
        _row(fleet, "orders", ", ".join(f"{k} {n}" for k, n in result["orders"].items() if n))
        c = result["charging"]
        _row(
            fleet,
            "charging",
            f"{c['visits']} visits ({c['top_ups']} topping up, {c['given_up']} given up), "
            f"{c['time_s']:.0f} s, min {c['min_battery']}%",
        )
        _row(fleet, "chargers", chargers_text(c))
    files = "  ".join(f"{k}: {v}" for k, v in result.get("files", {}).items())
    if result["fault_reason"]:
        fleet.caption = Text(f"FAULT: {result['fault_reason']}")
    counts = ", ".join(f"{k} {n}" for k, n in result.get("event_counts", {}).items()) or "none"
    used = any(u["assigned"] or u["visits"] for u in result["station_utilisation"].values())
    parts = (tasks, fleet, util) if used else (tasks, fleet)  # recipes' stations only
    return Group(*parts, Text(f"events: {counts}"), Text(f"written: {files}"))
