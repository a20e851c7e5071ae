"""The whole fleet program against fleet size: 4, 16, 64, 256 and 1000 vehicles.

Every size runs the fleet program (``fleet.program``) end to end on the virtual
clock: CAN copy-in, per vehicle sequencer and VehicleControl (incremental A*, reservations,
replanning), ReservationMatrix, DeadlockResolver, recorder, CAN copy-out, with the vehicles
co-simulated in the same scan (task ``plant``, after the program) on virtual CAN buses (126
vehicles per bus, so 1000 vehicles are 8 buses and 8 drivers). Each vehicle is sent to a
uniformly random endpoint (a shelf-adjacent aisle cell: passable, with a shelf directly
above or below), and to the next one as soon as it arrives (no processing time).

Plants: the default 33 x 46 warehouse (1068 nodes) while the vehicles fill at most 12 % of
its nodes (4, 16, 64 vehicles); for more vehicles the warehouse is scaled up in both
directions until they do (256: ~2300 nodes, 1000: ~8600 nodes), so the sizes are compared at
a realistic density rather than jammed.

Reported per size: whole-scan execution time p50/p99/max (program + drivers + co-simulated
vehicles, as the runtime's scan statistics measure it), the real-time factor (simulated
seconds per wall second of ``rt.run``), replans per vehicle-hour, tasks completed, the
independent conflict monitor's head-on/node counts (must be 0) and the deadlock counters.

Baseline: the co-simulation of the vehicles would not run on a PLC, so the control cost is
separated out exactly, scan by scan: control = whole scan - the ``plant`` task (both are
recorded for every tick). Its p99 is compared with the cycle budget (the 50 ms cycle time:
the scan must end before the next release) and the count of scans over the budget and over
the S7 default watchdog of 150 ms is given; the control cost per vehicle is compared with the
4-vehicle run (1.0 = the same cost per vehicle; the 4-vehicle run carries the fixed cost of
the scan, so values below 1 are expected). The runs use a 1 s watchdog (``--watchdog-ms``) so
that an overlong scan is counted instead of stopping the run, and freeze the startup objects
out of the garbage collector (``gc.freeze()``, as the runtime's real-time mode does): without
that, a full collection over the 1000-vehicle heap lands in a scan of the first seconds,
where all vehicles plan at once, and the default 150 ms watchdog faulted the run at scan ~23.

Runs simulate ``--sim-seconds`` (300) per size; the default takes about 10 minutes on the
machine of docs/benchmarks.md, most of it the 1000-vehicle run (real-time factor 0.9, plus
10 s to build the program), and several times that on a slower or busy machine.
``--quick``: 10 simulated seconds for 4, 16 and 64 vehicles on the default warehouse, about
5-15 s in all (256 and 1000 vehicles would add 10-90 s, most of it building their programs
and their first, all-planning seconds).

    .venv/bin/python bench/fleet_scale.py [--sizes 4 16 64 256 1000] [--sim-seconds 300] [--quick]
"""

from __future__ import annotations

import argparse
import gc
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from blocks.jobs.recipe import Recipe  # noqa: E402
from blocks.traffic.tw_traffic import PLAN_ORDERS  # noqa: E402
from fleet.config import FleetConfig  # noqa: E402
from fleet.program import FleetProgram  # noqa: E402
from plc_runtime.clock import WallClock  # noqa: E402
from topology import Plant, warehouse  # noqa: E402
from vehicles.agv import AgvParams  # noqa: E402
from vehicles.fleet import Faults  # noqa: E402

DEFAULT_H, DEFAULT_W = 33, 46
MAX_DENSITY = 0.12  # vehicles per node at most
FUNCTION = 3  # the function every endpoint provides
S7_WATCHDOG_S = 0.150
# --quick lowers these defaults; options given on the command line still win.
QUICK = {"sim_seconds": 10.0, "sizes": [4, 16, 64]}


def timestep_s(cell_size: float = 1.0) -> float:
    """One MAPF timestep: the time to drive one cell at full speed (2 s)."""
    return cell_size / AgvParams().max_speed


