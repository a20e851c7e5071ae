"""What a fleet run leaves behind: the JSON summary, the CSV of completed recipes with a
timestamp per section, and the drawing of every vehicle's planned and driven routes.

The summary keys ``cycles``, ``overruns``, ``state``, ``sim_time_s``, ``vehicles``,
``recipes_completed``, ``stations_visited``, ``replans``, ``waits``, ``deadlocks_resolved``,
``head_on_conflicts``, ``node_conflicts``, ``area_conflicts``, ``station_utilisation`` and
``tasks`` are a contract for scripts (docs/fleet-config.md); more keys may be added, none
removed.
"""

from __future__ import annotations

import csv
import json
import os
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

from blocks.dispatch.order_file import HISTORY_COLUMNS, OrderFileError
from plc_runtime.cli import clock_kind, clock_speed
from plc_runtime.errors import ConfigError
from plc_runtime.files import lock_file, release_lock, same_path

from .order_report import OrderTotals, order_summary, run_totals, station_use, write_orders_csv
from .program import FleetProgram

CSV_COLUMNS = (
    "vehicle",
    "recipe",
    "round",
    "recipe_started_s",
    "recipe_finished_s",
    "step",
    "function",
    "station",
    "dispatched_s",
    "arrived_s",
    "done_s",
)


def summary(program: FleetProgram, wall_s: float, state: str | None = None) -> dict[str, Any]:
    rt = program.rt
    stats = rt.stats.to_dict()
    sim = stats["clock_time_s"]
    controls, sequencers = program.controls, program.jobs
    monitor = program.monitor
    resolver = program.resolver
    # every order of the run, swept ones included: one pass over the book for both uses
    totals = run_totals(program.orders) if program.orders else None
    vehicles = {
        str(row["vehicle"]): {
            **{
                k: row[k] for k in ("state", "node", "target", "recipe", "step", "phase", "battery")
            },
            "rounds_completed": row["rounds"],
            "stations_visited": sequencers[row["vehicle"]].stations_visited,
            "waits": row["waits"],
            "replans": row["replans"],
            "plans": controls[row["vehicle"]].plans,
            "no_route": controls[row["vehicle"]].no_routes,
            "suspect_reason": controls[row["vehicle"]].suspect_reason or None,
            # the order whose load is on board (null: none, or a recipe vehicle)
            "load": getattr(sequencers[row["vehicle"]], "load", "") or None,
        }
        for row in program.vehicle_rows()
    }
    return {
        "program": "fleet",
        "config": program.cfg.source,
        "plant": program.cfg.plant.name,
        "level": program.cfg.level,
        "cycles": stats["cycles"],
        "overruns": stats["overruns"],
        "omitted": stats["omitted"],
        "state": state or rt.state,
        "fault_reason": stats["fault_reason"],
        "clock": clock_kind(rt.clock),
        "speed": clock_speed(rt.clock) if clock_kind(rt.clock) == "paced" else None,
        "interrupted": False,
        "sim_time_s": sim,
        "wall_time_s": round(wall_s, 3),
        "real_time_factor": round(sim / wall_s, 2) if wall_s > 0 else None,
        "vehicles": vehicles,
        "recipes_completed": program.completed.total,  # recipes.csv: the newest kept
        "stations_visited": sum(s.stations_visited for s in sequencers.values()),
        "replans": sum(c.replans for c in controls.values()),
        "plans": sum(c.plans for c in controls.values()),
        "waits": sum(c.waits for c in controls.values()),
        "deadlocks_detected": resolver.detected,
        "deadlocks_resolved": resolver.resolved,
        "deadlocks_unresolved": resolver.unresolved,
        "stranded_vehicles": resolver.stranded(),
        "deadlock_events": [
            {
                "time_s": round(e.time_s, 3),
                "vehicles": list(e.vehicles),
                "backed_off": e.backed_off,
                "to_node": e.to_node,
            }
            for e in resolver.events[-DEADLOCK_EVENTS_IN_SUMMARY:]
        ],
        "vehicles_pushed": resolver.pushes,
        "traffic": _traffic(program),
        "head_on_conflicts": monitor.head_on if monitor else None,
        "node_conflicts": monitor.node if monitor else None,
        "area_conflicts": monitor.area if monitor else None,
        "conflict_monitor": MONITORED_HERE if monitor else NOT_MONITORED,
        "refused_reports": program.reservation.refused_reports,
        "suspect_vehicles": {
            str(v): c.suspect_reason for v, c in program.controls.items() if c.suspect
        },
        "suspect_events": sum(c.suspect_events for c in program.controls.values()),
        "blockades": [
            {"time_s": t, "event": what, "segment": [a, b]}
            for t, what, a, b in program.events.segment_changes
        ],
        "faults": faults(program, stats.get("drivers", {})),
        "events": [e.to_dict() for e in program.events.recent(EVENTS_IN_SUMMARY)],
        "event_counts": dict(sorted(program.events.counts.items())),
        "station_utilisation": _utilisation(program, sim, totals),
        "heuristic_table": {
            "build_ms": round(program.table.build_time_s * 1e3, 3),
            "bytes": program.table.nbytes,
        },
        **(order_summary(program.orders, totals) if program.orders else {}),
        **(
            {"goals_reached": sum(g.rounds_done for g in program.goals.values())}
            if program.goals
            else {}
        ),
        "tags": {tag.name: rt.image.read(tag.name) for tag in rt.image.tags},
        "drivers": stats.get("drivers", {}),
        "scan": stats["scan"],
        "tasks": stats["tasks"],
    }


