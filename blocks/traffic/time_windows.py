"""TimeWindowTable: who will be on which node and segment, and when.

Reactive traffic (:class:`ReservationMatrix`) knows who holds which node *now*. Planning in
time needs more: every node and every directed segment a vehicle's plan uses, with the
interval it will be there. Plans are then searched only through free windows (the
constraint of time-window planning: a segment is never used in opposite directions at
overlapping times), so the plans of different vehicles are conflict-free by construction,
and the executor only has to keep the order they fix.

Rules between the windows of two *different* vehicles, ``gap`` being the safety gap in
seconds:

* **node**: the windows are disjoint, at least ``gap`` apart. One vehicle on a node at a
  time, and the next arrives ``gap`` after the previous one left, when its body has cleared
  the crossing.
* **segment, opposite directions**: disjoint, at least ``gap`` apart (no head-on).
* **segment, same direction**: the follower enters at least ``gap`` after the leader
  entered and leaves at least ``gap`` after it left: vehicles keep their order and distance
  on a segment, never overtake; how many fit on it follows from its travel time and the gap.

A vehicle's own windows never conflict with each other: consecutive windows of one plan
touch. Memory stays bounded by the plans: :meth:`book` replaces a vehicle's windows,
:meth:`release` drops them, :meth:`expire` drops every window that ended before a time.

**Single-vehicle areas** (a transfer station and the node in front of it) hold one vehicle
in all of their nodes at once. The table keeps the windows of an area's nodes under one key,
the area (``resources``: node id -> area key), so the node rule holds for the area as a
whole: another vehicle's window anywhere in it keeps a vehicle out of all of it. One
vehicle's windows on the area's nodes touch one after the other while it drives inside.

A window that never ends (``end = inf``) is a vehicle staying at its goal, or standing
where it is until further notice (out of service, without a plan); nobody can be planned through
that node after its arrival until the vehicle is given a new plan. A window booked as for
good (``lasting``: a vehicle out of service) stays whole past a windowed plan's cut-off too
(:meth:`TimeWindowTable.safe_intervals`): that vehicle is in the way then as now, like a
blockade. Any other (``lasting=False``: it will go on, when is not known yet) ends at the
cut-off as every other window.

The gap is never zero: two vehicles passing one node at the same instant have windows of no
length that touch, and only a gap tells them apart. On a unit-time grid a gap of one step is
the usual multi-agent path-finding model: no two on a node at once, no swaps, following one
step behind allowed.

Times are seconds on the controller's clock. Comparisons allow ``EPS`` so that a time
computed as ``(t - travel) + travel`` still meets the window it was computed from.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Hashable, Iterable, Mapping
from typing import NamedTuple

EPS = 1e-9
# A vehicle passing a node without stopping has a window of no length: only a gap > 0 keeps
# two such passes at the same instant apart, so the gap can never be zero.
MIN_GAP_S = 1e-6


class Window(NamedTuple):
    start: float
    end: float
    vehicle: int


# How the table stores a window: a plain (start, end, vehicle) tuple. Unlike a Window (a
# tuple subclass) the garbage collector stops tracking such a tuple, and a thousand
# vehicles' plans hold tens of thousands of windows that would otherwise make every full
# collection long. The reading methods hand out Windows.
_Stored = tuple[float, float, int]


class WindowConflict(ValueError):
    """A booking would break a rule against another vehicle's window."""


