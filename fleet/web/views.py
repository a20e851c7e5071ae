"""Copies of the running fleet for the HTTP side, and their JSON-ready form.

The ``copy_*`` functions (and ``blockades``, ``events``, ``light_stats``) run in the scan
thread between two scans (through the desk or the live feed): they read the program's
blocks and return values that nothing changes afterwards, so the HTTP thread never touches
a live block. They copy as little as they can (the vehicles' words in one numpy copy, the
events by reference, as they are immutable), because whatever they cost, the scan pays.
The one shared thing is the statistics' ring buffers: the runtime overwrites one slot per
scan in place, and the percentiles are read from them as they are when rendered. The
``render_*`` functions turn a copy into the API's JSON in the server's thread, where
building dicts and computing percentiles costs the scan nothing but a share of the
processor. Nothing here changes the program.
"""

from __future__ import annotations

from collections.abc import Iterable
from itertools import islice
from typing import Any, NamedTuple

import numpy as np

from blocks.dispatch.executor import OrderRunner
from blocks.traffic.records import BATTERY_UNKNOWN, NO_NODE
from plc_runtime.stats import ScanStats
from topology import Plant

from ..events import Event
from ..program import FleetProgram
from ..tags import PHASE_NAMES, V
from .desk import OrderView

MAX_EVENTS = 500  # events in one page of the log


def plant(p: Plant, blocked: list[list[int]]) -> dict[str, Any]:
    """The plant model: nodes (position in metres, role), segments, what stands where. The
    plant never changes while the program runs, so this may run in any thread."""
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
            "highway": e.highway,
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


class ClosedSegments:
    """``blockades(program)``, computed again only when a segment was closed or reopened
    (the routing constraints count their changes): most scans change none."""

    def __init__(self, program: FleetProgram) -> None:
        self._program = program
        self._epoch = -1
        self._closed: list[list[int]] = []

    def __call__(self) -> list[list[int]]:
        epoch = self._program.blockades.epoch
        if epoch != self._epoch:
            self._epoch, self._closed = epoch, blockades(self._program)
        return self._closed


class VehicleCopy(NamedTuple):
    """What the scan copies of one vehicle: the blocks' values the words do not hold."""

    id: int
    state: str
    released: tuple[int, ...]
    planned: tuple[int, ...]
    order: str | None
    next_order: str | None
    recipe: str | None
    suspect_reason: str
    load: str | None


class FleetCopy:
    """The vehicles' copy for the HTTP side: ``fleet_copy()`` copies every vehicle once per
    scan, shared by whoever asks in it (the stream's snapshot and the requests answered at
    the same scan's end); ``fleet_copy.of(ids)`` copies some.

    In the scan: the vehicles' rows of words (fleet/tags.py, one numpy copy) and per vehicle
    its routes and job, a few attribute reads each. Which block holds what is looked up
    once, here, so a copy of a hundred vehicles is one list comprehension (about 70 us)."""

    def __init__(self, program: FleetProgram) -> None:
        self._program = program
        self._members = {
            v: (v, program.controls[v], job if isinstance(job, OrderRunner) else None, job)
            for v in program.vehicles
            for job in (program.jobs[v],)  # fixed once the program is built
        }
        self._all = list(self._members.values())
        self._scan = -1
        self._copy: tuple[np.ndarray, list[VehicleCopy]] | None = None

    def __call__(self) -> tuple[np.ndarray, list[VehicleCopy]]:
        scan = self._program.rt.ticks
        if self._copy is None or scan != self._scan:
            self._scan = scan
            self._copy = self._program.status.rows().copy(), self._take(self._all)
        return self._copy

    def of(self, ids: Iterable[int]) -> tuple[np.ndarray, list[VehicleCopy]]:
        members = [self._members[v] for v in ids]
        return self._program.status.rows()[[m[0] - 1 for m in members]], self._take(members)

    @staticmethod
    def _take(members: list[tuple]) -> list[VehicleCopy]:
        make = tuple.__new__  # VehicleCopy without its keyword handling: a third of the cost
        return [
            make(
                VehicleCopy,
                (
                    v,
                    c.state,
                    tuple(c.released),
                    tuple(c.route),
                    None if runner is None or runner.active is None else runner.active.id,
                    None if runner is None or runner.next is None else runner.next.id,
                    job.recipe_name or None,
                    c.suspect_reason,
                    None if runner is None else runner.load or None,
                ),
            )
            for v, c, runner, job in members
        ]


