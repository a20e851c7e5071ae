"""Copies of the running fleet for the HTTP side: plain JSON-ready dicts and lists.

Every function here runs in the scan thread at the quiet point (through the desk or the
live feed), reads the program's blocks and returns values nobody else holds, so the HTTP
thread never touches a live block. Each costs one pass over the vehicles (or the event
log's tail); nothing here changes the program.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from blocks.dispatch.executor import OrderRunner
from blocks.traffic.records import FAULT, ONLINE, STALE
from topology import Plant

from ..program import FleetProgram
from .desk import OrderView

MAX_EVENTS = 500  # events in one page of the log


def plant(p: Plant, blocked: list[list[int]]) -> dict[str, Any]:
    """The plant model: nodes (position in metres, role), segments, what stands where."""
    nodes = [
        {
            "id": n.id,
            "name": n.name,
            "x": n.x,
            "y": n.y,
            "role": n.role,
            "functions": list(n.functions),
            "queue_for": n.queue_for,
            "area": n.area,
        }
        for n in p.nodes
    ]
    edges = [
        {
            "a": e.source,
            "b": e.target,
            "length": e.length,
            "bidirectional": e.bidirectional,
            "routable": e.routable,
        }
        for e in p.edges
    ]
    return {
        "name": p.name,
        "nodes": nodes,
        "edges": edges,
        "stations": p.with_role("station"),
        "chargers": p.with_role("charger"),
        "parking": p.with_role("parking"),
        "queues": {str(s): list(q) for s, q in p.queues.items()},
        "functions": {str(f): name for f, name in p.functions.items()},
        "blockades": blocked,
    }


def blockades(program: FleetProgram) -> list[list[int]]:
    """The closed segments, each once as [lower id, higher id], sorted."""
    closed = {(min(a, b), max(a, b)) for a, b in program.blockades.blocked_segments()}
    return [list(s) for s in sorted(closed)]


def vehicles(program: FleetProgram, ids: Iterable[int] | None = None) -> list[dict[str, Any]]:
    """Every vehicle (or those of ``ids``) as the controller knows it."""
    bound = program.records.bound
    held = program.commands.held
    out = []
    for v in program.vehicles if ids is None else ids:
        c, job = program.controls[v], program.jobs[v]
        rec = program.records.inputs(v) if bound else None
        flags = int(rec["flags"]) if rec is not None else 0
        known = bool(flags & (ONLINE | STALE))
        active = nxt = None
        if isinstance(job, OrderRunner):
            active = job.active.id if job.active is not None else None
            nxt = job.next.id if job.next is not None else None
        out.append(
            {
                "id": v,
                "state": c.state,
                "node": c.current,
                "next": int(rec["next"]) if known and int(rec["next"]) != 0xFFFF else None,
                "target": job.target,
                "released": list(c.released),
                "planned": list(c.route),
                "battery": program._battery(v) if rec is not None else None,
                "speed_cm_s": int(rec["speed"]) if rec is not None else 0,
                "order": active,
                "next_order": nxt,
                "recipe": job.recipe_name,
                "waiting_for": c.waiting_for,
                "online": bool(flags & ONLINE),
                "stale": bool(flags & STALE),
                "fault": bool(flags & FAULT),
                "suspect": bool(c.suspect),
                "suspect_reason": c.suspect_reason,
                "held": v in held,
                "waits": c.waits,
                "replans": c.replans,
            }
        )
    return out


def stats(program: FleetProgram) -> dict[str, Any]:
    """The runtime's cycle statistics and the fleet's counters."""
    rt = program.rt
    s = rt.stats.to_dict()
    fleet: dict[str, Any] = {
        "vehicles": len(program.vehicles),
        "recipes_completed": len(program.completed),
        "deadlocks_detected": program.resolver.detected,
        "deadlocks_resolved": program.resolver.resolved,
        "blocked_segments": len(blockades(program)),
    }
    if program.monitor is not None:
        m = program.monitor
        fleet |= {"head_on_conflicts": m.head_on, "node_conflicts": m.node, "area_conflicts": m.area}
    if program.orders is not None:
        fleet["orders"] = program.orders.book.counts()
    return {
        "state": s["state"],
        "cycles": s["cycles"],
        "cycle_time_s": s["cycle_time_s"],
        "sim_time_s": s["clock_time_s"],
        "overruns": s["overruns"],
        "fault_reason": s["fault_reason"],
        "watchdog_ms": s["watchdog_ms"],
        "scan": s["scan"],
        "tasks": s["tasks"],
        "drivers": s["drivers"],
        "fleet": fleet,
    }


def events(program: FleetProgram, after: int, limit: int) -> dict[str, Any]:
    """Events numbered ``after + 1`` on (at most ``limit``), oldest first. Numbers count
    every event of the run from 1; the log keeps the newest, so ``first`` says where the
    kept ones begin."""
    log = program.events
    first = log.added - len(log.events) + 1
    start = max(after + 1, first)
    kept = list(log.events)
    chosen = kept[start - first : start - first + limit]
    return {
        "first": first,
        "last": log.added,
        "events": [
            {"seq": start + i, **e.to_dict()} for i, e in enumerate(chosen)
        ],
    }


def order(view: OrderView) -> dict[str, Any]:
    """An order as the stream sends it (the API's OrderOut, without pydantic's cost)."""
    return {
        "id": view.id,
        "get": view.get,
        "put": view.put,
        "start_s": view.start_s,
        "end_s": view.end_s,
        "priority": view.priority,
        "vehicle": view.vehicle,
        "state": view.state.value,
        "assigned": view.assigned,
        "reason": view.reason,
    }