def endpoints(plant: Plant, width: int) -> list[int]:
    """Shelf-adjacent aisle cells: passable, with an impassable cell directly above or below
    (grid ids are y * width + x; outside the map does not count as a shelf)."""
    ids = set(plant.ids.tolist())
    height = max(ids) // width + 1
    out = []
    for n in sorted(ids):
        y = n // width
        above = y > 0 and (n - width) not in ids
        below = y < height - 1 and (n + width) not in ids
        if above or below:
            out.append(n)
    return out


def plant_for(vehicles: int) -> tuple[Plant, int, int]:
    """(plant, width, height): the default warehouse, scaled up until density <= 12 %."""
    scale = 1.0
    while True:
        height = round(DEFAULT_H * scale) | 1  # odd: symmetric aisles top and bottom
        width = round(DEFAULT_W * scale)
        plant = warehouse(width=width, height=height)
        if vehicles <= MAX_DENSITY * plant.n:
            return plant, width, height
        scale += 0.1


def make_program(
    plant: Plant,
    width: int,
    vehicles: int,
    cycle_time: float,
    watchdog: float,
    seed: int = 0,
    traffic: str = "reactive",
    delay_rate: float = 0.0,
    plan_budget: int | None = None,
    clock: WallClock | None = None,
    highway_factor: float | None = None,
    window_s: float | None = None,
    plan_order: str | None = None,
    planner: str | None = None,
) -> FleetProgram:
    rng = np.random.default_rng(seed)
    starts = rng.choice(plant.ids, size=vehicles, replace=False).tolist()
    ids = list(range(1, vehicles + 1))
    cfg = FleetConfig(
        source="bench",
        plant=plant,
        starts=dict(zip(ids, (int(s) for s in starts), strict=True)),
        recipes={"t": Recipe("t", (FUNCTION,))},
        vehicle_recipes={v: ["t"] for v in ids},
        clusters={FUNCTION: endpoints(plant, width)},
        strategy="random",
        seed=seed,
        processing_s=0.0,
        cycle_time=cycle_time,
        watchdog=watchdog,
        traffic=traffic,
        faults={v: Faults(delay_rate=delay_rate) for v in ids} if delay_rate else {},
    )
    if plan_budget is not None:
        cfg.time_windows.plan_budget = plan_budget
    if window_s is not None:
        cfg.time_windows.window_s = window_s
    if plan_order is not None:
        cfg.time_windows.plan_order = plan_order
    if planner is not None:
        cfg.time_windows.planner = planner
    if highway_factor is not None:
        cfg.highway_factor = highway_factor
    return FleetProgram(cfg, clock=clock)


@dataclass
class ScanRecorder:
    """Every scan's whole and co-simulation execution time (ns), read out of the runtime's
    ring buffers after each chunk of at most one window of ticks."""

    program: FleetProgram
    whole: list[np.ndarray] = field(default_factory=list)
    plant: list[np.ndarray] = field(default_factory=list)

    def _take(self, stats, before: int) -> np.ndarray:
        new = stats.cycles - before
        idx = (np.arange(before, before + new)) % stats.window
        return stats._exec[idx].copy()  # the ring buffer itself: percentiles only cover one window

    def run(self, cycles: int) -> int:
        rt = self.program.rt
        scan, plant = rt.stats.scan, rt.stats["plant"]
        done = 0
        while done < cycles and rt.state == "RUN":
            chunk = min(scan.window, cycles - done)
            before_scan, before_plant = scan.cycles, plant.cycles
            ran = rt.run(cycles=chunk)
            done += ran
            w, p = self._take(scan, before_scan), self._take(plant, before_plant)
            if len(w) != len(p):
                raise RuntimeError(f"scan and plant task counts differ: {len(w)} != {len(p)}")
            self.whole.append(w)
            self.plant.append(p)
            if ran < chunk:
                break
        return done

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        whole = np.concatenate(self.whole) if self.whole else np.zeros(0, dtype=np.int64)
        plant = np.concatenate(self.plant) if self.plant else np.zeros(0, dtype=np.int64)
        return whole, whole - plant


