"""PassOrder: execute timed plans by order, not by time (an action dependency graph).

Plans made in time are conflict-free only if every vehicle keeps to its times, and real
vehicles do not: batteries, turns, acceleration and traffic make them early or late. What a
conflict-free joint plan fixes for certain is the *order* in which vehicles pass each node
(Hoenig et al. 2019, "Persistent and robust execution of MAPF schedules"; Ma et al. 2017).
So the controller keeps, per node, the visits of every plan sorted by the planned time the
node is claimed (the vehicle sets off towards it: ``TimedPlan.claims``), and lets a vehicle
drive onto a node only when every visit before its own has passed (the vehicle has left
the node). Then:

* no two vehicles are on a node at once (the one before has left);
* no two meet head-on on a segment: the plans never cross a segment in opposite directions
  at overlapping times, so the two ends' orders agree, and a vehicle enters the far end
  only after the oncoming one has left it;
* no deadlock: a vehicle waits for one that must leave the node first, i.e. claim its next
  node, which it is planned to do before the waiting one claims this node (their windows
  on the node are a gap apart). So every wait points to a strictly earlier planned claim,
  and the waits form no cycle. (Windows that open only on arrival do not give this: a
  ring of vehicles planned to move round in lockstep would each wait for the one ahead.)

for any delays. Delays are absorbed, not repaired: a late vehicle makes the ones after it
at shared nodes late, never unsafe. Its own visits are passed in plan order.

A "node" here may also be a single-vehicle area: all its nodes share one queue, so a
vehicle enters the area only after every visit planned there before its own has left it.

A vehicle's plan starts with the node it stands on (step 0), and is replaced whole when it
is replanned (:meth:`set_plan`); the replacement must come from the same consistent set of
windows (the time-window table) for the order to stay acyclic.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence


class PassOrder:
    """Per node, the pending visits (planned time, vehicle, step) of every plan, in order."""

    def __init__(self) -> None:
        self._queues: dict[int, list[tuple[float, int, int]]] = {}
        self._plans: dict[int, tuple[tuple[int, ...], tuple[float, ...]]] = {}
        self._passed: dict[int, int] = {}  # vehicle -> steps passed (its first pending step)

    def set_plan(self, vehicle: int, nodes: Sequence[int], arrive: Sequence[float]) -> None:
        """``vehicle`` now follows ``nodes`` (step 0: where it stands), claiming each at the
        planned time in ``arrive`` (``TimedPlan.claims``); its earlier pending visits are
        dropped."""
        if len(nodes) != len(arrive) or not nodes:
            raise ValueError(
                f"a plan needs one arrival time per node, got {len(nodes)} and {len(arrive)}"
            )
        self.drop(vehicle)
        self._plans[vehicle] = (tuple(nodes), tuple(arrive))
        self._passed[vehicle] = 0
        for step, (node, t) in enumerate(zip(nodes, arrive, strict=True)):
            bisect.insort(self._queues.setdefault(node, []), (t, vehicle, step))

    def drop(self, vehicle: int) -> None:
        """Forget ``vehicle``'s pending visits (its plan is void)."""
        plan = self._plans.pop(vehicle, None)
        first = self._passed.pop(vehicle, 0)
        if plan is None:
            return
        nodes, arrive = plan
        for step in range(first, len(nodes)):
            self._remove(nodes[step], (arrive[step], vehicle, step))

    def cut(self, vehicle: int, step: int) -> None:
        """``vehicle``'s plan ends before ``step`` now: its visits from there on are
        dropped (it waits at the end of what is left for a new plan)."""
        nodes, arrive = self._plans[vehicle]
        if not 0 < step < len(nodes) or step < self._passed[vehicle]:
            raise ValueError(f"step {step} is not a pending step after the first of the plan")
        for s in range(step, len(nodes)):
            self._remove(nodes[s], (arrive[s], vehicle, s))
        self._plans[vehicle] = (nodes[:step], arrive[:step])

    def passed(self, vehicle: int, step: int) -> None:
        """``vehicle`` has left the node of ``step`` (and so every step before it)."""
        nodes, arrive = self._plans[vehicle]
        first = self._passed[vehicle]
        for s in range(first, min(step + 1, len(nodes))):
            self._remove(nodes[s], (arrive[s], vehicle, s))
        self._passed[vehicle] = max(first, step + 1)

    def may_enter(self, vehicle: int, step: int) -> bool:
        """May ``vehicle`` drive onto the node of its plan's ``step``: has every visit
        planned there before its own passed?"""
        return self.blocker(vehicle, step) is None

    def blocker(self, vehicle: int, step: int) -> int | None:
        """The vehicle whose earlier visit to that node has not passed yet (None: nobody).
        The vehicle's own earlier visits there do not count: it is there, or leaving. (Of
        one node, a vehicle is never released a node it holds; of a single-vehicle area,
        it may come back in at another node before its earlier visit has passed, and then
        waits for the other vehicles' visits ordered between its two.)"""
        nodes, _ = self._plans[vehicle]
        for _, other, other_step in self._queues.get(nodes[step], ()):
            if other != vehicle:
                return other
            if other_step >= step:
                return None
        return None

    def ahead(self, vehicle: int, step: int) -> list[tuple[int, int]]:
        """The other vehicles' visits (vehicle, step) ordered before ``vehicle``'s visit of
        ``step`` at that node."""
        nodes, arrive = self._plans[vehicle]
        queue = self._queues[nodes[step]]
        end = bisect.bisect_left(queue, (arrive[step], vehicle, step))
        return [(other, s) for _, other, s in queue[:end] if other != vehicle]

    def take_turn(self, vehicle: int, step: int) -> None:
        """Move ``vehicle``'s visit of ``step`` before every pending visit at that node (it
        overtakes vehicles that are still on their way there). Only safe as
        :class:`~blocks.traffic.tw_traffic.TimeWindowTraffic` uses it: the vehicle enters
        the node now and may leave it for its next step without waiting for anyone, so
        nothing it waits for can wait for the visits it overtook."""
        nodes, arrive = self._plans[vehicle]
        queue = self._queues[nodes[step]]
        first = queue[0]
        if first[1:] == (vehicle, step):
            return
        queue.pop(bisect.bisect_left(queue, (arrive[step], vehicle, step)))
        earlier = first[0] - 1e-6 * max(1.0, abs(first[0]))
        self._plans[vehicle] = (nodes, (*arrive[:step], earlier, *arrive[step + 1 :]))
        queue.insert(0, (earlier, vehicle, step))  # the queue keeps the other visit: not empty

    def label(self, vehicle: int, step: int) -> float:
        """The place of ``vehicle``'s visit of ``step`` in its node's order."""
        return self._plans[vehicle][1][step]

    def pending(self, node: int) -> list[tuple[float, int, int]]:
        """The visits still to pass ``node``, first first."""
        return list(self._queues.get(node, ()))

    def progress(self, vehicle: int) -> int:
        """Steps of its plan ``vehicle`` has passed."""
        return self._passed.get(vehicle, 0)

    def _remove(self, node: int, visit: tuple[float, int, int]) -> None:
        queue = self._queues[node]
        queue.pop(bisect.bisect_left(queue, visit))
        if not queue:
            del self._queues[node]
