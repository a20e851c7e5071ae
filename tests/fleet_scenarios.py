"""Helpers for fleet tests: build a fleet program from TOML text, step it on the virtual clock
and check the invariants after every cycle (from the independent monitor: no head-on, node
or single-vehicle area conflict; and from the blocks)."""

from __future__ import annotations

from dataclasses import dataclass, field

from fleet.config import FleetConfig, parse_config
from fleet.program import FleetProgram

# The smallest fleet job: vehicle 1 drilling on the thesis's model plant (add to it).
ONE_DRILL = """
[plant]
sample = "model-plant"
[[recipes]]
name = "drill"
functions = [2, 1]
[[vehicles]]
id = 1
start = 0
"""


def config(text: str) -> FleetConfig:
    return parse_config(text, "test.toml")


@dataclass
class Trace:
    """What happened, cycle by cycle: segments driven (with the time they were entered)."""

    entered: list[tuple[float, int, int, int]] = field(default_factory=list)  # t, vehicle, a, b
    max_expansions: int = 0

    def segments(self, vehicle: int | None = None) -> list[tuple[int, int]]:
        return [(a, b) for _t, v, a, b in self.entered if vehicle in (None, v)]


def run(program: FleetProgram, seconds: float, check_every_cycle: bool = True) -> Trace:
    """Run ``seconds`` of simulated time; after every cycle assert zero conflicts (head-on,
    node, area) and the A* budget, and record every segment a vehicle enters (from the
    simulated vehicles)."""
    rt = program.rt
    if rt.state != "RUN":
        rt.start()
    trace = Trace()
    on = {}
    budget = program.cfg.astar_budget
    cycles = round(seconds / program.cfg.cycle_time)
    for _ in range(cycles):
        rt.step()
        assert rt.state == "RUN", rt.stats.to_dict()["fault_reason"]
        for fleet, offset in zip(program.fleets, program.monitor.offsets, strict=True):
            for v, agv in fleet.vehicles.items():
                seg = (agv.node, agv.target) if agv.target is not None else None
                if seg is not None and on.get(v + offset) != seg:
                    trace.entered.append((round(fleet.time, 3), v + offset, *seg))
                on[v + offset] = seg
        if check_every_cycle:
            assert program.monitor.head_on == 0, program.monitor.events
            assert program.monitor.node == 0, program.monitor.events
            assert program.monitor.area == 0, program.monitor.events
            for c in program.controls.values():
                trace.max_expansions = max(trace.max_expansions, c.astar.expansions_last_cycle)
                assert c.astar.expansions_last_cycle <= budget
    # every report was along the reporting vehicle's holds (positions are known before
    # anything is released, and every move is a granted one): nobody became suspect
    assert program.reservation.refused_reports == 0
    assert not any(c.suspect_events for c in program.controls.values())
    return trace


def visited_functions(program: FleetProgram, vehicle: int) -> list[tuple[str, list[int]]]:
    """(recipe, functions in the order they were visited) of the vehicle's completed recipes."""
    return [
        (r.recipe, [s.function for s in r.sections])
        for r in program.completed
        if r.vehicle == vehicle
    ]


def make_config(plant, starts, recipes, clusters, vehicle_recipes=None, **settings) -> FleetConfig:
    """A FleetConfig built in code (recipes: name -> function ids)."""
    from blocks.jobs.recipe import Recipe

    names = list(recipes)
    # tests measure behaviour, not wall time: a slow CI machine must not trip the watchdog
    settings.setdefault("watchdog", 5.0)
    return FleetConfig(
        source="test",
        plant=plant,
        starts=dict(starts),
        recipes={n: Recipe(n, tuple(f)) for n, f in recipes.items()},
        vehicle_recipes=vehicle_recipes or {v: names for v in starts},
        clusters={f: list(s) for f, s in clusters.items()},
        **settings,
    )