# Where a run's conflict counts come from (the summary's ``conflict_monitor``): scripts
# compare these strings, so docs/fleet-config.md lists them exactly.
MONITORED_HERE = "simulated positions"
MONITORED_IN_VEHICLES = "simulated positions, in the vehicles' process"
NOT_MONITORED = "not available (vehicles in another process)"
CONFLICT_MONITORS = (MONITORED_HERE, MONITORED_IN_VEHICLES, NOT_MONITORED)

# The simulator's counters of injected faults, reported alike whether the vehicles run in
# this process or in their own (the vehicles command's monitor report).
INJECTED = ("dropped", "corrupted", "spoofed", "delays")
DETECTED = ("crc_errors", "malformed", "repeated", "out_of_sequence", "resyncs", "unconfirmed")


def _utilisation(
    program: FleetProgram, sim: float, totals: OrderTotals | None
) -> dict[str, dict[str, float | int]]:
    """Per station: recipe assignments, and the visits and busy time of recipes and
    transport orders together (``totals``: the run's orders', if it has any)."""
    out = program.chooser.utilisation(sim)
    if totals is None:
        return out
    for station, (visits, busy) in station_use(totals).items():
        row = out.setdefault(
            str(station), {"assigned": 0, "visits": 0, "busy_s": 0.0, "utilisation": 0.0}
        )
        row["visits"] += visits
        row["busy_s"] = round(row["busy_s"] + busy, 3)
        row["utilisation"] = round(row["busy_s"] / sim, 4) if sim > 0 else 0.0
    return out


def _traffic(program) -> dict:
    """The traffic mode, and for time windows what its planning rounds did."""
    tw = program.traffic
    if tw is None:
        return {"mode": "reactive"}
    return {
        "mode": "time_windows",
        "rounds": tw.rounds,
        "plans": tw.plans,
        "failed_plans": tw.failed,
        "windows_booked": tw.booked,
        "give_ways": tw.give_ways,
        "cut_short": tw.cut_short,
        "kept_whole": tw.kept_whole,
        "overtakes": tw.overtakes,
        "wait_replans": tw.wait_replans,
        "stranded": sorted(tw.stranded_at),
        "refused_plans": tw.refused,
        "refused_reason": tw.refused_reason,
    }


def faults(program: FleetProgram, drivers: dict[str, Any]) -> dict[str, Any]:
    """Faults injected into the simulated vehicles' frames (``[faults]``; None where the
    vehicles are not simulated here) and what the controller's side detected: frames
    dropped by the CRC, counter and confirmation checks, and reports refused as implausible."""
    injected = None
    if program.fleet is not None:
        injected = {k: sum(f.counters.get(k, 0) for f in program.fleets) for k in INJECTED}
    detected = {k: sum(int(d.get(k, 0)) for d in drivers.values()) for k in DETECTED}
    detected["refused_reports"] = program.reservation.refused_reports
    detected["suspect_events"] = sum(c.suspect_events for c in program.controls.values())
    return {"injected": injected, "detected": detected}


def write_csv(program: FleetProgram, path: Path) -> Path:
    """One row per section of the newest recipe runs the program keeps
    (``blocks.jobs.recipe.RUNS_KEPT``); the summary's ``recipes_completed`` counts all."""
    with path.open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(CSV_COLUMNS)
        for run in program.completed:
            for s in run.sections:
                out.writerow(
                    [
                        run.vehicle,
                        run.recipe,
                        run.round,
                        _t(run.started_s),
                        _t(run.finished_s),
                        s.step,
                        s.function,
                        s.station,
                        _t(s.dispatched_s),
                        _t(s.arrived_s),
                        _t(s.done_s),
                    ]
                )
    return path


def _t(value: float | None) -> str:
    return "" if value is None else f"{value:.3f}"


