"""RecipeSequencer: each vehicle works through its recipes, one function after another.

Thesis 4.5: a recipe is an ordered list of function ids (0 = plant entry, 1 = plant exit);
a function cluster lists the stations that provide a function. Per vehicle the sequencer
keeps the current step, the chosen station and the target it hands to the vehicle control.
At a station a TON waits the processing time (3 s by default, as in the thesis) while the
route to the next station is already computed; the route is released when the TON ends.
A recipe ending at the exit follows the return lane (not used by routing) back to the
entry, where the next recipe is assigned: endlessly, or for a set number of rounds.

Station choice within a cluster is a ``StationChooser`` shared by the fleet, so it can see
every vehicle's choices: ``random`` (seeded: the thesis' choice), ``round_robin``,
``least_utilised`` (fewest assignments so far), ``nearest`` (by the exact heuristic table),
``occupancy_aware`` (nearest among stations nobody stands at or heads for). Assignments,
visits and processing time per station are counted so the choice can be judged.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from blocks.routing.heuristic import HeuristicTable
from blocks.standard import TON
from plc_runtime import CycleContext, FunctionBlock, Input, Output, Static
from plc_runtime.recent import RecentList
from topology import Plant

# finished recipe runs kept (recipes.csv, scripts): ~10,000 are days of a busy fleet's
# work and a few MB; a controller running for months would otherwise grow with every run.
# How many finished over the whole run is the list's ``total``.
RUNS_KEPT = 10_000

STRATEGIES = ("random", "round_robin", "least_utilised", "nearest", "occupancy_aware")
ENTRY, EXIT = 0, 1


@dataclass(frozen=True)
class Recipe:
    name: str
    functions: tuple[int, ...]


@dataclass
class Section:
    """One step of a recipe as it happened: times in simulated seconds."""

    step: int
    function: int
    station: int
    dispatched_s: float
    arrived_s: float | None = None
    done_s: float | None = None


@dataclass
class RecipeRun:
    vehicle: int
    recipe: str
    round: int
    started_s: float
    sections: list[Section] = field(default_factory=list)
    finished_s: float | None = None


class StationChooser:
    def __init__(
        self,
        plant: Plant,
        clusters: Mapping[int, Sequence[int]],
        strategy: str = "random",
        table: HeuristicTable | None = None,
        seed: int = 0,
    ) -> None:
        if strategy not in STRATEGIES:
            raise ValueError(
                f"station strategy must be one of {', '.join(STRATEGIES)}, got {strategy!r}"
            )
        if strategy in ("nearest", "occupancy_aware") and table is None:
            raise ValueError(f"station strategy {strategy!r} needs the heuristic table")
        self.plant = plant
        self.clusters = {f: sorted(stations) for f, stations in clusters.items()}
        self.strategy = strategy
        self.table = table
        self.rng = np.random.default_rng(seed)
        self._turn = dict.fromkeys(self.clusters, 0)
        stations = sorted({s for group in self.clusters.values() for s in group})
        self.assigned = dict.fromkeys(stations, 0)
        self.visits = dict.fromkeys(stations, 0)
        self.busy_s = dict.fromkeys(stations, 0.0)

    def choose(self, function: int, from_node: int, taken: Callable[[int], bool]) -> int:
        """A station for ``function``; ``taken(station)`` tells whether another vehicle
        stands at it or heads for it (used by ``occupancy_aware`` only)."""
        group = self.clusters.get(function)
        if not group:
            raise KeyError(f"no station provides function {function}")
        if self.strategy == "random":
            station = group[int(self.rng.integers(len(group)))]
        elif self.strategy == "round_robin":
            station = group[self._turn[function] % len(group)]
            self._turn[function] += 1
        elif self.strategy == "least_utilised":
            station = min(group, key=lambda s: (self.assigned[s], s))
        else:
            candidates = group
            if self.strategy == "occupancy_aware":
                candidates = [s for s in group if not taken(s)] or group
            station = min(
                candidates, key=lambda s: (self._distance(from_node, s), self.assigned[s], s)
            )
        self.assigned[station] += 1
        return station

    def _distance(self, node: int, station: int) -> float:
        d = self.table.distance(node, station)
        return float("inf") if d is None else d

    def utilisation(self, sim_time_s: float) -> dict[str, dict[str, float | int]]:
        """Per station: assignments, visits, processing seconds, and the busy fraction."""
        return {
            str(s): {
                "assigned": self.assigned[s],
                "visits": self.visits[s],
                "busy_s": round(self.busy_s[s], 3),
                "utilisation": round(self.busy_s[s] / sim_time_s, 4) if sim_time_s > 0 else 0.0,
            }
            for s in self.assigned
        }


class RecipeSequencer(FunctionBlock):
    arrived = Input(False, doc="the vehicle control reports: at the target, nothing left to drive")
    current = Input(None, doc="the node the vehicle last reported")

    target = Output(None, doc="the node the vehicle should drive to")
    fixed_route = Output(None, doc="the return lane to drive instead of a planned route")
    hold = Output(False, doc="TRUE while processing: the next route waits for the timer")
    phase = Output("start", doc="start|to_station|processing|returning|done")
    step = Output(0, doc="index of the current step in the recipe")
    recipe_name = Output("")
    rounds_done = Output(0)
    stations_visited = Output(0)
    priority_ns = Output(0, doc="when the current step was dispatched: older goes first")

    recipe_index = Static(0)
    run = Static(None)
    processing_at = Static(None)

    def __init__(
        self,
        vehicle: int,
        plant: Plant,
        recipes: Sequence[Recipe],
        chooser: StationChooser,
        taken: Callable[[int], bool],
        processing_s: Mapping[int, float] | float = 3.0,
        rounds: int = 0,
        first_recipe: int = 0,
        completed: RecentList[RecipeRun] | None = None,
    ) -> None:
        super().__init__()
        if not recipes:
            raise ValueError(f"vehicle {vehicle}: no recipes")
        self.vehicle = vehicle
        self.plant = plant
        self.recipes = list(recipes)
        self.chooser = chooser
        self.taken = taken
        self.processing_s = processing_s
        self.rounds = rounds
        self.recipe_index = first_recipe % len(self.recipes)
        # finished runs, the newest RUNS_KEPT (shared by the fleet's sequencers)
        self.completed = completed if completed is not None else RecentList(RUNS_KEPT)
        self.timer = TON()
        self.return_lanes = return_lanes(plant)

    def _processing(self, function: int) -> float:
        if isinstance(self.processing_s, Mapping):
            return float(self.processing_s.get(function, 0.0))
        return 0.0 if function in (ENTRY, EXIT) else float(self.processing_s)

    # ----- the scan --------------------------------------------------------------------------
    def cycle(self, ctx: CycleContext) -> None:
        if self.current is None:
            return
        if self.phase == "start":
            self._begin_recipe(ctx)
        elif self.phase == "to_station":
            if self.arrived and self.current == self.target:
                self._at_station(ctx)
        elif self.phase == "processing":
            at = self.processing_at
            if self.timer(ctx, IN=True, PT=self._processing(at.function)):
                self.timer(ctx, IN=False)
                at.done_s = ctx.time
                self.chooser.busy_s[at.station] += self._processing(at.function)
                self.hold, self.processing_at = False, None
                self.phase = "to_station"
                self._after_section(ctx)
        elif self.phase == "returning":
            if self.arrived and self.current == self.fixed_route[-1]:
                self.fixed_route = None
                self._next_round(ctx)

    def _begin_recipe(self, ctx: CycleContext) -> None:
        recipe = self.recipes[self.recipe_index]
        self.run = RecipeRun(self.vehicle, recipe.name, self.rounds_done + 1, ctx.time)
        self.recipe_name, self.step = recipe.name, 0
        self._dispatch(ctx, 0)

    def _dispatch(self, ctx: CycleContext, step: int) -> None:
        """Choose the station of ``step`` and make it the target."""
        function = self.recipes[self.recipe_index].functions[step]
        station = self.chooser.choose(function, self.current, self.taken)
        self.run.sections.append(Section(step, function, station, ctx.time))
        self.target = station
        self.priority_ns = ctx.time_ns
        if self.phase != "processing":
            self.phase = "to_station"

    def _has_next(self) -> bool:
        return self.step + 1 < len(self.recipes[self.recipe_index].functions)

    def _at_station(self, ctx: CycleContext) -> None:
        section = self.run.sections[-1]
        section.arrived_s = ctx.time
        if section.station in self.chooser.visits:
            self.chooser.visits[section.station] += 1
        self.stations_visited += 1
        if self._processing(section.function) > 0:
            self.phase, self.hold, self.processing_at = "processing", True, section
            self.timer(ctx, IN=True, PT=self._processing(section.function))
            if self._has_next():
                # the next route is computed during the processing time (thesis 4.5)
                self._dispatch(ctx, self.step + 1)
        else:
            section.done_s = ctx.time
            self._after_section(ctx)

    def _after_section(self, ctx: CycleContext) -> None:
        if not self._has_next():
            self._finish_recipe(ctx)
            return
        self.step += 1
        if self.run.sections[-1].step != self.step:  # not dispatched during processing
            self.phase = "to_station"
            self._dispatch(ctx, self.step)
        else:
            self.phase = "to_station"

    def _finish_recipe(self, ctx: CycleContext) -> None:
        self.run.finished_s = ctx.time
        self.completed.append(self.run)
        self.rounds_done += 1
        lane = self.return_lanes.get(self.current)
        if lane is not None:
            self.fixed_route, self.target, self.phase = lane, lane[-1], "returning"
            return
        self._next_round(ctx)

    def _next_round(self, ctx: CycleContext) -> None:
        self.recipe_index = (self.recipe_index + 1) % len(self.recipes)
        if self.rounds and self.rounds_done >= self.rounds:
            self.phase, self.target = "done", None
            return
        self._begin_recipe(ctx)


def return_lanes(plant: Plant) -> dict[int, tuple[int, ...]]:
    """For each exit: the node ids of its return lane to an entry, over non-routable
    segments only (the thesis' static route back), if it has one."""
    out_edges: dict[int, list[int]] = {}
    for e in plant.edges:
        if not e.routable:
            out_edges.setdefault(e.source, []).append(e.target)
            if e.bidirectional:
                out_edges.setdefault(e.target, []).append(e.source)
    lanes = {}
    for exit_node in plant.with_role("exit"):
        paths = {exit_node: (exit_node,)}
        frontier = [exit_node]
        while frontier:
            node = frontier.pop(0)
            if plant.node(node).role == "entry" and node != exit_node:
                lanes[exit_node] = paths[node]
                break
            for nxt in out_edges.get(node, []):
                if nxt not in paths:
                    paths[nxt] = paths[node] + (nxt,)
                    frontier.append(nxt)
    return lanes
