"""An independent check of timed plans: the rules between two vehicles' windows written from
their definitions, over plain lists, sharing no code with the table that enforces them."""

from __future__ import annotations


class PlanMonitor:
    """The windows of the plans added so far, and whether a new window keeps clear of them."""

    def __init__(self, gap: float, areas: dict[int, str] | None = None):
        self.gap = gap
        # single-vehicle areas, node -> area name: a node's window meets the windows on
        # every node of its area
        self.areas = areas or {}
        self.nodes: dict[int, list[tuple[float, float, int]]] = {}
        self.segments: dict[tuple[int, int], list[tuple[float, float, int]]] = {}

    def add(self, plan) -> None:
        for n, a, d in plan.node_windows():
            self.nodes.setdefault(n, []).append((a, d, plan.vehicle))
        for u, v, s, e in plan.segment_windows():
            self.segments.setdefault((u, v), []).append((s, e, plan.vehicle))

    def node_free(self, n, start, end, vehicle=None) -> bool:
        """Nobody else on node n, or anywhere in its area, closer than the gap to [start, end]."""
        gap = self.gap
        area = self.areas.get(n)
        near = [n] if area is None else [m for m, a in self.areas.items() if a == area]
        return all(
            v == vehicle or not (start < e + gap and s < end + gap)
            for m in near
            for s, e, v in self.nodes.get(m, ())
        )

    def segment_free(self, u, v, start, end, vehicle=None) -> bool:
        """No head-on on u-v, and on u -> v nobody overtaken or crowded."""
        gap = self.gap
        for s, e, w in self.segments.get((v, u), ()):
            if w != vehicle and start < e + gap and s < end + gap:
                return False
        for s, e, w in self.segments.get((u, v), ()):
            behind = start >= s + gap and end >= e + gap
            ahead = s >= start + gap and e >= end + gap
            if w != vehicle and not (behind or ahead):
                return False
        return True

    def conflicts(self, plan) -> list[str]:
        """What in ``plan`` breaks a rule against the plans added (empty: nothing)."""
        out = []
        for n, a, d in plan.node_windows():
            if not self.node_free(n, a, d, plan.vehicle):
                out.append(f"node {n} during [{a}, {d}]")
        for u, v, s, e in plan.segment_windows():
            if not self.segment_free(u, v, s, e, plan.vehicle):
                out.append(f"segment {u}->{v} during [{s}, {e}]")
        return out