class TimeWindowTable:
    """Node and directed-segment windows of every vehicle's plan, sorted by start."""

    def __init__(self, gap_s: float = 0.5, resources: Mapping[int, Hashable] | None = None) -> None:
        if not (math.isfinite(gap_s) and gap_s >= MIN_GAP_S):
            raise ValueError(
                f"gap_s must be a finite number of seconds >= {MIN_GAP_S:g}, got {gap_s!r}"
            )
        self.gap = float(gap_s)
        # node id -> the key its windows are kept under (its area's); a node not in it keeps
        # its own
        self.resources: Mapping[int, Hashable] = resources or {}
        self._nodes: dict[Hashable, list[_Stored]] = {}
        self._segments: dict[tuple[int, int], list[_Stored]] = {}
        # what each vehicle booked: the keys, so release never scans the whole table
        self._booked: dict[int, tuple[list[Hashable], list[tuple[int, int]]]] = {}
        # node key -> (start, vehicle) of each node window there that never ends: who
        # stands there for good, looked up in one step past a windowed plan's cut-off
        self._lasting: dict[Hashable, list[tuple[float, int]]] = {}

    # ----- reading -------------------------------------------------------------------------
    def node_windows(self, node: int) -> tuple[Window, ...]:
        """The windows on ``node``: on every node of its area, if it is in one."""
        return tuple(Window(*w) for w in self._nodes.get(self.resources.get(node, node), ()))

    def segment_windows(self, a: int, b: int) -> tuple[Window, ...]:
        """Windows on the directed segment a -> b."""
        return tuple(Window(*w) for w in self._segments.get((a, b), ()))

    @property
    def vehicles(self) -> frozenset[int]:
        return frozenset(self._booked)

    def __len__(self) -> int:
        """The number of windows held: what bounds the table's memory."""
        return sum(len(w) for w in self._nodes.values()) + sum(
            len(w) for w in self._segments.values()
        )

    def safe_intervals(
        self,
        node: int,
        vehicle: int | None = None,
        until: float = math.inf,
        lasting: bool = True,
    ) -> list[tuple[float, float]]:
        """The intervals in which ``vehicle`` may stand on ``node``: the gaps between the
        other vehicles' windows, each kept ``gap`` clear of them. Sorted, disjoint, possibly of
        no length (a pass at one instant); the last one ends at inf unless a window there
        never ends.

        ``until``: conflicts are resolved only before that time (a windowed plan). Windows
        starting at or after it are ignored and every other window ends there at the latest,
        so the node is free from ``until`` on, unless a window that never ends began before
        it: a vehicle that stands there for good is in the way past the cut-off too
        (``lasting=False``: it is not, the node is free from ``until`` on whatever stands
        there; a search's goal, see :class:`SafeIntervalSearch`)."""
        out: list[tuple[float, float]] = []
        free_from = -math.inf
        key = self.resources.get(node, node)
        for start, end, owner in self._nodes.get(key, ()):
            if owner == vehicle:
                continue
            if start >= until:
                break  # sorted by start: all the rest start later
            if start - self.gap >= free_from - EPS:  # (of no length: passing through is safe)
                out.append((free_from, start - self.gap))
            if end == math.inf and lasting and self._stays(key, owner):
                return out  # there for good, past the cut-off too
            free_from = max(free_from, min(end + self.gap, until))
            if free_from == math.inf:
                return out
        out.append((free_from, math.inf))
        return out

    def _stays(self, key: Hashable, vehicle: int) -> bool:
        """Is ``vehicle``'s window that never ends on ``key`` one for good?"""
        return any(owner == vehicle for _, owner in self._lasting.get(key, ()))

    def stands_for_good(
        self, node: int, vehicle: int | None = None, before: float = math.inf
    ) -> bool:
        """Does a vehicle other than ``vehicle`` stand on ``node`` (anywhere in its area)
        for good, from a time before ``before`` on (a node window that never ends)? One
        look-up, whatever the node's other windows."""
        lasting = self._lasting.get(self.resources.get(node, node))
        return lasting is not None and any(
            owner != vehicle and start < before for start, owner in lasting
        )

    def earliest_entry(
        self,
        a: int,
        b: int,
        earliest: float,
        travel: float,
        vehicle: int | None = None,
        latest: float = math.inf,
        until: float = math.inf,
    ) -> float | None:
        """The earliest time >= ``earliest`` at which ``vehicle`` may set off along a -> b
        and take ``travel`` seconds to reach b, by the segment rules (nodes not checked);
        None if that is later than ``latest``. ``until``: as for :meth:`safe_intervals`,
        a set-off at or after it meets no window (windows starting from then on are ignored).

        Each window allows the times before some bound and after another; a time between
        them is refused and the next time that window allows is its after-bound. So jumping
        to the after-bound of whichever window refuses, until none does, finds the earliest
        allowed time, and ends after at most one jump per window."""
        t = earliest
        ahead = self._segments.get((a, b), ())
        oncoming = self._segments.get((b, a), ())
        if not ahead and not oncoming:
            return t if t <= latest + EPS else None  # the common case: nobody uses it
        gap = self.gap
        while t <= latest + EPS and t < math.inf:
            if t >= until:
                return t
            jump = None
            for start, end, owner in oncoming:
                if (
                    owner != vehicle
                    and start < until
                    and t < end + gap - EPS
                    and start < t + travel + gap - EPS
                ):
                    jump = end + gap
                    break
            if jump is None:
                for w in ahead:
                    start, end, owner = w
                    if (
                        owner != vehicle
                        and start < until
                        and not (_follows(t, t + travel, w, gap) or _leads(t, t + travel, w, gap))
                    ):
                        jump = max(start + gap, end + gap - travel)
                        break
            if jump is None:
                return t
            t = min(jump, until)
        return None

    # ----- writing -------------------------------------------------------------------------
    def book(
        self,
        vehicle: int,
        nodes: Iterable[tuple[int, float, float]],
        segments: Iterable[tuple[int, int, float, float]],
        check: bool = True,
        lasting: bool = True,
    ) -> None:
        """Replace ``vehicle``'s windows by these: (node, start, end) and (a, b, start, end).
        All or nothing: on a conflict with another vehicle's window, WindowConflict names
        it and the table, the vehicle's old windows included, is left as it was.
        ``check=False`` books without the rules: for windows that are consistent by
        construction (a search's result, or what vehicles have already been given).
        ``lasting=False``: its node windows that never end are a vehicle that stands there
        only until further notice (it is expected to go on soon, when is not known): past
        a cut-off they end as every other window does."""
        nodes, segments = list(nodes), list(segments)
        if check:
            self.check(vehicle, nodes, segments)
        self.release(vehicle)
        nodes = [(self.resources.get(n, n), start, end) for n, start, end in nodes]
        for node, start, end in nodes:
            bisect.insort(self._nodes.setdefault(node, []), (start, end, vehicle))
            if end == math.inf and lasting:
                self._lasting.setdefault(node, []).append((start, vehicle))
        for a, b, start, end in segments:
            bisect.insort(self._segments.setdefault((a, b), []), (start, end, vehicle))
        self._booked[vehicle] = ([n for n, _, _ in nodes], [(a, b) for a, b, _, _ in segments])

    def check(
        self,
        vehicle: int,
        nodes: Iterable[tuple[int, float, float]],
        segments: Iterable[tuple[int, int, float, float]],
    ) -> None:
        """WindowConflict naming the first of these windows, (node, start, end) and (a, b,
        start, end), that breaks the rules against another vehicle's; the table is not
        changed (a plan from elsewhere is checked so before it is booked)."""
        for node, start, end in nodes:
            _check_interval(start, end, f"node {node}")
            key = self.resources.get(node, node)
            for w in map(Window._make, self._nodes.get(key, ())):
                if w.vehicle != vehicle and _overlap(start, end, w, self.gap):
                    where = f"node {node}" if key == node else f"node {node} (area {key})"
                    raise WindowConflict(
                        f"vehicle {vehicle} on {where} during [{start:g}, {end:g}] meets "
                        f"vehicle {w.vehicle}'s window [{w.start:g}, {w.end:g}] (gap {self.gap:g} s)"
                    )
        for a, b, start, end in segments:
            _check_interval(start, end, f"segment {a}->{b}")
            for w in map(Window._make, self._segments.get((b, a), ())):
                if w.vehicle != vehicle and _overlap(start, end, w, self.gap):
                    raise WindowConflict(
                        f"vehicle {vehicle} on {a}->{b} during [{start:g}, {end:g}] meets "
                        f"vehicle {w.vehicle} head-on ({b}->{a} during [{w.start:g}, {w.end:g}])"
                    )
            for w in map(Window._make, self._segments.get((a, b), ())):
                if w.vehicle != vehicle and not (
                    _follows(start, end, w, self.gap) or _leads(start, end, w, self.gap)
                ):
                    raise WindowConflict(
                        f"vehicle {vehicle} on {a}->{b} during [{start:g}, {end:g}] would overtake "
                        f"or crowd vehicle {w.vehicle} ([{w.start:g}, {w.end:g}], gap {self.gap:g} s)"
                    )

    def release(self, vehicle: int) -> None:
        """Drop every window of ``vehicle`` (its plan is void: replanned, withdrawn)."""
        nodes, segments = self._booked.pop(vehicle, ((), ()))
        for node in set(nodes):
            _drop(self._nodes, node, lambda w: w[2] == vehicle)
            if node in self._lasting:
                _drop(self._lasting, node, lambda w: w[1] == vehicle)
        for key in set(segments):
            _drop(self._segments, key, lambda w: w[2] == vehicle)

    def expire(self, now: float) -> int:
        """Drop the windows that ended before ``now`` (minus the gap, which still guards
        them); returns how many. A vehicle's later windows stay."""
        before = len(self)
        cutoff = now - self.gap
        for table in (self._nodes, self._segments):
            for key in list(table):
                _drop(table, key, lambda w: w[1] < cutoff)
        for vehicle, (nodes, segments) in list(self._booked.items()):
            kept_nodes = [
                n for n in set(nodes) if any(w[2] == vehicle for w in self._nodes.get(n, ()))
            ]
            kept_segments = [
                s for s in set(segments) if any(w[2] == vehicle for w in self._segments.get(s, ()))
            ]
            if kept_nodes or kept_segments:
                self._booked[vehicle] = (kept_nodes, kept_segments)
            else:
                del self._booked[vehicle]
        return before - len(self)


def _check_interval(start: float, end: float, where: str) -> None:
    if math.isnan(start) or math.isnan(end) or start == math.inf or end < start:
        raise ValueError(
            f"{where}: a window needs start <= end and a finite start, got [{start}, {end}]"
        )


def _overlap(start: float, end: float, w: _Stored, gap: float) -> bool:
    """Do [start, end] and w come closer than ``gap``?"""
    return start < w[1] + gap - EPS and w[0] < end + gap - EPS


def _follows(start: float, end: float, w: _Stored, gap: float) -> bool:
    """Does a traversal [start, end] keep ``gap`` behind w on the same segment?"""
    return start >= w[0] + gap - EPS and end >= w[1] + gap - EPS


def _leads(start: float, end: float, w: _Stored, gap: float) -> bool:
    return w[0] >= start + gap - EPS and w[1] >= end + gap - EPS


def _drop(table: dict, key, gone) -> None:
    windows = [w for w in table[key] if not gone(w)]
    if windows:
        table[key] = windows
    else:
        del table[key]
