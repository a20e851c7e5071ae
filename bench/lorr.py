"""League of Robot Runners 2023: our traffic planners on the competition's model.

Reads an instance of ``../shared/data/lorr2023/`` (its README: map, agents, tasks, round-robin
assignment, the MAPF_T action model: each timestep a robot moves forward one cell, turns 90
degrees or waits), runs ``--steps`` timesteps and writes the competition's output JSON
(``actionModel``, ``AllValid``, ``teamSize``, ``start``, ``numTaskFinished``, ``sumOfCost``,
``makespan``, ``actualPaths`` as F/R/C/W strings, ``plannerTimes``, ``errors``, ``events``,
``tasks``), which any validator of the competition can replay. tests/test_lorr.py replays it
with its own rules and recounts tasks and conflicts.

``--traffic time_windows`` (the default) is the time-window planner of the fleet
(``blocks/traffic``):
safe-interval search over (cell, heading) through a time-window table, with the model's
timing: a move and a quarter turn take one timestep, a U-turn two, and a gap of one timestep
(a robot may follow another into the cell it leaves, as the rules allow; never two in a
cell, never a swap). Plans are prioritised by task release: a robot plans when its task is
revealed, through the windows of every plan made before, and keeps its plan.

A robot without a plan stands still with a window that never ends on its cell, so nobody
plans through it. A plan, though, books its goal only for ``--stay-s`` timesteps after the
arrival (3 by default): the robot gets its next task there and plans on at once, so others
need not route round the cell for ever. If someone has booked the cell after that, the
robot plans first; if it still finds no plan, it is made safe where it stands and every
plan booked through its cell is void, those robots stand where they are (made safe the same
way) and plan again. Robots stand on cells of their own, so this ends, and no plan ever
crosses a cell where a robot stands without one: safety does not depend on the search
succeeding. A robot that finds no plan tries again next timestep, the one standing on its
goal without a plan steps aside to the nearest cell it can reach and keep, and so does a
robot after three failures. The simulator executes actions exactly, so plans run by time
here; on real vehicles the fleet executes them by order (``PassOrder``).

Planning stops for the timestep once ``--plan-budget`` search expansions are used (the
robots left plan next timestep), so a step's planning work stays bounded, as the
competition's 1 s limit demands. The budget counts work, not seconds, so a run gives the
same result on any machine; ``plannerTimes`` records the seconds each step took here.

``--traffic one_step`` plans one timestep at a time by priority inheritance
(``blocks/traffic/one_step.py``, PIBT): no plans, so nothing to fail or void, and a
step's work is bounded by the robots times their cells' degree. A robot's urgency is the
time since its task was revealed.

``--follow next_step`` forbids what the competition allows, driving into a cell in the step
its robot leaves it: a cell is entered a step after it was left at the earliest, which is
what our vehicles' reservations amount to (a node is released once the vehicle ahead has
cleared it). It measures what that rule costs a fleet.

``--kiva 60 100 140`` runs RHCR's kiva map (``topology.kiva``) in the same model instead of
the instances: starts on distinct free cells and tasks uniform over its 480 endpoints,
drawn per seed (``--seeds``), beside RHCR's published tasks per timestep (unit moves
too, but no turns).

    .venv/bin/python bench/lorr.py [INSTANCE.json] [--steps N] [--traffic time_windows one_step]
        [--follow same_step|next_step] [--kiva ROBOTS ...] [--seeds 0 1 2]
        [--out result.json] [--plan-budget 40000] [--stay-s 3] [--data DIR] [--quick]

Without INSTANCE: the README's three random-32-32-20 instances and the three warehouse_small
ones, with the steps of the README (500 / 500 / 1000 and 500), printed as a table beside the
published best-known figures (``--quick``: 100 robots, 50 steps each). The instances are
read from ``--data`` (default ``../shared/data/lorr2023`` beside the clone); where that is
missing, ``--quick`` runs on the one instance the repository keeps for its tests.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import math
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from blocks.routing.heuristic import distances_to  # noqa: E402
from blocks.traffic.one_step import OneStepPlanner  # noqa: E402
from blocks.traffic.sipp import ArcGeometry, SafeIntervalSearch, TurnTimes  # noqa: E402
from blocks.traffic.time_windows import TimeWindowTable, WindowConflict  # noqa: E402
from plc_runtime.cli import non_negative, one_line, positive, whole  # noqa: E402
from topology import Plant, read_cells  # noqa: E402
from topology.grid import grid_plant  # noqa: E402
from topology.samples import KIVA_HEIGHT, KIVA_WIDTH, kiva  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "lorr2023"  # the full set, beside the clone
TEST_DATA = ROOT / "tests" / "data" / "lorr2023"  # one instance kept in the repository
HEADINGS = ((1, 0), (0, 1), (-1, 0), (0, -1))  # E, S, W, N as (dx, dy), y down: clockwise
NAMES = "ESWN"
TURNS = TurnTimes(1.0, 2.0)
GAP = 1.0
FAILS_BEFORE_STEPPING_ASIDE = 3
PLAN_BUDGET = 40_000  # search expansions per timestep: well under 1 s here (see plannerTimes)
SEARCH_CAP = 4_000  # expansions of one search: one that needs more counts as failed for now
# best known tasks finished, 2023 main round (README of the data)
PUBLISHED = {("random-32-32-20", 100, 500): 1741, ("random-32-32-20", 200, 500): 3042}
PUBLISHED[("random-32-32-20", 400, 1000)] = 7432
# RHCR (Li et al., AAAI 2021) on its kiva map, tasks per timestep: windowed PBS, unit moves
# without turns, 5000 timesteps
KIVA_RHCR = {60: 2.33, 100: 3.56, 140: 4.55}
KIVA_STEPS = 500
RUNS = (  # (instance, robots, timesteps)
    ("random/EI23-random_100.json", 100, 500),
    ("random/EI23-random_200.json", 200, 500),
    ("random/EI23-random_400.json", 400, 1000),
    ("warehouse_small/EI23-warehouse_small_60.json", 60, 500),
    ("warehouse_small/EI23-warehouse_small_100.json", 100, 500),
    ("warehouse_small/EI23-warehouse_small_200.json", 200, 500),
)


class InstanceError(ValueError):
    """An instance file that cannot be read: names the file and what is wrong."""


@dataclass
class Instance:
    name: str
    passable: np.ndarray
    starts: list[int]
    tasks: list[int]
    team: int


def read_instance(path: Path) -> Instance:
    """The instance at ``path``, checked: a bad one stops here with one line naming the
    file and what is wrong, not with a traceback or a run that cannot end (robots sharing a
    start cell would make the planner void plans for ever, each waiting for the other)."""
    try:
        spec = json.loads(path.read_text())
        if not isinstance(spec, dict):
            raise ValueError("not a JSON object")
        for key in ("mapFile", "agentFile", "taskFile", "teamSize"):
            if key not in spec:
                raise ValueError(f"missing key {key!r}")
        base = path.parent
        passable = read_cells(base / spec["mapFile"])
        starts = read_locations(base / spec["agentFile"])
        tasks = read_locations(base / spec["taskFile"])
    except (OSError, ValueError, TypeError) as e:
        raise InstanceError(f"{path}: {e}") from e
    team = spec["teamSize"]
    if type(team) is not int or team < 1:  # not isinstance: a bool is an int
        raise InstanceError(f"{path}: teamSize must be a whole number >= 1, got {json.dumps(team)}")
    if spec.get("taskAssignmentStrategy", "roundrobin") != "roundrobin":
        raise InstanceError(f"{path}: only roundrobin task assignment is modelled")
    if len(starts) < team:
        raise InstanceError(
            f"{path}: teamSize {team}, but {spec['agentFile']} gives {len(starts)} starts"
        )
    if not tasks:
        raise InstanceError(f"{path}: {spec['taskFile']} lists no tasks")
    cells = passable.size
    for what, locations in (("start", starts), ("task", tasks)):
        for k, loc in enumerate(locations):
            if not (0 <= loc < cells and passable.flat[loc]):
                raise InstanceError(f"{path}: {what} {k} at {loc} is not a free cell of the map")
    robot_at: dict[int, int] = {}
    for k, loc in enumerate(starts[:team]):
        if loc in robot_at:
            raise InstanceError(f"{path}: start {k} at {loc} is also robot {robot_at[loc]}'s start")
        robot_at[loc] = k
    return Instance(Path(spec["mapFile"]).stem, passable, starts[:team], tasks, team)


def read_locations(path: Path) -> list[int]:
    try:
        values = [int(v) for v in path.read_text().split()]
    except ValueError:
        values = []  # not whole numbers: the same error
    if not values or not 0 <= values[0] <= len(values) - 1:
        raise ValueError(f"{path}: the first number is the count, then that many locations")
    return values[1 : 1 + values[0]]


@dataclass
class Robot:
    id: int
    node: int
    heading: int  # index into HEADINGS
    task: int  # the task cell it works on
    task_index: int  # index into the task list
    nodes: list[int] = field(default_factory=list)  # plan: cells, arrive, depart times
    arrive: list[float] = field(default_factory=list)
    depart: list[float] = field(default_factory=list)
    step: int = 0  # index in the plan of the cell it is at
    fails: int = 0
    replan: bool = False  # plan again once the current plan has ended
    aside: int | None = None  # the cell it steps aside to, when it does


class TimeWindowTraffic:
    """Lifelong prioritised time-window planning with the fleet's table and search."""

    def __init__(
        self, plant: Plant, budget: int, stay_s: float = math.inf, follow: bool = True
    ) -> None:
        self.plant, self.budget, self.stay_s = plant, budget, stay_s
        # the competition's rule: follow into the cell another leaves in the same step (a
        # window begins on arrival); else a cell is entered a step after it was left at the
        # earliest (a window begins when the robot sets off towards the cell)
        self.claim = "arrival" if follow else "departure"
        self.used = 0  # search expansions this timestep
        self.urgent: set[int] = set()  # robots whose stay ends: they plan first
        self.voided = 0  # plans released to make a robot without a plan safe
        self.table = TimeWindowTable(GAP)
        self.geometry = ArcGeometry(plant)
        self._rows: dict[int, np.ndarray] = {}  # goal -> distances of every cell to it
        self.queue: deque[int] = deque()  # robots waiting for a plan, by task release
        self.waiting: set[int] = set()  # the same, as a set
        self.searches = self.failures = self.asides = 0

    def stay(self, r: Robot, now: float) -> bool:
        """Stand still on the cell until the next plan, with a window that never ends; False
        if someone is booked through the cell later (the plan's stay there was bounded):
        then it keeps its bounded stay and must plan away before it ends."""
        try:
            self.table.book(r.id, [(r.node, now, math.inf)], [])
        except WindowConflict:
            self.urgent.add(r.id)
            return False
        r.nodes, r.arrive, r.depart, r.step = [r.node], [now], [math.inf], 0
        return True

    def plan(self, robots: list[Robot], now: float) -> None:
        """Plan the waiting robots, those whose stay ends first, then first released first.
        One that fails is tried again in the same timestep once others have planned (the
        robot standing on its goal may have left by then), while a pass over the queue gets
        someone a plan and the budget lasts. Then every robot still without a plan is made
        safe where it stands (:meth:`_secure`)."""
        self.table.expire(now)
        if self.urgent:
            first = [rid for rid in self.queue if rid in self.urgent]
            self.queue = deque(first + [rid for rid in self.queue if rid not in self.urgent])
        progress = True
        self.used = 0
        while progress and self.queue and self.used < self.budget:
            progress = False
            for _ in range(len(self.queue)):
                if self.used >= self.budget:
                    break
                r = robots[self.queue.popleft()]
                if self._search(r, r.aside if r.aside is not None else r.task, now):
                    r.fails, progress = 0, True
                    self.waiting.discard(r.id)
                    self.urgent.discard(r.id)
                else:
                    self.queue.append(r.id)
        for rid in [rid for rid in self.queue if rid in self.urgent]:
            self._secure(robots, robots[rid], now)
        standing = {robots[rid].node: rid for rid in self.queue}
        for rid in list(self.queue):  # still without a plan this timestep
            r = robots[rid]
            r.fails += 1
            self.failures += 1
            if self.used >= self.budget:
                continue
            goal = r.aside if r.aside is not None else r.task
            holder = standing.get(goal)
            if holder is not None and holder != rid and holder in self.waiting:
                self._step_aside(robots[holder], now)  # it stands, planless, on r's goal
            elif r.fails >= FAILS_BEFORE_STEPPING_ASIDE:
                self._step_aside(r, now)

    def _secure(self, robots: list[Robot], r: Robot, now: float) -> None:
        """Give ``r`` a window that never ends on its cell. A plan booked through that cell
        later is void: that robot stands where it is now, made safe the same way, and plans
        again. Every robot stands on a cell of its own, so this ends, and afterwards no plan
        crosses a cell where a robot stands without one."""
        stack = [r]
        while stack:
            x = stack.pop()
            if self.stay(x, now):
                self.urgent.discard(x.id)
                continue
            for v in {w.vehicle for w in self.table.node_windows(x.node) if w.vehicle != x.id}:
                self.table.release(v)
                self.voided += 1
                y = robots[v]
                stack.append(y)
                if v not in self.waiting:
                    self.waiting.add(v)
                    self.queue.append(v)
            stack.append(x)

    def _step_aside(self, r: Robot, now: float) -> None:
        if r.aside is not None:
            return
        r.aside = self._aside(r, now)
        if r.aside is not None:
            self.asides += 1
            self.waiting.discard(r.id)
            self.urgent.discard(r.id)
            self.queue.remove(r.id)

    def _to(self, goal: int) -> np.ndarray:
        """Distances of every cell to ``goal``: one Dijkstra per task cell, not per search
        (robots search for the same cells again and again)."""
        row = self._rows.get(goal)
        if row is None:
            row = self._rows[goal] = distances_to(self.plant, [goal])[0]
        return row

    def _search(self, r: Robot, goal: int, now: float) -> bool:
        self.searches += 1
        s = SafeIntervalSearch(
            self.plant,
            self.table,
            r.id,
            r.node,
            goal,
            now,
            speed=1.0,
            heading=HEADINGS[r.heading],
            turns=TURNS,
            claim=self.claim,
            hold_s=self.stay_s if goal == r.task else math.inf,
            to_goal=self._to(goal),
            geometry=self.geometry,
        )
        s.step(min(SEARCH_CAP, max(self.budget - self.used, 1)))
        self.used += s.expansions
        if s.plan is None:  # no path, or none found within the cap: it fails for now
            return False
        s.plan.book(self.table)
        r.nodes, r.arrive, r.depart = list(s.plan.nodes), list(s.plan.arrive), list(s.plan.depart)
        r.step = 0
        return True

    def _aside(self, r: Robot, now: float) -> int | None:
        """The nearest cell (breadth-first) it can reach and stay on for good."""
        seen, frontier = {r.node}, deque([r.node])
        tried = 0
        while frontier and tried < 8:
            n = frontier.popleft()
            for v, _, _ in self.plant.neighbors[self.plant.idx(n)]:
                cell = int(self.plant.ids[v])
                if cell in seen:
                    continue
                seen.add(cell)
                frontier.append(cell)
                if self.table.safe_intervals(cell, r.id)[-1][1] == math.inf:
                    tried += 1
                    if self._search(r, cell, now):
                        return cell
        return None


