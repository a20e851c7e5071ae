"""The experiments of the time-window planning study (seed 004) with our planner.

The study plans on a 40 x 30 grid; its tables give total distance and total time of 4, 8 and
12 tasks (one robot per task, priority = task number) for plain Dijkstra routing and for its
time-window planner, and a head-on experiment between two robots on given routes. The
source gives no speed, cell length or turn time, so we choose and state them: cells of
``--cell-m`` metres (6 by default: the head-on robot h2 then needs 132 s for its 21 cells and
6 turns, the study's 132.39 s), 1 m/s, 1 s per 90-degree turn, 2 s per U-turn, a safety gap
of 1 s, an open grid (the study shows no obstacles), every robot starting at t = 0 facing
any way it likes, and staying ``--dwell-s`` seconds at its goal (the pick) before it drives
off to work the map no longer shows. Total time is the sum of the arrival times.

1. **Tasks** (4, 8, 12). Dijkstra: each robot's shortest path by plain Dijkstra (turns not
   counted), then timed in priority order through the time-window table: it may only wait
   on its path, as with the study's online rules; a robot that waiting cannot get through
   (its path meets a robot of higher priority head-on, and that one's goal is its start)
   replans, as the study's robots do after their wait thresholds. Time windows: each robot searched in
   priority order by SIPP over (node, heading) with turning time, through the windows of the
   robots before it; and the same with path heat (the study's offline stage: arc usage of
   the Dijkstra paths as arc weights). Every plan is booked in the table, which refuses any
   conflict, so all rows are conflict-free.
2. **Head-on.** h1 (priority 1) on its given route, h2 on its own: h2's arrival with no
   conflict (h1 absent), with pure waiting (held to its route), and with the online detour:
   held to its route except within one cell of the segment where the two routes meet
   head-on, where it may step aside (the study's detour is (14,8) -> (15,8) -> (15,6) ->
   (14,6)). The planner weighs waiting against detouring in one search, as the study asks
   (take the cheaper, estimating both).

Ratios against the study's published figures are printed in the same run.

    .venv/bin/python bench/time_windows.py [--cell-m 6] [--dwell-s 10] [--quick]

``--quick``: the same tables (they take well under a second); kept for ``make bench-quick``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse.csgraph import dijkstra

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from blocks.traffic.path_heat import arc_usage, heat_weights  # noqa: E402
from blocks.traffic.sipp import SafeIntervalSearch, TimedPlan, TurnTimes  # noqa: E402
from blocks.traffic.time_windows import TimeWindowTable  # noqa: E402
from plc_runtime.cli import non_negative, positive  # noqa: E402
from topology import Plant  # noqa: E402
from topology.grid import grid_plant  # noqa: E402

WIDTH, HEIGHT = 40, 30
SPEED = 1.0  # m/s
TURNS = TurnTimes(1.0, 2.0)
GAP_S = 1.0
# (start, goal) as (x, y) grid coordinates; priority = position in the list
TASKS = (
    ((10, 18), (8, 1)),
    ((21, 10), (16, 1)),
    ((19, 23), (24, 1)),
    ((29, 8), (32, 1)),
    ((32, 25), (17, 13)),
    ((8, 23), (11, 13)),
    ((24, 1), (16, 15)),
    ((29, 25), (25, 8)),
    ((7, 5), (29, 5)),
    ((38, 27), (32, 1)),
    ((6, 15), (19, 8)),
    ((18, 8), (30, 15)),
)
# published: tasks -> (distance, time) for Dijkstra and for the time-window planner
PUBLISHED = {
    4: ((549.35, 559.35), (534.9, 550.9)),
    8: ((1107.71, 1131.72), (1085.24, 1119.45)),
    12: ((1692.41, 1708.42), (1650.87, 1697.78)),
}
H1 = ((16, 1), (16, 2), (14, 2), (14, 10), (11, 10))  # waypoints of the given routes
H2 = ((13, 15), (13, 13), (14, 13), (14, 5), (10, 5), (10, 3), (8, 3), (8, 1))
PUBLISHED_HEAD_ON = {"no conflict": 132.39, "waiting": 162.86, "detour": 146.25}


def cell(x: int, y: int) -> int:
    return y * WIDTH + x


def seed_grid(cell_m: float) -> Plant:
    return grid_plant(
        np.ones((HEIGHT, WIDTH), dtype=bool), cell_m, name=f"seed004-{WIDTH}x{HEIGHT}"
    )


def along(waypoints) -> list[int]:
    """The cells of a route given by its corners."""
    out = [cell(*waypoints[0])]
    for (x0, y0), (x1, y1) in zip(waypoints, waypoints[1:], strict=False):
        if x0 != x1 and y0 != y1:
            raise ValueError(f"waypoints {(x0, y0)} -> {(x1, y1)} are not on one row or column")
        n = abs(x1 - x0) + abs(y1 - y0)
        out += [cell(x0 + (x1 - x0) * k // n, y0 + (y1 - y0) * k // n) for k in range(1, n + 1)]
    return out


def dijkstra_route(plant: Plant, start: int, goal: int) -> list[int]:
    _, pred = dijkstra(plant.csr, directed=True, indices=plant.idx(start), return_predecessors=True)
    route, at = [], plant.idx(goal)
    while at >= 0:
        route.append(int(plant.ids[at]))
        at = pred[at]
    return route[::-1]


def arcs_of(plant: Plant, nodes) -> list[bool]:
    """An ``allowed`` mask: the arcs between consecutive nodes of a route, or (a set) every
    arc between two of the nodes."""
    allowed = [False] * plant.n_arcs
    if isinstance(nodes, (set, frozenset)):
        pairs = [(a, b) for a in nodes for b in nodes]
    else:
        pairs = list(zip(nodes, nodes[1:], strict=False))
    for a, b in pairs:
        for arc in plant.arc_index.get((a, b), ()):
            allowed[arc] = True
    return allowed


def plan(plant, table, vehicle, start, goal, dwell_s, **kw) -> TimedPlan | None:
    search = SafeIntervalSearch(
        plant, table, vehicle, start, goal, 0.0, speed=SPEED, turns=TURNS, hold_s=dwell_s, **kw
    )
    search.step(None)
    if search.plan is not None:
        search.plan.book(table)
    return search.plan


@dataclass
class Totals:
    distance: float
    time: float
    planned: int  # robots with a plan (all of them, unless one is stuck for good)
    replanned: int  # Dijkstra robots that could not wait their way through and replanned
    plan_ms: float


def run_tasks(plant: Plant, n: int, mode: str, dwell_s: float) -> Totals:
    """Plan tasks 1..n in priority order: ``dijkstra`` (shortest path, waits only),
    ``time_windows`` (SIPP with turns), ``heat`` (SIPP with turns and path heat)."""
    tasks = [(cell(*s), cell(*g)) for s, g in TASKS[:n]]
    table = TimeWindowTable(GAP_S)
    routes = [dijkstra_route(plant, s, g) for s, g in tasks]
    weights = heat_weights(arc_usage(plant, routes)).tolist() if mode == "heat" else None
    distance = total_time = 0.0
    planned = replanned = 0
    begin = time.perf_counter()
    for vehicle, ((start, goal), route) in enumerate(zip(tasks, routes, strict=True), start=1):
        if mode == "dijkstra":
            p = plan(plant, table, vehicle, start, goal, dwell_s, allowed=arcs_of(plant, route))
            if p is None:  # waiting cannot resolve it: it replans (the study's online rule)
                replanned += 1
                p = plan(plant, table, vehicle, start, goal, dwell_s)
        else:
            p = plan(plant, table, vehicle, start, goal, dwell_s, weights=weights)
        if p is None:
            continue
        planned += 1
        distance += plant_length(plant, p.nodes)
        total_time += p.arrival
    return Totals(distance, total_time, planned, replanned, (time.perf_counter() - begin) * 1e3)


def plant_length(plant: Plant, nodes) -> float:
    _, _, length = plant.arcs
    return sum(
        min(length[k] for k in plant.arc_index[(a, b)])
        for a, b in zip(nodes, nodes[1:], strict=False)
    )


@dataclass
class HeadOn:
    no_conflict: TimedPlan
    waiting: TimedPlan
    detour: TimedPlan
    conflict: tuple[int, int]  # the first segment where h2's free plan meets h1 head-on


def head_on(plant: Plant, dwell_s: float) -> HeadOn:
    r1, r2 = along(H1), along(H2)
    table = TimeWindowTable(GAP_S)
    h1 = plan(plant, table, 1, r1[0], r1[-1], dwell_s, allowed=arcs_of(plant, r1))
    alone = plan(
        plant, TimeWindowTable(GAP_S), 2, r2[0], r2[-1], dwell_s, allowed=arcs_of(plant, r2)
    )
    conflict = first_head_on(h1, alone)
    waiting = plan(plant, only(h1), 2, r2[0], r2[-1], dwell_s, allowed=arcs_of(plant, r2))
    near = {
        cell(x + dx, y + dy)
        for c in conflict
        for x, y in [(c % WIDTH, c // WIDTH)]
        for dx in (-1, 0, 1)
        for dy in (-1, 0, 1)
        if 0 <= x + dx < WIDTH and 0 <= y + dy < HEIGHT
    }
    corridor = [a or b for a, b in zip(arcs_of(plant, r2), arcs_of(plant, near), strict=True)]
    detour = plan(plant, only(h1), 2, r2[0], r2[-1], dwell_s, allowed=corridor)
    return HeadOn(alone, waiting, detour, conflict)


def only(*plans: TimedPlan) -> TimeWindowTable:
    """A table holding just these plans."""
    table = TimeWindowTable(GAP_S)
    for p in plans:
        p.book(table)
    return table


def first_head_on(p1: TimedPlan, p2: TimedPlan) -> tuple[int, int]:
    """The first segment (in p2's order) that p2 drives while p1 drives it the other way."""
    oncoming = {(a, b): (s, e) for a, b, s, e in p1.segment_windows()}
    for a, b, s, e in p2.segment_windows():
        w = oncoming.get((b, a))
        if w is not None and s < w[1] + GAP_S and w[0] < e + GAP_S:
            return (a, b)
    raise RuntimeError("the given routes do not meet head-on with these speeds")


def xy(node: int) -> tuple[int, int]:
    return (node % WIDTH, node // WIDTH)


def turns_of(plant: Plant, nodes) -> int:
    dirs = [
        (b % WIDTH - a % WIDTH, b // WIDTH - a // WIDTH)
        for a, b in zip(nodes, nodes[1:], strict=False)
    ]
    return sum(1 for d0, d1 in zip(dirs, dirs[1:], strict=False) if d0 != d1)


def report(cell_m: float, dwell_s: float) -> None:
    plant = seed_grid(cell_m)
    print(
        f"Time-window planning (seed 004), {WIDTH} x {HEIGHT} grid, cells {cell_m:g} m, {SPEED:g} m/s,"
    )
    print(
        f"turns {TURNS.turn_90:g} s / {TURNS.turn_180:g} s, gap {GAP_S:g} s, dwell at the goal {dwell_s:g} s"
    )
    print()
    print("### 1. Total distance and time, tasks 1..n (one robot each)")
    print()
    print(
        "| tasks | Dijkstra distance (m) | Dijkstra time (s) | time windows distance | time windows time "
        "| with path heat distance | with path heat time | distance change | time change "
        "| study: distance change | study: time change | planning (ms) |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    replans = {}
    for n in (4, 8, 12):
        base = run_tasks(plant, n, "dijkstra", dwell_s)
        tw = run_tasks(plant, n, "time_windows", dwell_s)
        heat = run_tasks(plant, n, "heat", dwell_s)
        (pd, pt), (qd, qt) = PUBLISHED[n]
        best = min((tw, heat), key=lambda r: r.time)
        print(
            f"| {n} | {base.distance:.1f} | {base.time:.1f} | {tw.distance:.1f} | {tw.time:.1f} "
            f"| {heat.distance:.1f} | {heat.time:.1f} "
            f"| {pct(best.distance, base.distance)} | {pct(best.time, base.time)} "
            f"| {pct(qd, pd)} | {pct(qt, pt)} | {tw.plan_ms + heat.plan_ms:.1f} |"
        )
        for name, r in (("Dijkstra", base), ("time windows", tw), ("path heat", heat)):
            if r.planned != n:
                print(f"|  | {name}: only {r.planned} of {n} robots found a plan |")
        replans[n] = base.replanned
    print()
    print(
        "Dijkstra robots that could not wait their way through and replanned (the study's online "
        "rule): "
        + ", ".join(f"{k} at {n} tasks" for n, k in replans.items())
        + ". Both columns count every robot."
    )
    print()
    print("### 2. Head-on: h2's travel time (h1 has priority)")
    print()
    h = head_on(plant, dwell_s)
    a, b = h.conflict
    print(f"The routes meet head-on first on {xy(a)} -> {xy(b)} (the study: on (14,8)-(14,6)).")
    print()
    print("| h2 | ours: time (s) | ours: distance (m) | turns | study: time (s) | ours / study |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, p in (
        ("no conflict", h.no_conflict),
        ("pure waiting", h.waiting),
        ("online detour", h.detour),
    ):
        published = PUBLISHED_HEAD_ON[name.split()[-1] if name != "no conflict" else name]
        print(
            f"| {name} | {p.arrival:.1f} | {plant_length(plant, p.nodes):.1f} | {turns_of(plant, p.nodes)} "
            f"| {published:.2f} | {p.arrival / published:.3f} |"
        )
    gain = h.waiting.arrival - h.detour.arrival
    print()
    print(
        f"Detouring beats waiting by {gain:.1f} s (the study: "
        f"{PUBLISHED_HEAD_ON['waiting'] - PUBLISHED_HEAD_ON['detour']:.2f} s). "
        f"Detour route: {' '.join(str(xy(n)) for n in h.detour.nodes if n not in along(H2))} off the given route."
    )


def pct(new: float, old: float) -> str:
    return f"{100.0 * (new - old) / old:+.1f} %" if old else "n/a"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cell-m", type=positive(float), default=6.0)
    ap.add_argument("--dwell-s", type=non_negative, default=10.0)
    ap.add_argument("--quick", action="store_true", help="the same tables (they are cheap)")
    args = ap.parse_args()
    begin = time.perf_counter()
    report(args.cell_m, args.dwell_s)
    print()
    print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