def run_size(
    vehicles: int,
    sim_s: float,
    cycle_time: float,
    watchdog: float,
    traffic: str = "reactive",
    plan_budget: int | None = None,
    window_s: float | None = None,
    plan_order: str | None = None,
) -> dict:
    plant, width, height = plant_for(vehicles)
    begin = time.perf_counter()
    program = make_program(
        plant,
        width,
        vehicles,
        cycle_time,
        watchdog,
        traffic=traffic,
        plan_budget=plan_budget,
        window_s=window_s,
        plan_order=plan_order,
    )
    program.rt.start()
    setup_s = time.perf_counter() - begin
    recorder = ScanRecorder(program)
    planner = time_planner(program)
    gc.collect()
    gc.freeze()  # plant, table and fleet are startup data: keep the collector off them
    begin = time.perf_counter()
    try:
        cycles = recorder.run(round(sim_s / cycle_time))
    finally:
        wall_s = time.perf_counter() - begin
        gc.unfreeze()
    rt = program.rt
    whole, control = recorder.arrays()
    simulated = cycles * cycle_time
    controls = program.controls.values()
    replans = sum(c.replans for c in controls)
    states: dict[str, int] = {}
    for c in controls:
        states[c.state] = states.get(c.state, 0) + 1
    out = {
        "vehicles": vehicles,
        "traffic": traffic,
        "rounds": program.traffic.rounds if program.traffic else None,
        "plant": f"{height}x{width}",
        "nodes": plant.n,
        "setup_s": setup_s,
        "state": rt.state,
        "fault": rt.fault_reason,
        "cycles": cycles,
        "sim_s": simulated,
        "wall_s": wall_s,
        "rtf": simulated / wall_s if wall_s else math.nan,
        "whole_us": [np.percentile(whole, q) / 1e3 for q in (50, 99)] + [whole.max() / 1e3],
        "control_us": [np.percentile(control, q) / 1e3 for q in (50, 99)] + [control.max() / 1e3],
        "planner_us": [np.percentile(planner, q) / 1e3 for q in (50, 99)] + [max(planner) / 1e3]
        if planner
        else None,
        "over_budget": int((control > cycle_time * 1e9).sum()),
        "over_watchdog": int((control > S7_WATCHDOG_S * 1e9).sum()),
        "replans_vh": replans / (vehicles * simulated / 3600) if simulated else math.nan,
        "tasks": program.completed.total,
        "head_on": program.monitor.head_on,
        "node": program.monitor.node,
        "events": list(program.monitor.events[:5]),
        "deadlocks": (
            program.resolver.detected,
            program.resolver.resolved,
            program.resolver.unresolved,
        ),
        "states": states,
    }
    program.close()
    return out


