"""A vehicle's own list of goals: the job for trying one's own assignment of places to
vehicles (a researcher's task allocation, a test drive, a commissioning tour) on the whole
fleet program, where recipes choose stations by function and orders go between stations.

Goals are plant nodes, driven in the order given; routing, reservations and traffic drive
the vehicle there as they drive any job's target. ``send`` may be called from any thread
(a deque append): the scan takes the goals in its own time.
"""

from __future__ import annotations

from collections import deque
from numbers import Integral

from plc_runtime import CycleContext, FunctionBlock, Input, Output
from topology import Plant

MAX_REACHED = 10_000  # goals remembered as reached (node, time): a long run's memory is bounded


class GoalQueue(FunctionBlock):
    """Sends its vehicle to each goal of its queue in turn; a goal is reached when the
    vehicle control reports it there with nothing left to drive."""

    arrived = Input(False, doc="the vehicle control reports: at the target, nothing left to drive")
    current = Input(None, doc="the node the vehicle last reported")

    target = Output(None, doc="the goal the vehicle drives to (None: no goal left)")
    fixed_route = Output(None, doc="always None: the route is planned")
    hold = Output(False, doc="always FALSE: a goal is left as soon as it is reached")
    phase = Output("idle", doc="idle|to_goal")
    priority_ns = Output(0, doc="when the current goal was taken: older goes first")
    rounds_done = Output(0, doc="goals reached")
    # what the fleet's reports read of every job (a goal is no recipe and no station visit)
    step = Output(0)
    recipe_name = Output("")
    stations_visited = Output(0)

    def __init__(self, vehicle: int, plant: Plant) -> None:
        super().__init__()
        self.vehicle = vehicle
        self.plant = plant
        self.pending: deque[int] = deque()  # goals not taken yet, in order
        self.reached: deque[tuple[int, float]] = deque(maxlen=MAX_REACHED)

    def send(self, *nodes: int) -> None:
        """Queue ``nodes`` as goals, in order. A node the plant does not have is a
        ValueError naming it, and none of ``nodes`` is queued."""
        goals = []
        for node in nodes:
            if isinstance(node, bool) or not isinstance(node, Integral):
                raise ValueError(f"vehicle {self.vehicle}: goal {node!r} is not a node id")
            if int(node) not in self.plant.index:
                raise ValueError(
                    f"vehicle {self.vehicle}: goal {node} is not a node of the plant "
                    f"{self.plant.name}"
                )
            goals.append(int(node))  # a numpy integer from plant.ids too
        self.pending.extend(goals)

    def cycle(self, ctx: CycleContext) -> None:
        if self.current is None:
            return
        if self.target is not None and self.arrived and self.current == self.target:
            self.reached.append((self.target, ctx.time))
            self.rounds_done += 1
            self.target, self.phase = None, "idle"
        if self.target is None and self.pending:
            self.target, self.phase = self.pending.popleft(), "to_goal"
            self.priority_ns = ctx.time_ns
