"""The fleet's event log: what an operator wants to be told about, in the order it happened.

The log is a function block at the end of the fleet task. It does not ask the other blocks
to report; it compares what they expose with what it saw in the previous scan (a new
deadlock record, a replan counter that went up, a segment that became blocked, a vehicle
whose state became stale), so no block carries logging code and every source is covered
the same way, whoever caused the change (the blockade schedule, an operator over Modbus).
Memory is bounded: the newest ``capacity`` events (and segment changes) are kept, and a
count per kind.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import asdict, dataclass

from blocks.dispatch.executor import OrderRunner
from blocks.jobs.recipe import RecipeSequencer
from blocks.routing.constraints import RoutingConstraints
from blocks.traffic.deadlock import DeadlockResolver
from blocks.traffic.tw_traffic import TimeWindowTraffic
from blocks.traffic.vehicle_control import VehicleControl
from plc_runtime import CycleContext, FunctionBlock

# vehicle states worth an event when a vehicle enters them
ALARM_STATES = ("offline", "stale", "fault", "no_route", "suspect")
FOREIGN_NEWS_S = 2.0  # a vehicle stopped for a route it was not released this long is news
REPEAT_S = 60.0  # an event a client can repeat is logged at most once per this long
KINDS = ("deadlock", "livelock", "replan", "blockade", "reopened", "vehicle", "recovered")


@dataclass(frozen=True)
class Event:
    time_s: float
    kind: str  # one of KINDS
    vehicle: int | None
    text: str

    def to_dict(self) -> dict[str, object]:
        return asdict(self)

    def line(self) -> str:
        who = f"agv{self.vehicle} " if self.vehicle is not None else ""
        return f"{self.time_s:8.1f} s  {self.kind:<8} {who}{self.text}"


class EventLog(FunctionBlock):
    """Turns changes in the fleet's blocks into events (bounded)."""

    def __init__(
        self,
        controls: Mapping[int, VehicleControl],
        sequencers: Mapping[int, RecipeSequencer],
        resolver: DeadlockResolver,
        blockades: RoutingConstraints,
        capacity: int = 1000,
        traffic: TimeWindowTraffic | None = None,
        silent_after_s: float = math.inf,
    ) -> None:
        super().__init__()
        # a vehicle not heard from at all this long after the start: an alarm of its own,
        # since "offline" at the start is every vehicle's state and no news by itself
        self.silent_after_s = silent_after_s
        self._silence_checked = False
        self._silent: set[int] = set()  # reported silent, not heard from since
        self.traffic = traffic
        self._stranded: dict[int, int] = {}
        self.controls = controls
        self.sequencers = sequencers
        self.resolver = resolver
        self.blockades = blockades
        self.events: deque[Event] = deque(maxlen=capacity)
        self.counts: Counter[str] = Counter()
        self.added = 0  # events of the run so far: event k (from 1) is the k-th added
        self._deadlocks_seen = 0  # the resolver's events.total when last read
        self._replans = {v: 0 for v in controls}
        self._states = {v: "offline" for v in controls}
        # vehicles stopped for a route they were not released: since when, and whether told
        self._foreign: dict[int, tuple[float, bool]] = {}
        # vehicles that take orders, and the order whose load each was left with ('': none)
        self._runners = {v: j for v, j in sequencers.items() if isinstance(j, OrderRunner)}
        self._loads = dict.fromkeys(self._runners, "")
        self._blocked: set[tuple[int, int]] = set()
        # every segment closed or reopened, whoever did it: (time_s, "closed" | "reopened", a, b)
        self.segment_changes: deque[tuple[float, str, int, int]] = deque(maxlen=capacity)
        self.lifted: set[tuple[int, int]] = set()  # reopened during the run, open now
        self._epoch = -1  # the blockades' change counter when they were last compared
        # events a client can repeat at will: the last time each was logged, and how many
        # like it were left out since
        self._recent: dict[tuple[str, int | None, str], tuple[float, int]] = {}
        self.left_out = 0
        self._started = False

    def add(self, time_s: float, kind: str, vehicle: int | None, text: str) -> None:
        self.events.append(Event(round(time_s, 3), kind, vehicle, text))
        self.added += 1
        self.counts[kind] += 1

    def add_unless_repeated(self, time_s: float, kind: str, vehicle: int | None, text: str) -> bool:
        """:meth:`add`, but an event like one added less than REPEAT_S ago is left out
        (counted in ``left_out`` and in ``counts``) and the next one logged says how many
        were, since when: for events a
        client can cause at will (a refused acknowledge), which would otherwise push every
        other event out of the bounded log. True if it was added."""
        key = (kind, vehicle, text)
        last = self._recent.get(key)
        if last is not None and time_s - last[0] < REPEAT_S:
            self._recent[key] = (last[0], last[1] + 1)
            self.left_out += 1
            self.counts[kind] += 1  # the counts stay whole: every one happened
            return False
        more = ""
        if last is not None and last[1]:
            more = f" ({last[1]} more like it left out since {round(last[0], 3):g} s)"
        if len(self._recent) >= self.events.maxlen:
            self._recent = {k: t for k, t in self._recent.items() if time_s - t[0] < REPEAT_S}
        self._recent[key] = (time_s, 0)
        self.add(time_s, kind, vehicle, text + more)
        return True

    def cycle(self, ctx: CycleContext) -> None:
        now = ctx.time
        self._deadlocks(now)
        for v, control in self.controls.items():
            if control.replans > self._replans[v]:
                self._replans[v] = control.replans
                self.add(now, "replan", v, f"next segment taken at node {control.current}")
            state, before = control.state, self._states[v]
            if state != before:
                self._states[v] = state
                # every vehicle starts offline until its first status: not news
                if state in ALARM_STATES and (self._started or state != "offline"):
                    why = f": {control.suspect_reason}" if state == "suspect" else ""
                    self.add(now, "vehicle", v, f"{before} -> {state}{why}")
                elif before in ALARM_STATES and (before != "offline" or v in self._silent):
                    self._silent.discard(v)
                    self.add(now, "recovered", v, f"{before} -> {state}")
        self._foreign_routes(now)
        self._started = True
        if not self._silence_checked and now > self.silent_after_s:
            self._silence_checked = True
            for v, state in self._states.items():
                if state == "offline":
                    self._silent.add(v)
                    self.add(now, "vehicle", v, "offline: no status received since the start")
        self._loads_left(now)
        if self.traffic is not None:
            self._strandings(now)
        if self._epoch == self.blockades.epoch:
            return  # no segment closed or reopened since the last scan
        self._epoch = self.blockades.epoch
        blocked = {(min(a, b), max(a, b)) for a, b in self.blockades.blocked_segments()}
        for a, b in sorted(blocked - self._blocked):
            self.add(now, "blockade", None, f"segment {a}-{b} closed")
            self.segment_changes.append((round(now, 3), "closed", a, b))
            self.lifted.discard((a, b))
        for a, b in sorted(self._blocked - blocked):
            self.add(now, "reopened", None, f"segment {a}-{b} open again")
            self.segment_changes.append((round(now, 3), "reopened", a, b))
            self.lifted.add((a, b))
        self._blocked = blocked

    def _foreign_routes(self, now: float) -> None:
        """A vehicle kept stopped because it reports a next node it was not released (a
        route it still carries): news once it has lasted FOREIGN_NEWS_S, since a spoofed
        status frame stops one for a moment and that is no operator's business."""
        for v, control in self.controls.items():
            if control.foreign_route:
                since, told = self._foreign.setdefault(v, (now, False))
                if not told and now - since >= FOREIGN_NEWS_S:
                    self._foreign[v] = (since, True)
                    self.add(
                        now,
                        "vehicle",
                        v,
                        f"stopped at node {control.current}: it reports a next node it was "
                        "not released (a route it still carries); the command is repeated",
                    )
            elif v in self._foreign:
                _since, told = self._foreign.pop(v)
                if told:
                    self.add(now, "recovered", v, "carries only what it was released")

    def _loads_left(self, now: float) -> None:
        """An order ended without its Put (withdrawn, failed): its load is still on the
        vehicle, which takes no order until an operator confirms it was taken off."""
        for v, job in self._runners.items():
            left = job.load if job.load and job.load_left else ""
            if left != self._loads[v]:
                self._loads[v] = left
                if left:
                    text = (
                        f"load of order {left} left on board: no order until it is taken off "
                        f"and the vehicle acknowledged (agv{v}.ack)"
                    )
                    self.add(now, "vehicle", v, text)

    def _strandings(self, now: float) -> None:
        """Time-window traffic found no path for a vehicle for longer than its wait
        threshold: the seed's FAULT report (the vehicle stands; it is planned again every
        round, first)."""
        stranded = self.traffic.stranded_at
        if stranded == self._stranded:
            return
        for v in sorted(stranded.keys() - self._stranded.keys()):
            self.add(now, "vehicle", v, f"FAULT: no conflict-free path from node {stranded[v]}")
        for v in sorted(self._stranded.keys() - stranded.keys()):
            self.add(now, "recovered", v, "a path was found again")
        self._stranded = dict(stranded)

    def _deadlocks(self, now: float) -> None:
        records = self.resolver.events  # the newest only: count by its total, not its length
        unseen = min(records.total - self._deadlocks_seen, len(records))
        self._deadlocks_seen = records.total
        for e in records[len(records) - unseen :]:
            ring = " -> ".join(f"agv{v}" for v in e.vehicles)
            if e.backed_off is None:
                self.add(e.time_s, "livelock", None, f"unresolved: {ring} (nobody can give way)")
            else:
                self.add(
                    e.time_s, "deadlock", e.backed_off, f"gives way to node {e.to_node}: {ring}"
                )

    def recent(self, n: int) -> list[Event]:
        """The newest ``n`` events, oldest first."""
        return list(self.events)[-n:] if n > 0 else []