def heading(a: int, b: int, width: int) -> int:
    """Index into HEADINGS of the way from cell ``a`` to its neighbour ``b``."""
    return HEADINGS.index(((b % width) - (a % width), (b // width) - (a // width)))


def finish(r: Robot, t: int, instance: Instance, events: list) -> None:
    """``r`` stands on its task's cell at timestep t: the task is finished, and the next one
    of its round-robin share is revealed to it."""
    events.append([r.task_index, t, "finished", r.id])
    r.task_index += instance.team
    r.task = instance.tasks[r.task_index % len(instance.tasks)]
    events.append([r.task_index, t, "assigned", r.id])


def last_finishes(robots: list[Robot], steps: int, events: list) -> int:
    """Tasks finished by standing on their cells after the last timestep."""
    done = [r for r in robots if r.node == r.task]
    events.extend([r.task_index, steps, "finished", r.id] for r in done)
    return len(done)


def action(r: Robot, t: int, width: int) -> str:
    """The robot's action for timestep t -> t+1 from its plan: turn as late as the plan
    allows, set off at the planned departure, else wait."""
    if r.step + 1 >= len(r.nodes):
        return "W"
    a, b = r.nodes[r.step], r.nodes[r.step + 1]
    want = heading(a, b, width)
    depart = round(r.depart[r.step])
    if t == depart:
        if want != r.heading:
            raise AssertionError(f"robot {r.id} sets off at {t} facing {NAMES[r.heading]}")
        return "F"
    quarter_turns = min((want - r.heading) % 4, (r.heading - want) % 4)
    if want != r.heading and t >= depart - quarter_turns:
        return "R" if (want - r.heading) % 4 in (1, 2) else "C"
    return "W"


def conflicts(robots: list[Robot], before: dict[int, int], t: int) -> list[list]:
    """The competition's errors of timestep t: two robots in one cell, two swapping cells
    ([robot, robot, timestep, kind])."""
    out = []
    at: dict[int, int] = {}
    for r in robots:
        if r.node in at:
            out.append([at[r.node], r.id, t + 1, "vertex conflict"])
        at[r.node] = r.id
    for r in robots:
        other = at.get(before[r.id])
        if other is not None and other > r.id and before[other] == r.node != before[r.id]:
            out.append([r.id, other, t + 1, "edge conflict"])
    return out


def run(
    instance: Instance, steps: int, budget: int, stay_s: float = math.inf, follow: bool = True
) -> dict:
    width = instance.passable.shape[1]
    plant = grid_plant(instance.passable, 1.0, name=instance.name)
    traffic = TimeWindowTraffic(plant, budget, stay_s, follow)
    tasks = instance.tasks
    robots = [Robot(i, s, 0, tasks[i % len(tasks)], i) for i, s in enumerate(instance.starts)]
    paths: list[list[str]] = [[] for _ in robots]
    events, planner_times, errors = [], [], []
    finished = 0
    for r in robots:
        traffic.stay(r, 0.0)
        events.append([r.task_index, 0, "assigned", r.id])
        r.replan = True
    for t in range(steps):
        for r in robots:
            if r.node == r.task:  # standing on it finishes it, passing through included
                finished += 1
                finish(r, t, instance, events)
                r.replan = True
            if r.step + 1 >= len(r.nodes):  # its plan has ended: a new one from here
                if r.aside is not None and r.node == r.aside:
                    r.aside, r.replan = None, True
                if r.replan and r.id not in traffic.waiting:
                    traffic.stay(r, float(t))
                    traffic.queue.append(r.id)
                    traffic.waiting.add(r.id)
                r.replan = False
        begin = time.perf_counter()
        traffic.plan(robots, float(t))
        planner_times.append(time.perf_counter() - begin)
        before = {r.id: r.node for r in robots}
        for r in robots:
            a = action(r, t, width)
            paths[r.id].append(a)
            if a == "F":
                r.step += 1
                r.node = r.nodes[r.step]
            elif a == "R":
                r.heading = (r.heading + 1) % 4
            elif a == "C":
                r.heading = (r.heading - 1) % 4
        errors.extend(conflicts(robots, before, t))
    finished += last_finishes(robots, steps, events)
    stats = {
        "searches": traffic.searches,
        "failures": traffic.failures,
        "asides": traffic.asides,
        "voided": traffic.voided,
    }
    return output(instance, steps, paths, planner_times, errors, events, finished, stats)


def run_one_step(instance: Instance, steps: int, follow: bool = True) -> dict:
    """The same rules, planned one timestep at a time by priority inheritance
    (:class:`OneStepPlanner`): a robot's urgency is the timesteps since its task was
    revealed (ties by robot number), so the one that has waited longest goes first."""
    width = instance.passable.shape[1]
    plant = grid_plant(instance.passable, 1.0, name=instance.name)
    planner = OneStepPlanner(plant, speed=1.0, turns=TURNS, step_s=1.0, follow=follow)
    to = functools.cache(planner.distances)  # robots head for the same cells again and again
    tasks = instance.tasks
    team = instance.team
    robots = [Robot(i, s, 0, tasks[i % len(tasks)], i) for i, s in enumerate(instance.starts)]
    since = [0] * team  # the timestep each robot's task was revealed
    paths: list[list[str]] = [[] for _ in robots]
    events, planner_times, errors = [], [], []
    events.extend([r.task_index, 0, "assigned", r.id] for r in robots)
    finished = stayed = 0
    for t in range(steps):
        for r in robots:
            if r.node == r.task:
                finished += 1
                finish(r, t, instance, events)
                since[r.id] = t
        begin = time.perf_counter()
        moves = planner.step(
            [plant.idx(r.node) for r in robots],
            [HEADINGS[r.heading] for r in robots],
            [to(r.task) for r in robots],
            [t - since[i] + i / team for i in range(team)],
        )
        planner_times.append(time.perf_counter() - begin)
        before = {r.id: r.node for r in robots}
        for r, m in zip(robots, moves, strict=True):
            node = int(plant.ids[m.node])
            if node != r.node:
                want = heading(r.node, node, width)
                if want != r.heading:
                    raise AssertionError(f"robot {r.id} drives off facing {NAMES[r.heading]}")
                a = "F"
                r.node = node
            else:
                turn = m.turn(HEADINGS[r.heading])
                a = "R" if turn > 0 else "C" if turn < 0 else "W"
                r.heading = (r.heading + turn) % 4
                stayed += a == "W"
            paths[r.id].append(a)
        errors.extend(conflicts(robots, before, t))
    finished += last_finishes(robots, steps, events)
    stats = {"searches": 0, "failures": 0, "asides": 0, "voided": 0, "waits": stayed}
    return output(instance, steps, paths, planner_times, errors, events, finished, stats)


def output(instance, steps, paths, planner_times, errors, events, finished, stats) -> dict:
    """The competition's output JSON, and our own counts under ``_stats``."""
    width = instance.passable.shape[1]
    tasks = instance.tasks
    return {
        "actionModel": "MAPF_T",
        "AllValid": "No" if errors else "Yes",
        "teamSize": instance.team,
        "start": [[s // width, s % width, "E"] for s in instance.starts],
        "numTaskFinished": finished,
        "sumOfCost": sum(sum(1 for a in p if a != "W") for p in paths),
        "makespan": steps,
        "actualPaths": [",".join(p) for p in paths],
        "plannerPaths": [",".join(p) for p in paths],
        "plannerTimes": planner_times,
        "errors": errors,
        "events": [[e[:3] for e in events if e[3] == k] for k in range(instance.team)],
        "tasks": [[k, loc // width, loc % width] for k, loc in enumerate(tasks)],
        "_stats": {**stats, "conflicts": len(errors)},
    }


TRAFFIC = ("time_windows", "one_step")
FOLLOW = {"same_step": True, "next_step": False}


def solve(traffic: str, instance: Instance, steps: int, args: argparse.Namespace) -> dict:
    follow = FOLLOW[args.follow]
    if traffic == "one_step":
        return run_one_step(instance, steps, follow)
    return run(instance, steps, args.plan_budget, args.stay_s, follow)


def kiva_instance(robots: int, seed: int) -> Instance:
    """RHCR's kiva map (``topology.kiva``, cell for cell) in the competition's model: starts
    on distinct free cells and tasks uniform over its 480 endpoints, both drawn with
    ``seed``; robots take the tasks round-robin, as in the competition."""
    plant = kiva()
    passable = np.zeros((KIVA_HEIGHT, KIVA_WIDTH), dtype=bool)
    passable.flat[plant.ids] = True
    rng = np.random.default_rng(seed)
    starts = rng.choice(plant.ids, robots, replace=False).tolist()
    tasks = rng.choice(plant.with_role("station"), robots * 100).tolist()
    return Instance("kiva", passable, [int(s) for s in starts], [int(t) for t in tasks], robots)


def kiva_table(args: argparse.Namespace) -> None:
    """Tasks per step on kiva per fleet size, traffic mode and following rule, the mean over
    the seeds with the min-max, beside RHCR's figures (unit moves too, but no turns)."""
    steps = args.steps or KIVA_STEPS
    print(
        f"RHCR's kiva map in the competition's model (unit moves, quarter turns), {steps} "
        f"steps, seeds {' '.join(map(str, args.seeds))}, following: {args.follow}"
    )
    print()
    print(
        "| robots | following | traffic | tasks per step | RHCR (no turns) | ours / RHCR "
        "| moves / turns / waits per task | planning mean (s) | planning max (s) | conflicts |"
    )
    print("|---:|---|---|---:|---:|---:|---|---:|---:|---:|")
    for robots in args.kiva:
        for traffic in args.traffic:
            rates, means, peaks, conflicts, actions = [], [], [], 0, []
            for seed in args.seeds:
                result = solve(traffic, kiva_instance(robots, seed), steps, args)
                actions.append(actions_per_task(result))
                s = summary(result)
                rates.append(s["tasks_finished"] / steps)
                means.append(s["plan_mean_s"])
                peaks.append(s["plan_max_s"])
                conflicts += s["conflicts"]
            mean = sum(rates) / len(rates)
            ref = KIVA_RHCR.get(robots)
            per_task = " / ".join(f"{sum(a) / len(a):.1f}" for a in zip(*actions, strict=True))
            print(
                f"| {robots} | {args.follow} | {traffic} "
                f"| {mean:.2f} ({min(rates):.2f}-{max(rates):.2f}) "
                f"| {ref or '-'} | {f'{mean / ref:.2f}' if ref else '-'} "
                f"| {per_task} "
                f"| {sum(means) / len(means):.3f} | {max(peaks):.3f} | {conflicts} |"
            )


def actions_per_task(result: dict) -> tuple[float, float, float]:
    """A finished task's share of the fleet's timesteps: (moves, turns, waits) per task,
    from the actions in ``actualPaths``. Their sum is the robot-steps a task costs, so it
    says where a fleet's rate goes: longer ways round, more turns, or standing."""
    tasks = result["numTaskFinished"]
    counts = {"F": 0, "R": 0, "C": 0, "W": 0}
    for path in result["actualPaths"]:
        for a in path.split(",") if path else ():
            counts[a] += 1
    if not tasks:
        return (math.inf, math.inf, math.inf)
    return (counts["F"] / tasks, (counts["R"] + counts["C"]) / tasks, counts["W"] / tasks)


def summary(result: dict) -> dict:
    times = result["plannerTimes"]
    return {
        "tasks_finished": result["numTaskFinished"],
        "plan_mean_s": sum(times) / len(times),
        "plan_max_s": max(times),
        **result["_stats"],
    }


def load(path: Path) -> Instance:
    """:func:`read_instance`, or exit with its one-line error (file names from the instance
    written with their control characters and line breaks as escapes)."""
    try:
        return read_instance(path)
    except InstanceError as e:
        sys.exit(f"lorr.py: {one_line(str(e))}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("instance", nargs="?", type=Path)
    ap.add_argument("--steps", type=positive(int), default=None)
    ap.add_argument(
        "--traffic",
        choices=list(TRAFFIC),
        nargs="+",
        help="time_windows: full plans in time, prioritised; one_step: priority inheritance, "
        "one step at a time. Several: side by side (default: both; with an INSTANCE one, "
        "time_windows by default)",
    )
    ap.add_argument(
        "--follow",
        choices=list(FOLLOW),
        default="same_step",
        help="same_step: the competition's rule (into a cell in the step its robot leaves "
        "it); next_step: a step after it was left, as our vehicles' reservations allow",
    )
    ap.add_argument(
        "--kiva",
        type=positive(int),
        nargs="+",
        metavar="ROBOTS",
        help="run RHCR's kiva map with these fleet sizes instead of the instances",
    )
    ap.add_argument("--seeds", type=whole, nargs="+", default=[0, 1, 2], help="--kiva's seeds")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--data", type=Path, default=DATA, help="the instances' folder (its README)")
    ap.add_argument("--plan-budget", type=positive(int), default=PLAN_BUDGET)
    ap.add_argument("--stay-s", type=non_negative, default=3.0)
    ap.add_argument("--quick", action="store_true", help="100 robots, 50 steps per instance")
    args = ap.parse_args()
    if args.kiva and max(args.kiva) > (free := kiva().n):
        ap.error(
            f"argument --kiva: {max(args.kiva)} robots, but the kiva map has {free} free cells"
        )
    if args.traffic is None:
        args.traffic = ["time_windows"] if args.instance is not None else list(TRAFFIC)
    begin = time.perf_counter()
    if args.kiva:
        kiva_table(args)
        print()
        print(f"wall time {time.perf_counter() - begin:.1f} s")
        return
    if args.instance is not None:
        if len(args.traffic) > 1:
            ap.error("one --traffic mode with an INSTANCE")
        instance = load(args.instance)
        result = solve(args.traffic[0], instance, args.steps or 500, args)
        stats = result.pop("_stats")
        if args.out:
            args.out.write_text(json.dumps(result))
        print(
            json.dumps(
                {
                    "instance": str(args.instance),
                    "steps": args.steps or 500,
                    "tasks_finished": result["numTaskFinished"],
                    **stats,
                }
            )
        )
        return
    data = args.data
    if not data.exists():
        if not args.quick:
            sys.exit(f"lorr.py: no instances at {data} (pass --data DIR, the folder of the README)")
        data = TEST_DATA  # the quick check runs on the instance the repository keeps
    print(
        f"League of Robot Runners 2023 instances, traffic {' and '.join(args.traffic)}, "
        f"following: {args.follow}; time_windows' planning budget {args.plan_budget:,} search "
        "expansions per timestep"
    )
    print()
    print(
        "| instance | robots | steps | traffic | tasks finished | per step | best known "
        "| ours / best known | planning mean (s) | planning max (s) | failed searches "
        "| stepped aside |"
    )
    print("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for (rel, robots, steps), traffic in itertools.product(RUNS, args.traffic):
        if args.quick and robots > 100:
            continue
        if not (data / rel).exists():
            print(f"| {rel} | skipped: not in {data} |")
            continue
        instance = load(data / rel)
        if args.quick:
            steps = 50
        steps = args.steps or steps
        result = solve(traffic, instance, steps, args)
        s = summary(result)
        best = PUBLISHED.get((instance.name, instance.team, steps))
        ratio = f"{s['tasks_finished'] / best:.2f}" if best else "n/a"
        print(
            f"| {instance.name} | {instance.team} | {steps} | {traffic} | {s['tasks_finished']} "
            f"| {s['tasks_finished'] / steps:.2f} | {best or 'none published'} | {ratio} "
            f"| {s['plan_mean_s']:.3f} | {s['plan_max_s']:.3f} | {s['failures']} | {s['asides']} |"
        )
    print()
    print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