def write_drawing(program: FleetProgram, path: Path) -> Path:
    """The plant with every vehicle's driven route, the route it still plans and where it
    is now (a heat map of segment usage for a large fleet, see ``topology.draw``), the
    blockades in force and those lifted during the run.

    The driven routes kept are handed over (the newest ``fleet.program.DRIVEN_NODES_KEPT``
    nodes of each vehicle), the drawing emphasising the newest segments itself; the heat
    map draws the recorder's count of every segment driven over the whole run."""
    vehicles = {}
    for v in program.vehicles:
        control = program.controls[v]
        planned = ([control.current] if control.current is not None else []) + list(control.planned)
        vehicles[f"AGV {v}"] = (program.recorder.driven[v], planned)
    lifted = sorted(program.events.lifted)
    stats = program.rt.stats.to_dict()
    done = [f"{program.completed.total} recipes"] if program.sequencers else []
    if program.orders is not None:
        done.append(f"{program.orders.book.counts()['FINISHED']} orders")
    if program.goals:
        done.append(f"{sum(g.rounds_done for g in program.goals.values())} goals")
    title = (
        f"{program.cfg.plant.name}: {len(program.vehicles)} AGVs, "
        f"{' and '.join(done)} in {stats['clock_time_s']:.0f} s"
    )
    # matplotlib costs a second of start-up: only commands that draw pay for it
    from topology.draw import draw

    return draw(
        program.cfg.plant,
        path,
        title=title,
        blocked=program.blockades.blocked_segments(),
        lifted=lifted,
        vehicles=vehicles,
        usage=program.recorder.usage,
    )


EVENTS_IN_SUMMARY = 200  # the newest events; event_counts counts them all
# the newest deadlock records: on a long run the first ones are old news, and the
# deadlocks_* counts count them all
DEADLOCK_EVENTS_IN_SUMMARY = 100
OUTPUT_FILES = ("summary.json", "recipes.csv", "routes.png", "orders.csv")
LOCK_FILE = ".plc-runtime.lock"


def is_order_history(path: Path) -> bool:
    """Does the file begin as the order history a run writes (``orders.csv``)? Another
    file of that name, such as an order file to read, is no run's output to replace."""
    with open(path, encoding="utf-8", errors="replace") as f:
        header = f.readline(4096).strip().split(",")
    return header[: len(HISTORY_START)] == list(HISTORY_START)


HISTORY_START = HISTORY_COLUMNS[:5]  # id, get, put, vehicle, state


def missing_folders(folder: Path) -> list[Path]:
    """``folder`` and those of its parents that do not exist yet, deepest first: what
    claiming it for a run makes, and what a run refused before it wrote anything removes.
    None for a path through ``..``: which folder that names is the file system's to say
    once the folders before it exist, not the path's (``new/../mine`` is ``mine``)."""
    if ".." in folder.parts:
        return []
    missing = []
    for each in (folder, *folder.parents):
        if each.exists() or each.is_symlink():
            break
        missing.append(each)
    return missing


def remove_empty(folders: list[Path]) -> None:
    """Remove ``folders`` (deepest first) while they are empty; what holds a file stays."""
    for each in folders:
        try:
            each.rmdir()
        except OSError:  # not empty (results, or another's files), or gone already
            return