def render_vehicles(copied: tuple[np.ndarray, list[VehicleCopy]]) -> list[dict[str, Any]]:
    """Anywhere: the vehicles as the API sends them."""
    rows, copies = copied
    out = []
    for row, c in zip(rows.tolist(), copies, strict=True):
        out.append(
            {
                "id": c.id,
                "state": c.state,
                "node": _node(row[V["node"]]),
                "next": _node(row[V["next"]]),
                "target": _node(row[V["target"]]),
                "phase": PHASE_NAMES.get(row[V["phase"]], "-"),
                "released": list(c.released),
                "planned": list(c.planned),
                "battery": None if row[V["battery"]] == BATTERY_UNKNOWN else row[V["battery"]],
                "speed_cm_s": row[V["speed"]],
                "order": c.order,
                "next_order": c.next_order,
                "recipe": c.recipe,
                "waiting_for": row[V["waiting_for"]] or None,
                "online": bool(row[V["online"]]),
                "stale": bool(row[V["stale"]]),
                "fault": bool(row[V["fault"]]),
                "suspect": bool(row[V["suspect"]]),
                "suspect_reason": c.suspect_reason,
                "load": c.load,
                "held": bool(row[V["held"]]),
                "waits": row[V["waits"]],
                "replans": row[V["replans"]],
            }
        )
    return out


def _node(word: int) -> int | None:
    return None if word == NO_NODE else word


class StatsCopy(NamedTuple):
    """What the scan copies of the statistics: the counters. The percentiles are computed
    (``render_stats``) outside the scan, from the runtime's ring buffers as they are then
    (``ScanStats.copy(share_window=True)``)."""

    runtime: dict[str, Any]
    scan: ScanStats
    tasks: dict[str, ScanStats]
    drivers: dict[str, Any]
    fleet: dict[str, Any]


def copy_stats(program: FleetProgram) -> StatsCopy:
    rt = program.rt
    runtime = {
        "state": rt.state,
        "cycles": rt.ticks,
        "cycle_time_s": rt.cycle_time,
        "sim_time_s": round(rt.clock_time, 9),
        "overruns": rt.stats.overruns,
        "fault_reason": rt.fault_reason,
        "watchdog_ms": rt.watchdog * 1e3,
    }
    return StatsCopy(
        runtime,
        rt.stats.scan.copy(share_window=True),
        {name: s.copy(share_window=True) for name, s in rt.stats.tasks.items()},
        {d.name: d.stats() for d in rt.drivers},
        fleet_counters(program),
    )


def render_stats(c: StatsCopy) -> dict[str, Any]:
    return {
        **c.runtime,
        "scan": c.scan.to_dict(),
        "tasks": {name: s.to_dict() for name, s in c.tasks.items()},
        "drivers": c.drivers,
        "fleet": c.fleet,
    }


def light_stats(program: FleetProgram) -> dict[str, Any]:
    """The statistics the stream sends: counters and the last, mean and max scan, no
    percentile (they cost the scan a sort; ``GET /stats`` has them)."""
    rt = program.rt
    scan = rt.stats.scan
    return {
        "state": rt.state,
        "cycles": rt.ticks,
        "sim_time_s": round(rt.clock_time, 9),
        "overruns": rt.stats.overruns,
        "exec_us": {
            "last": round(scan.exec_last_ns * 1e-3, 3),
            "mean": round(scan.exec_mean_ns * 1e-3, 3),
            "max": round(scan.exec_max_ns * 1e-3, 3),
        },
    }


def fleet_counters(program: FleetProgram) -> dict[str, Any]:
    fleet: dict[str, Any] = {
        "vehicles": len(program.vehicles),
        "recipes_completed": program.completed.total,
        "deadlocks_detected": program.resolver.detected,
        "deadlocks_resolved": program.resolver.resolved,
        "blocked_segments": program.status.blocked_segments,
    }
    if program.monitor is not None:
        m = program.monitor
        fleet |= {
            "head_on_conflicts": m.head_on,
            "node_conflicts": m.node,
            "area_conflicts": m.area,
        }
    if program.orders is not None:
        fleet["orders"] = program.orders.book.counts()
    return fleet


class EventsCopy(NamedTuple):
    """The scan's part of an events answer: numbers and the (immutable) events chosen;
    :func:`render_events` turns them into JSON in the server's thread."""

    first: int
    last: int
    start: int
    events: tuple[Event, ...]


def events(program: FleetProgram, after: int, limit: int) -> EventsCopy:
    """Events numbered ``after + 1`` on (at most ``limit``), oldest first. Numbers count
    every event of the run from 1; the log keeps the newest, so ``first`` says where the
    kept ones begin."""
    log = program.events
    first = log.added - len(log.events) + 1
    start = max(after + 1, first)
    skip = start - first
    return EventsCopy(first, log.added, start, tuple(islice(log.events, skip, skip + limit)))


def render_events(c: EventsCopy) -> dict[str, Any]:
    return {
        "first": c.first,
        "last": c.last,
        "events": [{"seq": c.start + i, **e.to_dict()} for i, e in enumerate(c.events)],
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