def time_planner(program: FleetProgram) -> list[int]:
    """The time-window planner block's own time per scan (ns, appended as the run goes; empty
    in reactive mode): the planning cost a scan pays, apart from the rest of the fleet's."""
    times: list[int] = []
    traffic = program.traffic
    if traffic is None:
        return times
    cycle = traffic.cycle

    def timed(ctx) -> None:
        begin = time.perf_counter_ns()
        cycle(ctx)
        times.append(time.perf_counter_ns() - begin)

    traffic.cycle = timed
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 16, 64, 256, 1000])
    parser.add_argument("--sim-seconds", type=float, default=300.0)
    parser.add_argument("--cycle-ms", type=float, default=50.0)
    parser.add_argument("--watchdog-ms", type=float, default=1000.0)
    parser.add_argument(
        "--traffic",
        choices=["reactive", "time_windows"],
        default="reactive",
        help="the fleet's traffic mode",
    )
    parser.add_argument(
        "--plan-budget",
        type=int,
        default=None,
        help="time_windows: search expansions per scan (default: the configuration's)",
    )
    parser.add_argument(
        "--window-s",
        type=float,
        default=None,
        help="time_windows: conflict window in seconds (default: the configuration's, none)",
    )
    parser.add_argument(
        "--plan-order",
        choices=PLAN_ORDERS,
        default=None,
        help="time_windows: who a round plans first (default: the configuration's, release)",
    )
    parser.add_argument(
        "--quick", action="store_true", help="reduced run: --sim-seconds 10 --sizes 4 16 64"
    )
    args = parser.parse_args()
    if args.quick:
        parser.set_defaults(**QUICK)
        args = parser.parse_args()
    sim_s = args.sim_seconds
    cycle = args.cycle_ms / 1e3
    begin = time.perf_counter()
    console = Console(width=max(Console().width, 170))
    console.print(
        f"Fleet program against fleet size, Python {sys.version.split()[0]}: {sim_s:g} simulated s "
        f"per size, cycle {args.cycle_ms:g} ms, timestep {timestep_s():g} s, "
        f"traffic {args.traffic}" + (f", plan order {args.plan_order}" if args.plan_order else "")
    )
    rows = []
    for n in args.sizes:
        r = run_size(
            n,
            sim_s,
            cycle,
            args.watchdog_ms / 1e3,
            args.traffic,
            args.plan_budget,
            args.window_s,
            args.plan_order,
        )
        rows.append(r)
        console.print(
            f"  {n} vehicles on {r['plant']} ({r['nodes']} nodes): setup {r['setup_s']:.1f} s, "
            f"run {r['wall_s']:.1f} s wall, state {r['state']}, final vehicle states {r['states']}"
        )

    base = next((r for r in rows if r["vehicles"] == min(args.sizes)), rows[0])
    base_per_vehicle = base["control_us"][0] / base["vehicles"]
    cost = Table(
        title=f"Scan cost against fleet size (cycle {args.cycle_ms:g} ms, {sim_s:g} simulated s)"
    )
    for name in (
        "vehicles",
        "plant (nodes)",
        "density",
        "scan p50 us",
        "scan p99 us",
        "scan max us",
        "control p50 us",
        "control p99 us",
        f"control p99 / {args.cycle_ms:g} ms",
        f"control > {args.cycle_ms:g} / > 150 ms",
        "control p50 us / vehicle",
        f"per vehicle / {base['vehicles']}-vehicle run",
    ):
        cost.add_column(name, justify="right")
    behaviour = Table(title="Behaviour against fleet size")
    for name in (
        "vehicles",
        "real-time factor",
        "wall s",
        "replans / vehicle-h",
        "tasks",
        "tasks / vehicle-h",
        "conflicts head-on/node",
        "deadlocks det/res/unres",
        "planning rounds",
        "planner p50 / p99 / max us",
        "state",
    ):
        behaviour.add_column(name, justify="right")
    for r in rows:
        per_vehicle = r["control_us"][0] / r["vehicles"]
        cost.add_row(
            str(r["vehicles"]),
            f"{r['plant']} ({r['nodes']:,})",
            f"{r['vehicles'] / r['nodes']:.1%}",
            f"{r['whole_us'][0]:,.0f}",
            f"{r['whole_us'][1]:,.0f}",
            f"{r['whole_us'][2]:,.0f}",
            f"{r['control_us'][0]:,.0f}",
            f"{r['control_us'][1]:,.0f}",
            f"{r['control_us'][1] / (cycle * 1e6):.1%}",
            f"{r['over_budget']} / {r['over_watchdog']}",
            f"{per_vehicle:,.1f}",
            f"{per_vehicle / base_per_vehicle:.2f}",
        )
        behaviour.add_row(
            str(r["vehicles"]),
            f"{r['rtf']:,.1f}",
            f"{r['wall_s']:,.1f}",
            f"{r['replans_vh']:,.0f}",
            str(r["tasks"]),
            f"{r['tasks'] / (r['vehicles'] * r['sim_s'] / 3600):,.1f}" if r["sim_s"] else "-",
            f"{r['head_on']}/{r['node']}",
            "/".join(str(x) for x in r["deadlocks"]),
            str(r["rounds"]) if r["rounds"] is not None else "-",
            " / ".join(f"{x:,.0f}" for x in r["planner_us"]) if r["planner_us"] else "-",
            r["state"] if r["fault"] is None else f"{r['state']}: {r['fault']}",
        )
    console.print(cost)
    console.print(behaviour)
    console.print(
        "scan = the runtime's whole-scan time (drivers + fleet program + co-simulated vehicles); "
        "control = scan minus the co-simulation task, scan by scan."
    )
    for r in rows:
        for e in r["events"]:
            console.print(f"  conflict with {r['vehicles']} vehicles: {e}")
    console.print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
