"""The route program: the heuristic-table and A* blocks in a runtime on the virtual clock.

Used by ``plc-runtime route``: it shows what the path-finding layer does on a PLC, cycle by
cycle, rather than calling a shortest-path function: the table is built in the startup
phase, the search runs ``budget`` expansions per cycle, the route appears when complete.
"""

from __future__ import annotations

from pathlib import Path

from blocks.routing.astar import IncrementalAStar
from blocks.routing.constraints import RoutingConstraints, highway_penalty
from blocks.routing.heuristic import HeuristicTable
from plc_runtime import ConfigError, CycleContext, FunctionBlock, Runtime, VirtualClock
from topology import SAMPLES, Plant, TopologyError, load

from .config import HIGHWAY_FACTOR


class RouteRequest(FunctionBlock):
    """Drives the A* inputs (request from the first scan on), as the sequencer above it would."""

    def __init__(self, astar: IncrementalAStar, start: int, goal: int, budget: int) -> None:
        super().__init__()
        self.astar, self.start_node, self.goal_node, self.budget = astar, start, goal, budget

    def cycle(self, ctx: CycleContext) -> None:
        astar = self.astar
        astar.start, astar.goal, astar.budget = self.start_node, self.goal_node, self.budget
        astar.request = True


def load_plant(name: str) -> Plant:
    """A plant file of any supported format, or the name of a sample plant."""
    path = Path(name)
    if not path.exists() and name in SAMPLES:
        return SAMPLES[name]()
    if not path.exists():
        raise TopologyError(f"no such file (and not a sample plant: {', '.join(SAMPLES)})", name)
    return load(path)


def parse_segment(text: str) -> tuple[int, int]:
    try:
        a, b = text.split("-")
        return int(a), int(b)
    except ValueError:
        raise ConfigError(f"--block {text!r}: expected two node ids like 7-8") from None


def find_route(
    plant: Plant,
    start: int,
    goal: int,
    budget: int = 1,
    blocked: list[tuple[int, int]] = (),
    heuristic: str = "table",
    cycle_time: float = 0.010,
    highway_factor: float = HIGHWAY_FACTOR,
) -> dict[str, object]:
    """The route the fleet's A* block finds, at ``budget`` expansions per cycle: priced as
    the fleet prices it, against highway lanes at ``highway_factor`` times their length."""
    for node, what in ((start, "--from"), (goal, "--to")):
        if node not in plant.index:
            raise ConfigError(f"{what} {node}: no such node in {plant.name}")
    if budget < 1:
        raise ConfigError(f"--budget must be >= 1, got {budget}")
    constraints = RoutingConstraints(plant)
    try:
        constraints.penalty[:] = highway_penalty(plant, highway_factor)
    except ValueError:
        raise ConfigError(
            f"--highway-factor must be a number >= 1, got {highway_factor:g}"
        ) from None
    for a, b in blocked:
        try:
            constraints.block(a, b)
        except TopologyError as exc:
            raise ConfigError(f"--block {a}-{b}: {exc}") from None
    table = HeuristicTable(plant, targets=[goal]) if heuristic == "table" else None
    astar = IncrementalAStar(plant, table, heuristic=heuristic, constraints=constraints)
    rt = Runtime(cycle_time=cycle_time, clock=VirtualClock())
    rt.add_task(
        "pathfinding",
        [b for b in (RouteRequest(astar, start, goal, budget), table, astar) if b is not None],
    )
    rt.start()
    try:
        finished = rt.run_until(lambda: astar.done, max_cycles=plant.n // budget + 10)
        if not finished:
            raise ConfigError(
                rt.fault_reason or "the search did not finish"
            )  # cannot happen: bounded by n
    finally:
        rt.stop()
    return {
        "plant": plant.name,
        "from": start,
        "to": goal,
        "route": list(astar.route),
        "cost": astar.cost,
        "expansions": astar.expansions,
        "cycles": astar.cycles,
        "no_route": astar.no_route,
        "budget": budget,
        "blocked": [list(s) for s in constraints.blocked_segments()],
        "heuristic": heuristic,
        "highway_factor": highway_factor,
        "table_build_ms": round(table.build_time_s * 1e3, 3) if table else None,
        "sim_time_s": round(rt.clock_time, 6),
    }
