"""ConflictMonitor: counts collisions from the simulated vehicles' true positions.

It is independent of the blocks that prevent conflicts: it never reads the controller's
reservations or the reported positions, only where the simulated vehicles physically are.
Checked after every simulation step:

* head-on: two vehicles on the same segment driving towards each other;
* node conflict: two vehicles in one node's crossing zone at once, where a vehicle is in a
  node's zone when it stands at the node, or on a segment with its body (``length`` long,
  behind its front) closer than one vehicle length to the node's centre.

Each conflict is counted once when it begins (a pair that stays in conflict is one event).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from .fleet import Fleet


@dataclass(frozen=True)
class Conflict:
    time_s: float
    kind: str  # "head_on" or "node"
    where: tuple[int, ...]  # the segment (a, b) or the node (n,)
    vehicles: tuple[int, int]


class ConflictMonitor:
    """Watches one fleet, or several (one per bus) sharing the plant: ``id_offsets[k]`` is
    added to fleet k's vehicle ids in the events."""

    def __init__(
        self, fleets: Fleet | Sequence[Fleet], id_offsets: Sequence[int] | None = None
    ) -> None:
        self.fleets = [fleets] if isinstance(fleets, Fleet) else list(fleets)
        self.offsets = list(id_offsets) if id_offsets is not None else [0] * len(self.fleets)
        self.events: list[Conflict] = []
        self.head_on = 0
        self.node = 0
        self._active: set[tuple] = set()

    def _agvs(self):
        for fleet, offset in zip(self.fleets, self.offsets, strict=True):
            for v, agv in fleet.vehicles.items():
                yield v + offset, agv

    def zones(self) -> dict[int, list[int]]:
        """node id -> vehicles in its crossing zone now."""
        out: dict[int, list[int]] = {}
        for v, agv in self._agvs():
            clearance = agv.params.length
            if agv.target is None:
                out.setdefault(agv.node, []).append(v)
                continue
            if agv.progress - agv.params.length < clearance:
                out.setdefault(agv.node, []).append(v)
            if agv.progress > agv.length - clearance:
                out.setdefault(agv.target, []).append(v)
        return out

    def check(self) -> None:
        now: set[tuple] = set()
        on_segment: dict[tuple[int, int], list[int]] = {}
        for v, agv in self._agvs():
            if agv.target is not None:
                on_segment.setdefault((agv.node, agv.target), []).append(v)
        for (a, b), vehicles in on_segment.items():
            for w in on_segment.get((b, a), []):
                for v in vehicles:
                    if v < w:
                        now.add(("head_on", (a, b), (v, w)))
        for node, vehicles in self.zones().items():
            vehicles = sorted(set(vehicles))
            for i, v in enumerate(vehicles):
                for w in vehicles[i + 1 :]:
                    now.add(("node", (node,), (v, w)))
        for key in sorted(now - self._active):
            kind, where, pair = key
            self.events.append(Conflict(round(self.fleets[0].time, 3), kind, where, pair))
            if kind == "head_on":
                self.head_on += 1
            else:
                self.node += 1
        self._active = now
