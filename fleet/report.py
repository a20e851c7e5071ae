"""What a fleet run leaves behind: the JSON summary, the CSV of completed recipes with a
timestamp per section, and the drawing of every vehicle's planned and driven routes.

The summary keys ``cycles``, ``overruns``, ``state``, ``sim_time_s``, ``vehicles``,
``recipes_completed``, ``stations_visited``, ``replans``, ``waits``, ``deadlocks_resolved``,
``head_on_conflicts``, ``node_conflicts``, ``station_utilisation`` and ``tasks`` are a
contract for scripts (docs/fleet-config.md); more keys may be added, none removed.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from topology.draw import draw

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
    controls, sequencers = program.controls, program.sequencers
    monitor = program.monitor
    resolver = program.resolver
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
        "clock": "virtual" if rt.clock.is_virtual else "wall",
        "sim_time_s": sim,
        "wall_time_s": round(wall_s, 3),
        "real_time_factor": round(sim / wall_s, 2) if wall_s > 0 else None,
        "vehicles": vehicles,
        "recipes_completed": len(program.completed),
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
            for e in resolver.events[:100]
        ],
        "vehicles_pushed": resolver.pushes,
        "head_on_conflicts": monitor.head_on if monitor else None,
        "node_conflicts": monitor.node if monitor else None,
        "conflict_monitor": "simulated positions"
        if monitor
        else "not available (vehicles in another process)",
        "reservation_takeovers": program.reservation.forced_takeovers,
        "blockades": [
            {"time_s": round(t, 3), "event": what, "segment": [a, b]}
            for t, what, a, b in program.schedule.log
        ],
        "station_utilisation": program.chooser.utilisation(sim),
        "heuristic_table": {
            "build_ms": round(program.table.build_time_s * 1e3, 3),
            "bytes": program.table.nbytes,
        },
        "drivers": stats.get("drivers", {}),
        "scan": stats["scan"],
        "tasks": stats["tasks"],
    }


def write_csv(program: FleetProgram, path: Path) -> Path:
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


def write_drawing(program: FleetProgram, path: Path, last_nodes: int = 40) -> Path:
    """The plant with each vehicle's driven route (its last ``last_nodes`` nodes, so laps
    do not paint the whole plant) and the route it still plans, and the blockades in force."""
    vehicles = {}
    for v in program.vehicles:
        driven = program.recorder.driven[v][-last_nodes:]
        control = program.controls[v]
        planned = ([control.current] if control.current is not None else []) + list(control.planned)
        vehicles[f"AGV {v}"] = (driven, planned)
    stats = program.rt.stats.to_dict()
    title = (
        f"{program.cfg.plant.name}: {len(program.vehicles)} AGVs, {len(program.completed)} recipes "
        f"in {stats['clock_time_s']:.0f} s (driven: last {last_nodes} nodes, planned: dashed)"
    )
    return draw(
        program.cfg.plant,
        path,
        title=title,
        blocked=program.blockades.blocked_segments(),
        vehicles=vehicles if len(vehicles) <= 20 else None,
    )


def write_all(program: FleetProgram, out_dir: Path, result: dict[str, Any]) -> dict[str, str]:
    """Write summary.json, recipes.csv and routes.png into ``out_dir`` (created)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {
        "summary": out_dir / "summary.json",
        "recipes": out_dir / "recipes.csv",
        "routes": out_dir / "routes.png",
    }
    write_csv(program, files["recipes"])
    write_drawing(program, files["routes"])
    result["files"] = {k: str(p) for k, p in files.items()}
    files["summary"].write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return result["files"]
