"""OneStepPlanner: every robot's next node for one timestep, by priority inheritance (PIBT).

Full plans through a crowd fail: when a quarter of the cells hold robots, prioritised
planning finds no path for most of them, and the robots left without one stand in
everybody's way. Priority inheritance with backtracking (PIBT, Okumura et al., Artificial
Intelligence 2022; the planner under the best entries of the League of Robot Runners 2023)
plans one timestep at a time instead. The most urgent robot picks its best next node; a robot
standing there must move first and inherits the urgency to do so, recursively; if it cannot
move anywhere, the urgent one tries its next-best node. Nobody is ever without a move (to
stay is one), so a step's work is bounded by the robots times their nodes' degree, at any
density, and a robot that has waited longest is urgent enough to get through.

Robots here have a heading and turn on the spot: a next node that is not straight ahead
costs the time to face it, and a robot that picks one spends the step turning on its own
node, so it stays there for the step, and whoever was to follow into its node waits too. A
robot asked to make room that must turn first thus leaves a step later, and the one that
pushed it waits behind it meanwhile. "Straight ahead" is what the turn times price at
nothing: with turns of 1 s and 2 s on a grid, the one neighbour the robot faces.

No two robots end a step on one node, and no two swap nodes: the result is safe under the
unit-time model of multi-agent path finding, where a robot may follow another into the node
it leaves in the same step (tests/test_one_step.py checks both on random grids).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from topology import Plant

from .sipp import ArcGeometry, TurnTimes

Direction = tuple[float, float] | None


@dataclass(frozen=True)
class Move:
    """One robot's step: the node (index) it is at afterwards, and, when it stays to turn,
    the direction it turns to face (else None)."""

    node: int
    face: Direction = None

    def turn(self, facing: Direction) -> int:
        """+1 for a quarter turn clockwise (y pointing down, as in a grid's rows), -1 for
        counter-clockwise, 0 for none; a U-turn starts clockwise."""
        if self.face is None or facing is None:
            return 0
        cross = facing[0] * self.face[1] - facing[1] * self.face[0]
        dot = facing[0] * self.face[0] + facing[1] * self.face[1]
        if abs(cross) < 1e-9:
            return 1 if dot < 0 else 0
        return 1 if cross > 0 else -1


class OneStepPlanner:
    """PIBT over a plant's routable arcs. Candidates are priced in metres: a neighbour costs
    its segment, the turn to face it (``turns`` at ``speed``) and its distance to the goal;
    staying costs one step's drive (``step_s`` at ``speed``) more than the best way on from
    where the robot stands, and nothing more on its goal. So a robot off its goal stays only
    when the nodes that would serve it better are taken, a U-turn away from a goal behind
    it wins over standing, and a robot on its goal stays there unless asked to make room.
    A robot whose goal it cannot reach stays (its distances are inf) unless asked to move."""

    def __init__(
        self,
        plant: Plant,
        speed: float = 1.0,
        turns: TurnTimes | None = None,
        step_s: float = 1.0,
        follow: bool = True,
    ) -> None:
        self.plant = plant
        self.follow = follow
        self.speed = speed
        self.wait_m = speed * step_s  # what standing a step costs: one step's drive
        self.turns = turns or TurnTimes()
        geometry = ArcGeometry(plant)
        # the plant's headings: the distinct directions of its segments (4 on a grid)
        self.headings: list[tuple[float, float]] = []
        self._out: list[list[tuple[int, float, Direction, int]]] = [[] for _ in range(plant.n)]
        for u, arcs in enumerate(plant.neighbors):
            for v, arc, length in arcs:
                direction = geometry.direction[arc]
                d = self._heading_of(direction)
                if d < 0 and direction is not None:
                    self.headings.append(direction)
                    d = len(self.headings) - 1
                self._out[u].append((v, length, direction, d))
        self._reverse = self._state_graph().T.tocsr()

    def _state_graph(self) -> sp.csr_array:
        """Arcs between (node, heading) states: driving u -> v from heading h costs the
        turn to face v and the segment, and arrives facing v's direction."""
        h_count = max(len(self.headings), 1)
        src, dst, cost = [], [], []
        for u, arcs in enumerate(self._out):
            for v, length, direction, d in arcs:
                for h in range(h_count):
                    before = self.headings[h] if self.headings else None
                    turn = self.turns.between(before, direction) * self.speed
                    src.append(u * h_count + h)
                    dst.append(v * h_count + (d if d >= 0 else h))
                    cost.append(length + turn)
        size = self.plant.n * h_count
        return sp.csr_array((cost, (src, dst)), shape=(size, size))

    def distances(self, goal: int) -> np.ndarray:
        """(nodes x headings): the metres, turns counted at ``speed``, from each node facing
        each heading to the node with id ``goal``, facing any way. Turns are a large part of
        a trip on a grid, so counting them picks the ways with fewer; rows of this table are
        what :meth:`step` wants as ``to_goal``."""
        h_count = max(len(self.headings), 1)
        g = self.plant.idx(goal)
        d = dijkstra(
            self._reverse,
            directed=True,
            indices=[g * h_count + h for h in range(h_count)],
            min_only=True,
        )
        return d.reshape(self.plant.n, h_count)

    def step(
        self,
        at: Sequence[int],
        facing: Sequence[Direction],
        to_goal: Sequence[np.ndarray],
        priority: Sequence[float],
    ) -> list[Move]:
        """Each robot's move: ``at`` its node index, ``facing`` its heading (a unit vector,
        None for a robot that turns for free), ``to_goal`` the distance of every node index
        to its goal, ``priority`` its urgency (higher first; make them distinct, e.g. the
        steps since its task began plus a fraction by robot). ValueError if two robots
        stand on one node."""
        n = len(at)
        here: dict[int, int] = {}
        for i, node in enumerate(at):
            if node in here:
                raise ValueError(f"robots {here[node]} and {i} both stand on node index {node}")
            here[node] = i
        want: list[int] = [-1] * n  # node index each robot is given by PIBT
        taken: dict[int, int] = {}  # node index -> the robot given it
        for i in sorted(range(n), key=lambda k: -priority[k]):
            if want[i] < 0:
                self._inherit(i, at, facing, to_goal, here, taken, want)
        return self._turn_first(at, facing, want, here)

    def _candidates(self, at: int, facing: Direction, dist: np.ndarray) -> list[int]:
        """Its own node and every neighbour, cheapest first: a neighbour costs its segment,
        the turn to face it and its distance to the goal (per heading if ``dist`` has a
        column per heading); staying costs a step more than going on as well as it can."""
        out = []
        per_heading = dist.ndim == 2
        for v, length, direction, d in self._out[at]:
            turn = self.turns.between(facing, direction) if facing is not None else 0.0
            rest = float(dist[v, d] if d >= 0 else dist[v].min()) if per_heading else float(dist[v])
            out.append((length + turn * self.speed + rest, 1, rest, v))
        if per_heading:
            h = self._heading_of(facing)
            here = float(dist[at, h] if h >= 0 else dist[at].min())
        else:
            here = float(dist[at])
        # going on as well as it can from here: a table per heading holds exactly that (0 on
        # the goal); a table per node alone does not count the turns, and would price
        # standing below a U-turn towards the goal for ever, so the best neighbour stands in
        best = min((c[0] for c in out), default=math.inf)
        on = here if per_heading or here == 0 else best
        out.append((on + self.wait_m, 0, here, at))  # ties (inf: no way to the goal): stay
        out.sort()
        return [c[3] for c in out]

    def _heading_of(self, facing: Direction) -> int:
        """Index of the plant's heading ``facing`` is (-1: None, or none of them)."""
        if facing is None:
            return -1
        return next(
            (
                j
                for j, h in enumerate(self.headings)
                if abs(h[0] - facing[0]) < 1e-6 and abs(h[1] - facing[1]) < 1e-6
            ),
            -1,
        )

    def _inherit(self, root, at, facing, to_goal, here, taken, want) -> None:
        """PIBT from ``root`` on nodes alone, with an explicit stack (a chain of robots
        asked to make room may be as long as the fleet). A frame is [robot, the robot that
        pushes it or -1, its candidates, the next candidate to try]."""
        stack = [[root, -1, self._candidates(at[root], facing[root], to_goal[root]), 0]]
        child_ok: bool | None = None
        while stack:
            frame = stack[-1]
            i, pusher, cands, k = frame
            if child_ok:  # the robot in the way of cands[k - 1] made room: keep it
                stack.pop()
                continue
            child_ok = None
            pushed = None
            while k < len(cands):
                v = cands[k]
                k += 1
                if v in taken or (pusher >= 0 and v == at[pusher]):
                    continue  # someone will be there, or a swap with the one pushing
                taken[v] = i
                want[i] = v
                j = here.get(v)
                if j is not None and j != i and want[j] < 0:
                    pushed = j
                break
            else:  # nothing left: it stays, and the one pushing it tries elsewhere
                taken[at[i]] = i
                want[i] = at[i]
                stack.pop()
                child_ok = False
                continue
            if pushed is not None:
                frame[3] = k
                stack.append(
                    [pushed, i, self._candidates(at[pushed], facing[pushed], to_goal[pushed]), 0]
                )
                continue
            stack.pop()
            child_ok = True

    def _turn_first(self, at, facing, want, here) -> list[Move]:
        """Robots given a node they do not face turn towards it and stay; whoever was to
        follow into a node whose robot stays stays too, down the chain (without ``follow``,
        whoever was to drive into a node that is not empty now). What is left moves: into
        empty nodes, or behind robots that move on."""
        n = len(at)
        face: list[Direction] = [None] * n
        stays = [False] * n
        chain = []
        for i in range(n):
            if want[i] == at[i]:
                stays[i] = True
                chain.append(i)
                continue
            direction = self._direction(at[i], want[i])
            if facing[i] is not None and self.turns.between(facing[i], direction) > 0:
                face[i], stays[i] = direction, True
                chain.append(i)
        if not self.follow:
            for i in range(n):
                if not stays[i] and here.get(want[i], i) != i:
                    stays[i] = True  # into a node that is not empty yet: not this step
        behind: dict[int, int] = {want[i]: i for i in range(n) if want[i] != at[i]}
        while chain:
            j = behind.get(at[chain.pop()])  # the robot that was to take this node
            if j is not None and not stays[j]:
                stays[j] = True
                chain.append(j)
        return [Move(at[i], face[i]) if stays[i] else Move(want[i]) for i in range(n)]

    def _direction(self, u: int, v: int) -> Direction:
        for w, _, direction, _ in self._out[u]:
            if w == v:
                return direction
        raise ValueError(f"node index {v} is not a neighbour of {u}")
