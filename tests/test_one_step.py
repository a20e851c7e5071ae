"""OneStepPlanner (priority inheritance, one timestep at a time) on small grids.

The checks are written here from the unit-time model's rules, not taken from the planner:
after a step no two robots share a cell and no two have swapped cells; a robot that changes
cell moves to a neighbour straight ahead of it; one that turns stays on its cell and turns a
quarter (or starts a U-turn). Robots are simulated step by step, with their urgency the
steps since their goal was last reached, as the planner's users do.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from blocks.routing.heuristic import distances_to
from blocks.traffic.one_step import Move, OneStepPlanner
from blocks.traffic.sipp import TurnTimes
from topology.grid import grid_plant

HEADINGS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))  # E S W N, y down: clockwise
TURNS = TurnTimes(1.0, 2.0)


class Sim:
    """Robots on a grid, driven by the planner, checked against the rules every step."""

    def __init__(
        self, rows: list[str], starts, headings, goals, follow: bool = True, per_heading=True
    ) -> None:
        self.passable = np.array([[c == "." for c in row] for row in rows], dtype=bool)
        self.width = self.passable.shape[1]
        self.plant = grid_plant(self.passable)
        self.follow = follow
        self.per_heading = per_heading  # the planner's own table, or distances per node
        self.planner = OneStepPlanner(self.plant, speed=1.0, turns=TURNS, step_s=1.0, follow=follow)
        self.cell = list(starts)  # cell numbers (row * width + column)
        self.heading = list(headings)  # index into HEADINGS
        self.goals = [list(g) for g in goals]  # each robot's goals, in turn
        self.since = [0] * len(starts)
        self.urgency: list[float] | None = None  # fixed urgencies instead of the waits
        self.done = [0] * len(starts)
        self.t = 0

    def to(self, goal: int) -> np.ndarray:
        if self.per_heading:
            return self.planner.distances(goal)
        return distances_to(self.plant, [goal])[0]

    def step(self) -> list[Move]:
        n = len(self.cell)
        for i in range(n):
            if self.goals[i] and self.cell[i] == self.goals[i][0]:
                self.goals[i].pop(0)
                self.done[i] += 1
                self.since[i] = self.t
        goal = [g[0] if g else c for g, c in zip(self.goals, self.cell, strict=True)]
        moves = self.planner.step(
            [self.plant.idx(c) for c in self.cell],
            [HEADINGS[h] for h in self.heading],
            [self.to(g) for g in goal],
            self.urgency or [self.t - self.since[i] + i / n for i in range(n)],
        )
        assert len(moves) == n
        before = list(self.cell)
        for i, m in enumerate(moves):
            after = int(self.plant.ids[m.node])
            if after != before[i]:
                dx, dy = HEADINGS[self.heading[i]]
                ahead = before[i] + int(dx) + int(dy) * self.width
                assert after == ahead, f"robot {i} leaves {before[i]} for {after}, not ahead"
                assert m.face is None
                assert self.follow or after not in before, f"robot {i} follows into {after}"
            else:
                h = self.heading[i]
                turn = m.turn(HEADINGS[h])
                if m.face is not None:  # a quarter turn to face it, or a U-turn's first
                    assert turn != 0
                    assert HEADINGS[(h + turn) % 4] == m.face or m.face == HEADINGS[(h + 2) % 4]
                self.heading[i] = (h + turn) % 4
            self.cell[i] = after
        assert len(set(self.cell)) == n, f"step {self.t}: two robots share a cell"
        where = {c: i for i, c in enumerate(before)}
        for i in range(n):
            j = where.get(self.cell[i])
            assert not (j is not None and j != i and self.cell[j] == before[i]), (
                f"step {self.t}: robots {i} and {j} swap cells"
            )
        self.t += 1
        return moves


def test_turning_signs_follow_the_grid():
    east, south, west, north = HEADINGS
    assert Move(0, south).turn(east) == 1  # clockwise with y down
    assert Move(0, north).turn(east) == -1
    assert Move(0, west).turn(east) == 1  # a U-turn starts clockwise
    assert Move(0, east).turn(east) == 0
    assert Move(0, None).turn(east) == 0


def test_two_robots_on_one_node_is_an_error():
    plant = grid_plant(np.ones((2, 2), dtype=bool))
    planner = OneStepPlanner(plant)
    row = distances_to(plant, [0])[0]
    with pytest.raises(ValueError, match="robots 0 and 1"):
        planner.step([1, 1], [None, None], [row, row], [1.0, 0.0])


def test_a_robot_alone_turns_once_then_drives_the_shortest_way():
    sim = Sim(["....", "....", "...."], starts=[0], headings=[0], goals=[[8]])  # (0,0) -> (2,0)
    for _ in range(3):
        sim.step()
    assert sim.cell == [8]  # one quarter turn, two moves
    assert sim.heading == [1]


def test_the_more_urgent_robot_pushes_the_other_out_of_its_way():
    """Head-on on a ring: robot 0 (urgent, facing east) must get along the top row; robot 1
    stands on its own goal there, facing it. Robot 1 inherits the urgency, turns round (two
    steps, while robot 0 waits behind it), drives ahead of robot 0 to the corner and round
    it, and robot 0 arrives. Robot 1 would not leave its goal on its own account: with the
    urgency the other way round, robot 0 never gets past."""
    rows = [".......", ".#####.", "......."]
    sim = Sim(rows, starts=[0, 2], headings=[0, 2], goals=[[6], [2]])
    sim.urgency = [1.0, 0.0]  # robot 0 is the more urgent
    for _ in range(12):
        sim.step()
        if not sim.goals[0]:
            break
    assert sim.done[0] == 1, f"robot 0 stuck at {sim.cell[0]} after {sim.t} steps"
    assert sim.t <= 10 and sim.cell[1] in (13, 20)  # robot 1 round the corner, out of the way
    # the other way round robot 1 stays on its goal and robot 0 waits behind it: one step's
    # planning does not route round a robot; an urgency that grows with the wait (as the
    # benchmarks give it) is what gets a robot through in the end
    other = Sim(rows, starts=[0, 2], headings=[0, 2], goals=[[6], [2]])
    other.urgency = [0.0, 1.0]
    for _ in range(20):
        other.step()
        assert other.cell[1] == 2
    assert other.done[0] == 0


def test_a_robot_on_its_goal_stays_and_one_that_cannot_reach_it_too():
    plant = grid_plant(np.ones((1, 3), dtype=bool))
    planner = OneStepPlanner(plant, turns=TURNS)
    east = HEADINGS[0]
    for row in (distances_to(plant, [1])[0], planner.distances(1)):
        assert planner.step([1], [east], [row], [0.0]) == [Move(1)]
        assert planner.step([1], [None], [row], [0.0]) == [Move(1)]
    assert planner.step([2], [east], [np.full(3, np.inf)], [0.0]) == [Move(2)]
    # asked to make room, it still does: robot 1 (urgent) wants node 2, robot 0 stands there
    moves = planner.step(
        [2, 1], [HEADINGS[2], east], [np.full(3, np.inf), distances_to(plant, [2])[0]], [0, 1]
    )
    assert moves == [Move(2), Move(1)]  # facing west it would have to drive into robot 1


def brute_force_steps(rows: list[str], start: int, heading: int, goal: int) -> int:
    """Fewest timesteps from (start, heading) to goal, facing any way: breadth-first over
    (cell, heading) with a move forward or a quarter turn per step, written from the model
    alone."""
    width, height = len(rows[0]), len(rows)
    seen, frontier, steps = {(start, heading)}, [(start, heading)], 0
    while frontier:
        if any(cell == goal for cell, _ in frontier):
            return steps
        nxt = []
        for cell, h in frontier:
            x, y = cell % width, cell // width
            dx, dy = (int(c) for c in HEADINGS[h])
            options = [(cell, (h + 1) % 4), (cell, (h - 1) % 4)]
            if 0 <= x + dx < width and 0 <= y + dy < height and rows[y + dy][x + dx] == ".":
                options.append((cell + dx + dy * width, h))
            for state in options:
                if state not in seen:
                    seen.add(state)
                    nxt.append(state)
        frontier, steps = nxt, steps + 1
    return -1


def test_without_headings_it_is_plain_pibt_and_a_ring_rotates():
    """Four robots on a 2 x 2 ring, each wanting the next cell clockwise: all move at once,
    one following another, which the unit-time model allows (no swap, no shared cell)."""
    plant = grid_plant(np.ones((2, 2), dtype=bool))
    planner = OneStepPlanner(plant)
    at = [0, 1, 3, 2]  # node indices of cells (0,0) (0,1) (1,1) (1,0)
    goals = [1, 3, 2, 0]
    moves = planner.step(
        at, [None] * 4, [distances_to(plant, [g])[0] for g in goals], [4.0, 3.0, 2.0, 1.0]
    )
    assert [m.node for m in moves] == goals
    # where a robot may only drive into an empty node, nobody moves: the ring is full
    strict = OneStepPlanner(plant, follow=False)
    moves = strict.step(
        at, [None] * 4, [distances_to(plant, [g])[0] for g in goals], [4.0, 3.0, 2.0, 1.0]
    )
    assert [m.node for m in moves] == at


def test_without_following_the_one_behind_drives_a_step_later():
    sim = Sim(["......"], starts=[1, 0], headings=[0, 0], goals=[[5], [4]], follow=False)
    sim.step()
    assert sim.cell == [2, 0]  # the front robot drives on, the one behind waits
    sim.step()
    assert sim.cell == [3, 1]


grids = st.integers(4, 8).flatmap(
    lambda w: st.integers(3, 7).flatmap(
        lambda h: st.lists(st.booleans(), min_size=w * h, max_size=w * h).map(
            lambda cells: [
                "".join(
                    "." if (free or (y * w + x) % 3 == 0) else "#"
                    for x, free in enumerate(cells[y * w : (y + 1) * w])
                )
                for y in range(h)
            ]
        )
    )
)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rows=grids, data=st.data(), follow=st.booleans(), per_heading=st.booleans())
def test_no_shared_cell_no_swap_and_only_straight_moves_on_random_grids(
    rows, data, follow, per_heading
):
    """With ``follow`` off, also: nobody drives into a cell that was not empty."""
    plant = grid_plant(np.array([[c == "." for c in r] for r in rows], dtype=bool))
    # the part connected to the first free cell, so that every goal is reachable
    free = [int(c) for c in plant.ids]
    reach = distances_to(plant, [free[0]])[0]
    part = [int(plant.ids[k]) for k in np.flatnonzero(np.isfinite(reach))]
    if len(part) < 3:
        return
    n = data.draw(st.integers(2, max(2, min(len(part) - 1, len(part) * 2 // 3))))
    starts = data.draw(st.permutations(part))[:n]
    headings = data.draw(st.lists(st.integers(0, 3), min_size=n, max_size=n))
    goals = [data.draw(st.lists(st.sampled_from(part), min_size=1, max_size=4)) for _ in range(n)]
    sim = Sim(rows, starts, headings, goals, follow, per_heading)
    for _ in range(40):
        sim.step()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rows=grids, data=st.data())
def test_a_robot_alone_takes_the_fewest_steps_turns_counted(rows, data):
    """With the planner's table per heading, a lone robot reaches its goal in exactly the
    fewest timesteps of moves and quarter turns (a brute-force search of the model), and
    its table holds that number for its start."""
    plant = grid_plant(np.array([[c == "." for c in r] for r in rows], dtype=bool))
    free = [int(c) for c in plant.ids]
    start = data.draw(st.sampled_from(free))
    goal = data.draw(st.sampled_from(free))
    heading = data.draw(st.integers(0, 3))
    best = brute_force_steps(rows, start, heading, goal)
    sim = Sim(rows, [start], [heading], [[goal, goal]])
    h = sim.planner._heading_of(HEADINGS[heading])
    table = sim.planner.distances(goal)
    if best < 0:
        assert np.isinf(table[plant.idx(start)]).all()
        return
    # headings the plant has no segment along (a robot alone in a column) fall back to
    # the best of the others; every grid with a move has east or west, north or south
    if h >= 0:
        assert table[plant.idx(start), h] == best
    for _ in range(best):
        sim.step()
    assert sim.cell == [goal] or h < 0
