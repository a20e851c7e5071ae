"""One simulated AGV on the plant graph.

It drives only along the nodes it has been commanded (the released "base", in VDA 5050
terms). Without a verified node after the one it is heading to, it slows down and stops at
that node's centre, the last point where it can change course (thesis 5.3.2), and waits.
It turns on the spot at a node (90 and 180 degree turns take configurable time), passes
straight through without stopping, accelerates and brakes with limited rates, and never
exceeds the segment's max speed. Reaching a node is a tag read (the thesis' RFID event),
reported at once. A front sensor (evaluated by the fleet, which sees every vehicle) stops
it behind another vehicle on the same lane; it resumes when the lane ahead is clear.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from plc_runtime.recent import RecentList
from topology import Plant

from .battery import Battery

# nodes reached kept per vehicle, the newest: a few thousand are hours of driving for the
# drawing of driven routes (it shows the last 48 segments); every node of a run of months
# would grow without bound. ``driven.total`` counts every node reached.
DRIVEN_KEPT = 2000


@dataclass
class AgvParams:
    max_speed: float = 0.5  # m/s
    accel: float = 0.5  # m/s^2
    decel: float = 0.8  # m/s^2
    creep_speed: float = 0.05  # m/s, the slowest approach to a node centre
    turn_90: float = 1.0  # s
    turn_180: float = 2.0  # s
    length: float = 0.25  # m, for the front sensor
    sensor_range: float = 0.15  # m of free space the sensor wants ahead


class AGV:
    def __init__(
        self,
        vehicle: int,
        plant: Plant,
        start: int,
        params: AgvParams | None = None,
        battery: Battery | None = None,
    ) -> None:
        plant.idx(start)
        self.vehicle = vehicle
        self.plant = plant
        self.params = params or AgvParams()
        self.battery = battery or Battery()
        self.node = start  # the last node reached (its tag read)
        self.target: int | None = None  # the node it is driving to, None while at `node`
        self.progress = 0.0  # metres along the current segment
        self.length = 0.0
        self.segment_max_speed = math.inf
        self.speed = 0.0
        self.accel = 0.0
        self.heading: tuple[float, float] | None = None
        self.turn_left = 0.0  # seconds of turning still to do before setting off
        self.route: deque[int] = deque()  # verified nodes after `target` (or after `node`)
        self.go = True
        self.commanded = False
        self.blocked_ahead = False
        self.stalled = False
        self.paused_until: float | None = None  # a random delay: it stands until then
        self.fault = False
        self.tag_reads = 0
        self.rejected_commands = 0
        # the nodes reached, the newest DRIVEN_KEPT, for the drawing of driven routes
        self.driven: RecentList[int] = RecentList(DRIVEN_KEPT, [start])
        self._lengths = {(e.source, e.target): e for e in plant.edges}
        self._lengths.update({(e.target, e.source): e for e in plant.edges if e.bidirectional})

    # ----- commands ----------------------------------------------------------------------
    def command(self, nodes: tuple[int, ...]) -> bool:
        """Replace the released route: the nodes to drive next, from where the vehicle is.
        On a segment the first node must be the segment's end; at a node, a neighbour. No
        nodes cancel the route: the vehicle stops at the node it reaches next."""
        nodes = tuple(nodes)
        if not nodes:
            self.route = deque()
            self.commanded = True
            if self.target is not None and self.progress == 0.0 and self.speed == 0.0:
                self.target = None  # it has not left its node yet: it stays there
            if self.target is None:
                self.turn_left = 0.0  # a turn on the spot towards the cancelled route ends
            return True
        if self.target is not None:
            if nodes[0] != self.target:
                self.rejected_commands += 1
                return False
            rest = nodes[1:]
            start = self.target
        else:
            rest, start = nodes, self.node
        previous = start
        for node in rest:
            if (previous, node) not in self._lengths:
                self.rejected_commands += 1
                return False
            previous = node
        self.route = deque(rest)
        self.commanded = True
        if self.target is None and self.turn_left > 0 and rest:
            self.turn_left = self._turn_time(
                self.node, rest[0]
            )  # turning towards a new direction now
        return True

    @property
    def clear(self) -> bool:
        """Its rear has left the crossing zone of ``node`` (one vehicle length around the
        node centre): another vehicle may enter the node behind it."""
        return self.target is not None and self.progress - self.params.length >= self.params.length

    @property
    def next_node(self) -> int | None:
        """The verified node it will reach next (the target, or the first released node)."""
        if self.target is not None:
            return self.target
        return self.route[0] if self.route else None

    @property
    def state(self) -> str:
        if self.fault or self.battery.failed or self.stalled:
            return "FAULT"
        if self.turn_left > 0:
            return "DRIVING"  # turning on the spot before setting off
        if self.target is not None:
            return "STOPPING_AT_NODE" if self._must_stop_at_end() and self.speed > 0 else "DRIVING"
        role = self.plant.node(self.node).role
        if role == "charger" and self.battery.percent < 100.0:
            return "CHARGING"
        if not self.commanded:
            return "IDLE"
        return "PROCESSING" if role == "station" else "WAITING_FOR_ROUTE"

    # ----- physics -----------------------------------------------------------------------
    def step(self, dt: float) -> bool:
        """Advance by dt seconds; True if a node was reached (a tag read) in this step."""
        p = self.params
        reached = False
        if self.fault or self.battery.failed:
            self._brake_to(0.0, dt)
        elif self.target is None:
            self.speed, self.accel = 0.0, 0.0
            if self.turn_left > 0:
                if self.go and self.paused_until is None:  # a stop holds the turn
                    self.turn_left = max(0.0, self.turn_left - dt)
                    if self.turn_left == 0:
                        self._set_off()
            elif self.route and self.go and self.paused_until is None:
                self._start_turn(self.route[0])
        else:
            if self.blocked_ahead or self.stalled or self.paused_until is not None or not self.go:
                self._brake_to(0.0, dt)
            else:
                remaining = self.length - self.progress
                limit = min(p.max_speed, self.segment_max_speed)
                if self._must_stop_at_end():
                    limit = min(
                        limit, max(p.creep_speed, math.sqrt(2 * p.decel * max(remaining, 0.0)))
                    )
                if self.speed < limit:
                    new = min(limit, self.speed + p.accel * dt)
                else:
                    new = max(limit, self.speed - p.decel * dt)
                self.accel = (new - self.speed) / dt if dt else 0.0
                self.speed = new
            self.progress += self.speed * dt
            if self.progress >= self.length:
                reached = True
                self._arrive()
        self.battery.step(dt, self.speed, self.accel, self.state == "CHARGING")
        return reached

    def _brake_to(self, target: float, dt: float) -> None:
        new = max(target, self.speed - self.params.decel * dt)
        self.accel = (new - self.speed) / dt if dt else 0.0
        self.speed = new

    def _must_stop_at_end(self) -> bool:
        """Stop at the target if nothing is released after it, or if the next hop needs a turn."""
        if not self.route or not self.go:
            return True
        return self._turn_time(self.target, self.route[0]) > 0

    def _direction(self, a: int, b: int) -> tuple[float, float] | None:
        na, nb = self.plant.node(a), self.plant.node(b)
        dx, dy = nb.x - na.x, nb.y - na.y
        norm = math.hypot(dx, dy)
        return (dx / norm, dy / norm) if norm > 1e-9 else None

    def _turn_time(self, at: int, to: int) -> float:
        new, old = (
            self._direction(at, to),
            self.heading,
        )  # heading: the direction it drives (or last drove)
        if new is None or old is None:
            return 0.0
        angle = math.degrees(math.acos(max(-1.0, min(1.0, old[0] * new[0] + old[1] * new[1]))))
        if angle >= 135:
            return self.params.turn_180
        return self.params.turn_90 if angle >= 45 else 0.0

    def _start_turn(self, to: int) -> None:
        self.turn_left = self._turn_time(self.node, to)
        if self.turn_left == 0:
            self._set_off()

    def _set_off(self) -> None:
        to = self.route.popleft()
        edge = self._lengths[(self.node, to)]
        self.target, self.length, self.progress = to, float(edge.length), 0.0
        self.segment_max_speed = edge.max_speed or math.inf
        self.heading = self._direction(self.node, to) or self.heading

    def _arrive(self) -> None:
        carry = self.progress - self.length
        self.node, self.target = self.target, None
        self.tag_reads += 1
        # the plant's own int for the node: every entry then shares one object per node
        # instead of holding an int of its own (28 bytes each) decoded from a route command
        self.driven.append(self.plant.node(self.node).id)
        if self.route and self.go and self._turn_time(self.node, self.route[0]) == 0:
            self._set_off()  # straight on: no stop at this node
            self.progress = min(carry, self.length)
        else:
            self.speed, self.progress = 0.0, 0.0