def claim_out_dir(out_dir: Path, inputs: dict[str, Path] | None = None) -> IO[bytes]:
    """Make sure the results can be written before a run starts, not after it finished,
    and that no other run writes its results into the same folder meanwhile (one run's
    summary beside another's drawing would describe neither).

    Creates the folder and takes an exclusive lock on a file in it, ``.plc-runtime.lock``,
    held until :func:`release_lock` (or, however the process ends, until it ends); an
    existing output file that is not a writable file (a folder of that name, no
    permission) is refused too, and so is an output file that is one of the run's
    ``inputs`` (what it is -> path), or an ``orders.csv`` that no run wrote: the results
    replace or remove their files, and a user's own file must never be one of them."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(f"--out {out_dir}: a file, not a folder")
    lock = lock_file(  # held for the whole run
        out_dir / LOCK_FILE,
        f"--out {out_dir}: cannot write results there",
        f"--out {out_dir}: another run is writing its results there; give another folder",
    )
    for name in OUTPUT_FILES:
        path = out_dir / name
        problem = None
        for what, given in (inputs or {}).items():
            if same_path(path, given):
                problem = f"{name} there is {what} of this run ({given}); give another folder"
                break
        else:
            staged = _staged(path)
            if path.exists() and (not path.is_file() or not os.access(path, os.W_OK)):
                problem = f"{name} exists and cannot be overwritten"
            elif staged.exists() and not staged.is_file():
                problem = f"{staged.name}, where {name} is written first, is not a file: move it"
            elif name == "orders.csv" and path.exists() and not is_order_history(path):
                problem = (
                    "orders.csv there is no order history a run wrote (a run replaces or "
                    "removes it): move it, or give another folder"
                )
        if problem is not None:
            release_lock(lock)  # ours: no other run holds it
            raise ConfigError(f"--out {out_dir}: {problem}")
    return lock


class ResultsNotWritten(OSError):
    """The data files of a run could not be written (a full disk, a folder gone): the
    message says which file failed, why, and which files the folder holds now."""


STAGED = ".partial"  # the suffix a data file is written under before it takes its name


def write_all(program: FleetProgram, out_dir: Path, result: dict[str, Any]) -> dict[str, str]:
    """Write summary.json, recipes.csv, routes.png and, with transport orders, orders.csv
    (every order's history) into ``out_dir`` (created).

    The data files are written whole under staged names first and then renamed into place,
    so a write that fails half-way (a full disk) raises :class:`ResultsNotWritten` and
    leaves the folder as it was: an earlier run's files are not cut short. The renames go
    data first, the summary last; one that fails after others did (something took a name
    during the run) says which files are this run's. The data comes first and the drawing last: drawing a plant can fail
    where writing data does not (matplotlib refusing a text, memory), and a run's numbers
    must not be lost with its picture. summary.json is written with the data and again
    after the drawing, then naming routes.png under ``files`` or, if the drawing failed,
    the reason under ``routes_error``; the failure is also a warning (one line, naming
    routes.png and the reason)."""
    files = {"summary": out_dir / "summary.json", "recipes": out_dir / "recipes.csv"}
    if program.orders is not None:
        files["orders"] = out_dir / "orders.csv"
    staged = {key: _staged(path) for key, path in files.items()}
    writing, replaced = files["recipes"], []
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        _discard(staged.values())  # a leftover, or a link: written anew, never through
        write_csv(program, staged["recipes"])
        if program.orders is not None:
            writing = files["orders"]
            write_orders_csv(program.orders, staged["orders"])
        writing = files["summary"]
        _write_summary(result, files, staged["summary"])
        for key in sorted(files, key=lambda k: k == "summary"):  # the summary last
            writing = files[key]
            os.replace(staged[key], writing)
            replaced.append(writing.name)
    except (OSError, OrderFileError) as exc:
        _discard(staged.values())
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        kept = (
            f"only {' and '.join(replaced)} {'is' if len(replaced) == 1 else 'are'} this run's"
            if replaced
            else "the folder keeps the files it held"
        )
        raise ResultsNotWritten(
            f"--out {out_dir}: the results were not written ({writing.name}: "
            f"{why.rsplit(': ', 1)[-1]}); {kept}"
        ) from None
    if program.orders is None:  # an earlier run's orders beside this run's data would seem
        _discard([out_dir / "orders.csv"])  # to be this run's
    routes = out_dir / "routes.png"
    try:
        files["routes"] = write_drawing(program, routes)
    except Exception as exc:  # any failure of the drawing: the data is written already
        result["routes_error"] = _reason(exc)
        try:  # an earlier run's drawing beside this run's data would show the wrong run
            routes.unlink(missing_ok=True)
        except OSError:
            pass  # routes.png is not named under "files", and the warning says why
        warnings.warn(
            f"{routes}: routes drawing not written: {result['routes_error']}",
            RuntimeWarning,
            stacklevel=2,
        )
    staged_summary = staged["summary"]
    try:
        _write_summary(result, files, staged_summary)
        os.replace(staged_summary, files["summary"])
    except OSError as exc:  # the summary written with the data stays
        _discard([staged_summary])
        warnings.warn(
            f"{files['summary']}: not written again after the drawing ({_reason(exc)}): it "
            "names the data files only",
            RuntimeWarning,
            stacklevel=2,
        )
    return result["files"]


def _staged(path: Path) -> Path:
    """Where ``path`` is written before it is renamed into place."""
    return path.with_name(path.name + STAGED)


def _discard(paths: Iterable[Path]) -> None:
    """Remove staged files that are not to be renamed into place, as far as that goes."""
    for path in paths:
        try:
            path.unlink(missing_ok=True)
        except OSError:
            pass  # not a file (something else took the name): left as it is


def _write_summary(result: dict[str, Any], files: dict[str, Path], to: Path) -> None:
    """summary.json's text into ``to``, its ``files`` naming the files written so far."""
    result["files"] = {k: str(p) for k, p in files.items()}
    to.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")


def _reason(exc: Exception) -> str:
    """One short line saying why: the OS's words for a file error, else the exception's
    first line (matplotlib's can run to dozens of lines)."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    lines = str(exc).strip().splitlines()
    text = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."
