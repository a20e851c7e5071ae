"""ConflictMonitor: counts collisions from the simulated vehicles' true positions.

It is independent of the blocks that prevent conflicts: it never reads the controller's
reservations or the reported positions, only where the simulated vehicles physically are.
Checked after every simulation step:

* head-on: two vehicles on the same segment driving towards each other;
* node conflict: two vehicles in one node's crossing zone at once, where a vehicle is in a
  node's zone when it stands at the node, or on a segment with its body (``length`` long,
  behind its front) closer than one vehicle length to the node's centre;
* area conflict: two vehicles in one single-vehicle area (plant key ``area``) at once,
  where a vehicle is in the area of the node it stands at and, while it drives a segment,
  in the areas of both of its ends: a segment into or out of an area belongs to it.

Each conflict is counted once when it begins (a pair that stays in conflict is one event).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from plc_runtime.recent import RecentList

from .fleet import Fleet

# conflicts kept, the newest: ~1,000 are far more than anyone reads back, and a monitor
# watching for months would otherwise grow with each one; head_on, node and area count them
# all, as does ``events.total``
EVENTS_KEPT = 1000


@dataclass(frozen=True)
class Conflict:
    time_s: float
    kind: str  # "head_on", "node" or "area"
    where: tuple[int, ...]  # the segment (a, b), the node (n,) or the area's nodes
    vehicles: tuple[int, int]


class ConflictMonitor:
    """Watches one fleet, or several (one per bus) sharing the plant: ``id_offsets[k]`` is
    added to fleet k's vehicle ids in the events."""

    def __init__(
        self, fleets: Fleet | Sequence[Fleet], id_offsets: Sequence[int] | None = None
    ) -> None:
        self.fleets = [fleets] if isinstance(fleets, Fleet) else list(fleets)
        self.offsets = list(id_offsets) if id_offsets is not None else [0] * len(self.fleets)
        self.events: RecentList[Conflict] = RecentList(EVENTS_KEPT)
        self.head_on = 0
        self.node = 0
        self.area = 0
        # node id -> the node ids of its single-vehicle area (the fleets share one plant)
        plant = self.fleets[0].plant
        self.area_of = {n: members for members in plant.areas.values() for n in members}
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

    def areas(self) -> dict[tuple[int, ...], set[int]]:
        """area (its node ids) -> vehicles in it now."""
        out: dict[tuple[int, ...], set[int]] = {}
        if not self.area_of:
            return out
        for v, agv in self._agvs():
            for node in (agv.node, agv.target):
                members = self.area_of.get(node)
                if members is not None:
                    out.setdefault(members, set()).add(v)
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
        for members, vehicles in self.areas().items():
            vehicles = sorted(vehicles)
            for i, v in enumerate(vehicles):
                for w in vehicles[i + 1 :]:
                    now.add(("area", members, (v, w)))
        for key in sorted(now - self._active):
            kind, where, pair = key
            self.events.append(Conflict(round(self.fleets[0].time, 3), kind, where, pair))
            if kind == "head_on":
                self.head_on += 1
            elif kind == "node":
                self.node += 1
            else:
                self.area += 1
        self._active = now
