"""Lifelong warehouse operation: tasks completed per timestep with 60, 100 and 140 vehicles.

The fleet program runs end to end on the virtual clock on the default 33 x 46 warehouse
(1068 nodes, 480 endpoints), the vehicles co-simulated over virtual CAN. Every vehicle is
sent to a uniformly random endpoint (a shelf-adjacent aisle cell: passable, with a shelf
directly above or below) and, the moment it arrives (no processing time), to the next one.
Throughput is tasks (endpoint arrivals) per timestep over 5000 timesteps, one timestep
being the time to drive one 1 m cell at the AGV's top speed (1 m / 0.5 m/s = 2 s), so 5000
timesteps are 10000 simulated seconds.

Reference, printed beside ours: the published lifelong multi-agent path-finding result of a
centralised C++ planner on a comparable 33 x 46 fulfilment map, 2.33 / 3.56 / 4.55 tasks
per timestep for 60 / 100 / 140 agents, and the no-congestion upper bound of that setting,
2.59 / 4.32 / 6.05 (agents / mean distance between goals). Our value is shown as a ratio to
both. We also print our own map's no-congestion bound under the MAPF model (vehicles /
mean shortest distance in cells between two uniformly random endpoints), to show how far
the maps are comparable.

A lower number than the MAPF planner's is expected: there a move takes exactly one
timestep and agents turn and stop for free; our vehicles are physical (0.5 m/s top speed,
0.5 m/s^2 acceleration, 0.8 m/s^2 deceleration, 1 s per 90 degree turn, 2 s per U-turn),
so even an unhindered vehicle needs more than d timesteps for a d-cell trip with turns,
and the controller reserves nodes a few segments ahead instead of planning in space-time.
Also reported: the independent conflict monitor's counts (must be 0), deadlocks
detected/resolved/unresolved, vehicles that completed nothing in the last 500 timesteps
(stuck), scan times and the wall time of each run.

Cycle time: 50 ms. The full runs took 6 / 12 / 18 minutes of wall time for their 200,000
scans each (scan p50 1.8 / 3.5 / 5.4 ms, co-simulation included), about 36 minutes in one
process; run the sizes separately with ``--sizes`` to split it. 100 ms would halve the
scans but not the wall time (each scan then simulates twice the motion and takes ~1.5x
longer). An earlier version of the program also counted 3 head-on and 10 node conflicts in
a 300 s trial at 100 vehicles and 100 ms; the cause was not found. The current version
counted none in the same trial (205 tasks). 50 ms is kept (``--cycle-ms`` changes it).

Because a lifelong run can degrade (vehicles jammed for good), the table also gives the
throughput over the first 500 timesteps and the timestep of the last completed task.

``--quick`` runs 60 vehicles for 50 timesteps in both traffic modes on both plants (100
simulated s, 2000 scans each; a minute or two): the same table and ratios, but over the
start-up, where every vehicle begins at a random node, so its throughput is not the
lifelong one.

    .venv/bin/python bench/warehouse_throughput.py [--timesteps 5000] [--sizes 60 100 140] [--seeds 0 1 2] [--quick]
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from fleet_scale import FUNCTION, ScanRecorder, make_program, timestep_s  # noqa: E402

from blocks.traffic.planners import PlanRequest, register_planner  # noqa: E402
from blocks.traffic.tw_traffic import PLAN_ORDERS  # noqa: E402
from plc_runtime.cli import positive, whole  # noqa: E402
from topology import kiva, warehouse  # noqa: E402
from vehicles.agv import AgvParams  # noqa: E402

WIDTH = 46
REFERENCE = {60: 2.33, 100: 3.56, 140: 4.55}  # tasks per timestep, centralised C++ planner
UPPER_BOUND = {60: 2.59, 100: 4.32, 140: 6.05}  # no-congestion bound of that setting
STUCK_TIMESTEPS = 500
EARLY_TIMESTEPS = 500  # throughput over the first 500 timesteps too (before any gridlock)
PLANTS = {"warehouse": warehouse, "kiva": kiva}  # both 33 x 46
BOUND_TIMESTEPS = 2000  # the single vehicle's run that gives our kinematics' bound
# --quick lowers these defaults; options given on the command line still win.
QUICK = {
    "timesteps": 50,
    "sizes": [60],
    "bound_timesteps": 200,
    "traffic": ["reactive", "time_windows"],
}


def route_first(request: PlanRequest):
    """A planner of one's own as a baseline for the built-in search: the shortest route
    over the open arcs, timed through the free windows (waiting where it must, never
    going round anyone)."""
    route = yield from request.shortest_route()
    return None if route is None else (yield from request.timed(route))


PLANNERS = {"sipp": None, "route_first": route_first}


def mean_endpoint_distance(program) -> float:
    """Mean shortest distance in cells between two uniformly random endpoints (the exact
    heuristic table the program built: rows are the endpoints)."""
    table = program.table
    eps = program.cfg.clusters[FUNCTION]
    plant = program.cfg.plant
    cols = [plant.idx(e) for e in eps]
    total, count = 0.0, 0
    for e in eps:
        row = table.row(e)
        d = np.asarray(row)[cols]
        total += float(d[np.isfinite(d)].sum())
        count += int(np.isfinite(d).sum())
    cell_m = timestep_s() * AgvParams().max_speed  # 1 m: the warehouse's cell size
    return total / count / cell_m if count else float("nan")


def run_size(
    vehicles: int,
    timesteps: int,
    cycle_time: float,
    watchdog: float,
    plant_name: str = "warehouse",
    traffic: str = "reactive",
    delay_rate: float = 0.0,
    plan_budget: int | None = None,
    highway_factor: float | None = None,
    plan_order: str | None = None,
    seed: int = 0,
    planner: str = "sipp",
) -> dict:
    plant = PLANTS[plant_name]()
    if PLANNERS[planner] is not None:
        register_planner(planner, PLANNERS[planner])
    begin = time.perf_counter()
    program = make_program(
        plant,
        WIDTH,
        vehicles,
        cycle_time,
        watchdog,
        seed=seed,
        traffic=traffic,
        delay_rate=delay_rate,
        plan_budget=plan_budget,
        highway_factor=highway_factor,
        plan_order=plan_order,
        planner=planner,
    )
    program.rt.start()
    setup_s = time.perf_counter() - begin
    mean_d = mean_endpoint_distance(program)
    recorder = ScanRecorder(program)
    sim_s = timesteps * timestep_s()
    total = round(sim_s / cycle_time)
    early_at = round(EARLY_TIMESTEPS * timestep_s() / cycle_time)
    stuck_at = total - round(STUCK_TIMESTEPS * timestep_s() / cycle_time)
    # the program keeps only its newest task records, so what the table needs of older ones
    # (tasks done by the early mark, each vehicle's count as the stuck window opens) is
    # read as the run passes those marks
    early_tasks: int | None = None
    rounds_then: dict[int, int] = {}
    gc.collect()
    gc.freeze()  # plant, table and fleet are startup data: keep the collector off them
    begin = time.perf_counter()
    try:
        cycles = 0
        for mark in sorted({m for m in (early_at, stuck_at, total) if 0 < m <= total}):
            cycles += recorder.run(mark - cycles)
            if cycles == early_at:
                early_tasks = program.completed.total
            if cycles == stuck_at:
                rounds_then = {v: s.rounds_done for v, s in program.sequencers.items()}
    finally:
        wall_s = time.perf_counter() - begin
        gc.unfreeze()
    rt = program.rt
    simulated = cycles * cycle_time
    scans, control = recorder.arrays()
    last: dict[int, float | None] = dict.fromkeys(program.vehicles)  # among the tasks kept
    for run in program.completed:
        if run.finished_s is not None:
            last[run.vehicle] = max(last[run.vehicle] or 0.0, run.finished_s)
    stuck = [v for v, n in rounds_then.items() if program.sequencers[v].rounds_done == n]
    agvs = {
        v + k * 126: agv
        for k, fleet in enumerate(program.fleets)
        for v, agv in fleet.vehicles.items()
    }
    stuck_info = []
    for v in stuck[:8]:
        c, agv = program.controls[v], agvs[v]
        physical = f"physically at {agv.node}"
        if agv.target is not None:
            physical += f" -> {agv.target} ({agv.progress:.2f} m)"
        physical += f", speed {agv.speed:.2f} m/s"
        physical += ", blocked ahead" if agv.blocked_ahead else ""
        physical += ", stalled" if agv.stalled else ""
        stuck_info.append(
            (v, c.state, c.current, program.sequencers[v].target, c.waiting_for, last[v], physical)
        )
    finished = sorted(r.finished_s for r in program.completed if r.finished_s is not None)
    out = {
        "vehicles": vehicles,
        "seed": seed,
        "plant": plant_name,
        "traffic": traffic,
        "highway_factor": program.cfg.highway_factor,
        "plan_order": program.cfg.time_windows.plan_order,
        "planner": planner,
        "refused_plans": program.traffic.refused if program.traffic else 0,
        "delay_rate": delay_rate,
        "delays": sum(f.counters["delays"] for f in program.fleets),
        "state": rt.state,
        "fault": rt.fault_reason,
        "sim_s": simulated,
        "timesteps": simulated / timestep_s(),
        "wall_s": wall_s,
        "setup_s": setup_s,
        "tasks": program.completed.total,
        "early": early_tasks / EARLY_TIMESTEPS if early_tasks is not None else None,
        "last_task_s": finished[-1] if finished else None,
        "mean_d": mean_d,
        "whole_us": [np.percentile(scans, q) / 1e3 for q in (50, 99)] if len(scans) else [0, 0],
        "control_us": [np.percentile(control, q) / 1e3 for q in (50, 99)]
        if len(control)
        else [0, 0],
        "head_on": program.monitor.head_on,
        "node": program.monitor.node,
        "events": list(program.monitor.events),  # the newest the monitor keeps
        "conflicts": program.monitor.events.total,
        "deadlocks": (
            program.resolver.detected,
            program.resolver.resolved,
            program.resolver.unresolved,
        ),
        "deadlock_events": [e for e in program.resolver.events if e.backed_off is None][:5],
        "pushes": program.resolver.pushes,
        "replans": sum(c.replans for c in program.controls.values()),
        "stuck": stuck,
        "stuck_info": stuck_info,
    }
    program.close()
    return out


def single_vehicle_rate(plant_name: str, timesteps: int, cycle: float, watchdog: float) -> float:
    """Tasks per timestep of one vehicle alone on the plant: our kinematics' no-congestion
    rate (its turns, accelerations and stops included), times N the bound for N vehicles.
    It drives shortest routes (no highways): a bound that took their detours would be
    lower, and flatter the fleets that take them."""
    r = run_size(1, timesteps, cycle, watchdog, plant_name, highway_factor=1.0)
    return r["tasks"] / r["timesteps"] if r["timesteps"] else float("nan")


def between(low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a finite number from ``low`` to ``high``, the range the fleet's
    configuration accepts for the option, so that a bad one stops at the command line
    with the option named, not after the single vehicle's long run."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not low <= value <= high:  # nan and inf fail it too
            raise argparse.ArgumentTypeError(f"must be a number from {low:g} to {high:g}: {text!r}")
        return value

    return parse


def json_rows(rows: list[dict], rate: dict[str, float]) -> list[str]:
    """One JSON object per plant and fleet size (the contract for scripts)."""
    out = []
    for r in rows:
        n = r["vehicles"]
        out.append(
            json.dumps(
                {
                    "plant": r["plant"],
                    "vehicles": n,
                    "seed": r["seed"],
                    "traffic": r["traffic"],
                    "highway_factor": r["highway_factor"],
                    "plan_order": r["plan_order"],
                    "planner": r["planner"],
                    "refused_plans": r["refused_plans"],
                    "delay_rate": r["delay_rate"],
                    "timesteps": round(r["timesteps"]),
                    "tasks": r["tasks"],
                    "tasks_per_timestep": r["tasks"] / r["timesteps"] if r["timesteps"] else None,
                    "bound_tasks_per_timestep": rate[r["plant"]] * n,
                    "head_on_conflicts": r["head_on"],
                    "node_conflicts": r["node"],
                    "stuck_vehicles": len(r["stuck"]),
                    "deadlocks_unresolved": r["deadlocks"][2],
                    "state": r["state"],
                    "wall_s": r["wall_s"],
                }
            )
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=positive(int), nargs="+", default=[60, 100, 140])
    parser.add_argument("--timesteps", type=positive(int), default=5000)
    parser.add_argument("--plant", nargs="+", choices=sorted(PLANTS), default=["kiva", "warehouse"])
    parser.add_argument(
        "--traffic",
        nargs="+",
        choices=["reactive", "time_windows"],
        default=["reactive"],
        help="the fleet's traffic modes to run, side by side",
    )
    parser.add_argument(
        "--delay-rate",
        type=between(0.0, 1.0),
        nargs="+",
        default=[0.0],
        help="random stops of 1-10 s: the chance per second and vehicle (0: none)",
    )
    parser.add_argument(
        "--plan-budget",
        type=positive(int),
        default=None,
        help="time_windows: search expansions per scan (default: the configuration's)",
    )
    parser.add_argument(
        "--highway-factor",
        type=between(1.0, 1e6),
        default=None,
        help="cost factor against a highway lane (kiva's long lanes; default: the "
        "configuration's, 3; 1 ignores them)",
    )
    parser.add_argument(
        "--plan-order",
        choices=PLAN_ORDERS,
        default=None,
        help="time_windows: who a round plans first (default: the configuration's, release)",
    )
    parser.add_argument(
        "--planner",
        choices=sorted(PLANNERS),
        default="sipp",
        help="time_windows: the built-in search (sipp), or route_first, a planner of one's "
        "own registered by this script (the shortest route, timed through the free windows)",
    )
    parser.add_argument(
        "--seeds",
        type=whole,
        nargs="+",
        default=[0],
        help="seeds of the starts and tasks, one run each (a summary over them follows)",
    )
    parser.add_argument("--bound-timesteps", type=positive(int), default=BOUND_TIMESTEPS)
    parser.add_argument("--json", action="store_true", help="one JSON object per run, per line")
    parser.add_argument("--cycle-ms", type=between(0.1, 1000.0), default=50.0)
    parser.add_argument("--watchdog-ms", type=between(1.0, 6000.0), default=1000.0)
    parser.add_argument(
        "--quick",
        action="store_true",
        help="reduced run: --timesteps 50 --sizes 60, both traffic modes, both plants",
    )
    args = parser.parse_args()
    if args.quick:
        parser.set_defaults(**QUICK)
        args = parser.parse_args()
    for p in args.plant:  # before the single vehicle's run: a bad size fails at once
        if max(args.sizes) > (nodes := PLANTS[p]().n):
            parser.error(
                f"argument --sizes: {max(args.sizes)} vehicles, but {p} has {nodes} nodes "
                "to start on"
            )
    timesteps = args.timesteps
    cycle = args.cycle_ms / 1e3
    watchdog = args.watchdog_ms / 1e3
    begin = time.perf_counter()
    rate = {p: single_vehicle_rate(p, args.bound_timesteps, cycle, watchdog) for p in args.plant}
    rows = [
        run_size(
            n,
            timesteps,
            cycle,
            watchdog,
            p,
            traffic,
            delay,
            args.plan_budget,
            args.highway_factor,
            args.plan_order,
            seed,
            args.planner,
        )
        for p in args.plant
        for traffic in args.traffic
        for delay in args.delay_rate
        for n in args.sizes
        for seed in args.seeds
    ]
    if args.json:
        print("\n".join(json_rows(rows, rate)))
        return
    for p in args.plant:
        report(p, [r for r in rows if r["plant"] == p], timesteps, rate[p], args, begin)
    print(f"wall time {time.perf_counter() - begin:.1f} s")


def same(rows: list[dict], r: dict, **change) -> dict | None:
    """The run that differs from ``r`` only in ``change`` (None: not run, or ``r`` itself)."""
    keys = ("plant", "vehicles", "traffic", "delay_rate", "seed")
    want = {k: change.get(k, r[k]) for k in keys}
    if all(want[k] == r[k] for k in keys):
        return None
    return next((o for o in rows if all(o[k] == want[k] for k in keys)), None)


def seed_summary(plant_name: str, rows: list[dict], rate: float) -> Table:
    """Per traffic mode, delay rate and fleet size: tasks per timestep as the mean over the
    seeds with their min-max, beside our kinematics' bound and the same seeds' reactive
    mean. A single run of a large fleet varies by up to 15 % with the seed, so a
    comparison of two versions or modes needs several."""
    table = Table(title=f"Over the seeds, {plant_name}: tasks per timestep, mean (min-max)")
    for name in (
        "traffic",
        "delays p/s",
        "vehicles",
        "seeds",
        "tasks/timestep",
        "x reactive",
        "ours / our bound",
        "conflicts",
    ):
        table.add_column(name, justify="right")
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["traffic"], r["delay_rate"], r["vehicles"]), []).append(r)

    def rates(group: list[dict]) -> list[float]:
        return [r["tasks"] / r["timesteps"] if r["timesteps"] else 0.0 for r in group]

    for (traffic, delay, n), group in groups.items():
        mine = rates(group)
        mean = float(np.mean(mine))
        reactive = groups.get(("reactive", delay, n))
        base = float(np.mean(rates(reactive))) if reactive and traffic != "reactive" else 0.0
        table.add_row(
            traffic,
            f"{delay:g}",
            str(n),
            str(len(group)),
            f"{mean:.3f} ({min(mine):.3f}-{max(mine):.3f})",
            f"{mean / base:.2f}" if base else "-",
            f"{mean / (rate * n):.2f}" if rate else "-",
            str(sum(r["head_on"] + r["node"] for r in group)),
        )
    return table


def report(plant_name, rows, timesteps, rate, args, begin) -> None:
    console = Console(width=max(Console().width, 260))
    console.print(
        f"Lifelong warehouse throughput, Python {sys.version.split()[0]}: {plant_name} 33x46, "
        f"{timesteps} timesteps of {timestep_s():g} s, cycle {args.cycle_ms:g} ms, "
        f"traffic {' / '.join(args.traffic)}, random delays per s {args.delay_rate}, "
        f"highway factor {rows[0]['highway_factor']:g}, time-window plan order "
        f"{rows[0]['plan_order']}, planner {rows[0]['planner']}"
    )
    for r in rows:
        n = r["vehicles"]
        console.print(
            f"  {n} vehicles, {r['traffic']}, delays {r['delay_rate']:g}/s: {r['tasks']} tasks "
            f"in {r['timesteps']:.0f} timesteps, "
            f"run {r['wall_s']:.0f} s wall (setup {r['setup_s']:.1f} s), state {r['state']}"
        )

    table = Table(title=f"Tasks per timestep, lifelong, 33x46 {plant_name} ({timesteps} timesteps)")
    for name in (
        "traffic",
        "delays p/s",
        "vehicles",
        "seed",
        "tasks",
        "x reactive",
        "kept vs no delays",
        "ours tasks/timestep",
        f"ours, first {EARLY_TIMESTEPS} timesteps",
        "last task at timestep",
        "reference (C++ MAPF)",
        "ours / reference",
        "no-congestion bound (published)",
        "ours / bound",
        "our map's MAPF bound",
        "our kinematics' bound",
        "ours / our bound",
        "conflicts head-on/node",
        "deadlocks det/res/unres",
        "stuck vehicles",
        "replans / vehicle-h",
        "scan p50/p99 us",
        "control p50/p99 us",
        "wall s",
        "state",
    ):
        table.add_column(name, justify="right")
    for r in rows:
        n = r["vehicles"]
        ours = r["tasks"] / r["timesteps"] if r["timesteps"] else float("nan")
        ref, bound = REFERENCE.get(n), UPPER_BOUND.get(n)
        reactive = same(rows, r, traffic="reactive")
        undelayed = same(rows, r, delay_rate=0.0)
        table.add_row(
            r["traffic"],
            f"{r['delay_rate']:g}",
            str(n),
            str(r["seed"]),
            str(r["tasks"]),
            f"{r['tasks'] / reactive['tasks']:.2f}" if reactive and reactive["tasks"] else "-",
            f"{r['tasks'] / undelayed['tasks']:.2f}" if undelayed and undelayed["tasks"] else "-",
            f"{ours:.3f}",
            f"{r['early']:.3f}" if r["early"] is not None else "-",
            f"{r['last_task_s'] / timestep_s():.0f}" if r["last_task_s"] is not None else "-",
            f"{ref:.2f}" if ref else "-",
            f"{ours / ref:.2f}" if ref else "-",
            f"{bound:.2f}" if bound else "-",
            f"{ours / bound:.2f}" if bound else "-",
            f"{n / r['mean_d']:.2f}",
            f"{rate * n:.2f}",
            f"{ours / (rate * n):.2f}" if rate else "-",
            f"{r['head_on']}/{r['node']}",
            "/".join(str(x) for x in r["deadlocks"]),
            str(len(r["stuck"])),
            f"{r['replans'] / (n * r['sim_s'] / 3600):,.0f}" if r["sim_s"] else "-",
            f"{r['whole_us'][0]:,.0f} / {r['whole_us'][1]:,.0f}",
            f"{r['control_us'][0]:,.0f} / {r['control_us'][1]:,.0f}",
            f"{r['wall_s']:,.0f}",
            r["state"] if r["fault"] is None else f"{r['state']}: {r['fault']}",
        )
    console.print(table)
    if len(args.seeds) > 1:
        console.print(seed_summary(plant_name, rows, rate))
    console.print(
        f"our map's MAPF bound = vehicles / mean shortest distance between random endpoints "
        f"({rows[0]['mean_d']:.1f} cells); stuck = no task completed in the last {STUCK_TIMESTEPS} "
        "timesteps; scan includes the co-simulated vehicles, control = scan minus them; "
        f"our kinematics' bound = one vehicle's rate alone on the map ({rate:.4f} tasks per "
        f"timestep over {args.bound_timesteps} timesteps) x vehicles."
    )
    for r in rows:
        for e in r["events"][:10]:
            console.print(f"  conflict with {r['vehicles']} vehicles: {e}")
        if r["conflicts"] > 10:
            console.print(
                f"  ... {r['conflicts'] - 10} more conflicts with {r['vehicles']} vehicles"
            )
        for e in r["deadlock_events"]:
            console.print(f"  unresolved deadlock with {r['vehicles']} vehicles: {e}")
        for v, state, node, target, waiting_for, last, physical in r["stuck_info"]:
            done = f"last task done at {last:.0f} s" if last is not None else "no task kept"
            console.print(
                f"  stuck with {r['vehicles']} vehicles: vehicle {v} state {state} at node {node} "
                f"target {target} waiting for {waiting_for}, {done}; {physical}"
            )


if __name__ == "__main__":
    main()
