"""The plant graph: decision points (nodes) and lane segments (edges), immutable once built.

Node ids are the plant's own integers (they may have holes, e.g. MovingAI cell ids of a map
with obstacles); internally every node also has a dense index 0..n-1, and every directed,
routable *arc* an index, so blockades and penalties are plain array lookups. A segment
that can be driven both ways is two arcs. Non-routable segments (a return lane) exist for
driving and drawing but never appear in the routing graph.

Besides the graph, a plant carries what dispatching needs to know about places: queue
nodes (a waiting place off the lanes before a station), cluster zones (the nodes around a
logistic unit, where a vehicle's next order is frozen) and single-vehicle areas (groups of
nodes at most one vehicle may occupy at a time, such as a transfer station and its approach).

The fingerprint is a hash of everything routing and dispatching depend on: a block that
precomputed something for one plant can tell when it is handed another.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from .errors import TopologyError

ROLES = ("transit", "station", "entry", "exit", "charger", "parking", "queue")
TARGET_ROLES = ("station", "exit", "charger")  # default final targets of routes
PORTS = ("N", "E", "S", "W")


@dataclass(frozen=True, slots=True)
class Node:
    id: int
    name: str = ""
    x: float = 0.0
    y: float = 0.0
    role: str = "transit"
    functions: tuple[int, ...] = ()  # function ids a station provides
    queue_for: int | None = None  # role "queue": the station this node is a waiting place of
    zone: int | None = None  # the function whose cluster zone this node lies in
    area: str | None = None  # the single-vehicle area this node belongs to


@dataclass(frozen=True, slots=True)
class Edge:
    source: int
    target: int
    length: float
    max_speed: float | None = None
    bidirectional: bool = True
    port_source: str | None = None  # compass port at the source end
    port_target: str | None = None
    routable: bool = True
    # a two-way edge whose 'from' -> 'to' direction is preferred (a highway lane): routing
    # prices driving the other way higher (the fleet's ``highway_factor``), so the flows of
    # a crowded plant keep apart without closing any lane
    highway: bool = False


@dataclass(frozen=True)
class Plant:
    """An immutable plant graph. Build it with ``Plant.build`` (validates) or a loader."""

    nodes: tuple[Node, ...]
    edges: tuple[Edge, ...]
    name: str = "plant"
    functions: dict[int, str] = field(default_factory=dict)  # function id -> name
    warnings: tuple[str, ...] = ()

    @classmethod
    def build(
        cls,
        nodes: Iterable[Node],
        edges: Iterable[Edge],
        name: str = "plant",
        functions: dict[int, str] | None = None,
        source: str | None = None,
    ) -> Plant:
        """Validate and build; TopologyError naming ``source`` and the offending item."""
        from .validate import validate  # validation needs the built graph

        plant = cls(tuple(nodes), tuple(edges), name, dict(functions or {}))
        warnings = validate(plant, source)
        object.__setattr__(plant, "warnings", tuple(warnings))
        return plant

    # ----- ids and indices -------------------------------------------------------------
    @cached_property
    def ids(self) -> np.ndarray:
        """Node id of each dense index."""
        return np.array([n.id for n in self.nodes], dtype=np.int64)

    @cached_property
    def index(self) -> dict[int, int]:
        """Dense index of each node id."""
        return {n.id: i for i, n in enumerate(self.nodes)}

    def node(self, node_id: int) -> Node:
        try:
            return self.nodes[self.index[node_id]]
        except KeyError:
            raise TopologyError(f"unknown node {node_id}", where=self.name) from None

    def idx(self, node_id: int) -> int:
        """Dense index of a node id; TopologyError naming the id if there is no such node."""
        try:
            return self.index[node_id]
        except (KeyError, TypeError):
            raise TopologyError(f"unknown node {node_id!r}", where=self.name) from None

    @property
    def n(self) -> int:
        return len(self.nodes)

    # ----- the routing graph ----------------------------------------------------------
    @cached_property
    def arcs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directed routable arcs as (source index, target index, length) arrays."""
        src, dst, length = [], [], []
        index = self.index
        for e in self.edges:
            if not e.routable:
                continue
            u, v = index[e.source], index[e.target]
            src.append(u)
            dst.append(v)
            length.append(e.length)
            if e.bidirectional:
                src.append(v)
                dst.append(u)
                length.append(e.length)
        return (
            np.array(src, dtype=np.int64),
            np.array(dst, dtype=np.int64),
            np.array(length, dtype=np.float64),
        )

    @cached_property
    def arc_max_speed(self) -> np.ndarray:
        """Speed limit of every arc in m/s, in the order of ``arcs`` (inf where its segment
        sets none)."""
        limits = []
        for e in self.edges:
            if not e.routable:
                continue
            limit = math.inf if e.max_speed is None else e.max_speed
            limits.extend((limit, limit) if e.bidirectional else (limit,))
        return np.array(limits, dtype=np.float64)

    @cached_property
    def against_highway(self) -> np.ndarray:
        """For every arc, in the order of ``arcs``: does it drive against its edge's
        preferred direction (the 'to' -> 'from' arc of a highway edge)?"""
        against = []
        for e in self.edges:
            if not e.routable:
                continue
            against.extend((False, e.highway) if e.bidirectional else (False,))
        return np.array(against, dtype=bool)

    @property
    def n_arcs(self) -> int:
        return len(self.arcs[0])

    @cached_property
    def csr(self) -> sp.csr_array:
        """Routable adjacency, lengths as weights (parallel arcs: the shortest one counts).

        Built from coordinates, so a length of 0 stays an explicit entry, which csgraph
        treats as a zero-length edge (not as "no edge", as it would in a dense matrix)."""
        src, dst, length = self.arcs
        order = np.lexsort((length, dst, src))  # for each (u, v), the shortest arc first
        src, dst, length = src[order], dst[order], length[order]
        keep = np.ones(len(src), dtype=bool)
        keep[1:] = (src[1:] != src[:-1]) | (dst[1:] != dst[:-1])
        return sp.csr_array((length[keep], (src[keep], dst[keep])), shape=(self.n, self.n))

    @cached_property
    def neighbors(self) -> list[tuple[tuple[int, int, float], ...]]:
        """For each node index: (neighbour index, arc id, length) of its routable out-arcs.

        Python tuples, because an A* step touches one node's few arcs and numpy element
        access from Python costs more than the work itself."""
        src, dst, length = self.arcs
        out: list[list[tuple[int, int, float]]] = [[] for _ in range(self.n)]
        for arc, (u, v, w) in enumerate(
            zip(src.tolist(), dst.tolist(), length.tolist(), strict=True)
        ):
            out[u].append((v, arc, w))
        return [tuple(a) for a in out]

    @cached_property
    def arc_index(self) -> dict[tuple[int, int], list[int]]:
        """O(1) lookup: (source id, target id) -> the arc ids of that directed segment."""
        src, dst, _ = self.arcs
        ids = self.ids
        lookup: dict[tuple[int, int], list[int]] = {}
        for arc, (u, v) in enumerate(zip(src.tolist(), dst.tolist(), strict=True)):
            lookup.setdefault((int(ids[u]), int(ids[v])), []).append(arc)
        return lookup

    def arcs_between(self, a: int, b: int, both_ways: bool = True) -> list[int]:
        """Arc ids of the segment a -> b (and b -> a); TopologyError if there is none."""
        for node in (a, b):
            if isinstance(node, bool) or not isinstance(node, int | np.integer):
                raise TopologyError(
                    f"node ids are integers, got {node!r} ({type(node).__name__})",
                    where=self.name,
                )
        arcs = list(self.arc_index.get((a, b), []))
        if both_ways:
            arcs += self.arc_index.get((b, a), [])
        if not arcs:
            raise TopologyError(f"no routable segment between nodes {a} and {b}", where=self.name)
        return arcs

    # ----- roles and targets ----------------------------------------------------------
    def with_role(self, *roles: str) -> list[int]:
        return [n.id for n in self.nodes if n.role in roles]

    @property
    def targets(self) -> list[int]:
        """Default final targets of routes: stations, exits and chargers."""
        return self.with_role(*TARGET_ROLES)

    def stations_for(self, function: int) -> list[int]:
        """The function cluster: every node that provides ``function``."""
        return [n.id for n in self.nodes if function in n.functions]

    # ----- dispatching: queues, cluster zones, single-vehicle areas --------------------
    @cached_property
    def queues(self) -> dict[int, tuple[int, ...]]:
        """Station id -> its queue nodes, in plant order (stations without one left out)."""
        out: dict[int, list[int]] = {}
        for n in self.nodes:
            if n.queue_for is not None:
                out.setdefault(n.queue_for, []).append(n.id)
        return {station: tuple(queue) for station, queue in out.items()}

    @cached_property
    def zones(self) -> dict[int, frozenset[int]]:
        """Function id -> the node ids of its cluster zone: the nodes marked with that zone
        and the nodes providing the function (a station lies in its own unit's zone), for
        every function of the plant. Without marks a zone is just the unit's stations."""
        members: dict[int, set[int]] = {}
        for n in self.nodes:
            for function in n.functions:
                members.setdefault(function, set()).add(n.id)
            if n.zone is not None:
                members.setdefault(n.zone, set()).add(n.id)
        return {function: frozenset(ids) for function, ids in sorted(members.items())}

    @cached_property
    def areas(self) -> dict[str, tuple[int, ...]]:
        """Area name -> its node ids, in plant order."""
        out: dict[str, list[int]] = {}
        for n in self.nodes:
            if n.area is not None:
                out.setdefault(n.area, []).append(n.id)
        return {name: tuple(members) for name, members in out.items()}

    @cached_property
    def positions(self) -> np.ndarray:
        return np.array([(n.x, n.y) for n in self.nodes], dtype=np.float64).reshape(-1, 2)

    @cached_property
    def heuristic_scale(self) -> dict[str, float]:
        """Largest factor that keeps the Euclidean and Manhattan distances admissible:
        min over arcs of length / distance between the end positions (at most 1)."""
        src, dst, length = self.arcs
        delta = np.abs(self.positions[src] - self.positions[dst])
        scales = {}
        for name, dist in (
            ("euclidean", np.hypot(delta[:, 0], delta[:, 1])),
            ("manhattan", delta.sum(axis=1)),
        ):
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(dist > 0, length / np.where(dist > 0, dist, 1), np.inf)
            scales[name] = float(min(1.0, ratio.min())) if len(ratio) else 1.0
        return scales

    @cached_property
    def fingerprint(self) -> str:
        """Hash of everything routing depends on: nodes and edges in their order (which
        fixes the node and arc indices that tables and constraints are built on), roles,
        functions, lengths as floats (so 1 and 1.0 are the same plant); and the queue, zone
        and area of the nodes that have them, which dispatching depends on."""
        digest = hashlib.sha256()
        for n in self.nodes:
            line = f"n{n.id}|{n.role}|{n.functions}"
            if n.queue_for is not None or n.zone is not None or n.area is not None:
                line += f"|{n.queue_for}|{n.zone}|{n.area!r}"  # only then: grids stay fast
            digest.update(f"{line}\n".encode())
        for e in self.edges:
            length = float(e.length).hex()
            line = f"e{e.source}|{e.target}|{length}|{e.bidirectional}|{e.routable}"
            if e.highway:
                line += "|highway"  # only then: plants without highways keep their prints
            digest.update(f"{line}\n".encode())
        return digest.hexdigest()[:16]

    def summary(self) -> dict[str, object]:
        roles = {r: len(self.with_role(r)) for r in ROLES if self.with_role(r)}
        return {
            "name": self.name,
            "nodes": self.n,
            "edges": len(self.edges),
            "routable_arcs": self.n_arcs,
            "roles": roles,
            "functions": {
                f: {"name": self.functions.get(f, ""), "stations": self.stations_for(f)}
                for f in sorted({f for n in self.nodes for f in n.functions})
            },
            "targets": len(self.targets),
            "queues": {station: list(queue) for station, queue in self.queues.items()},
            "zones": {function: sorted(zone) for function, zone in self.zones.items()},
            "areas": {name: list(members) for name, members in self.areas.items()},
            "fingerprint": self.fingerprint,
            "warnings": list(self.warnings),
        }


def route_cost(plant: Plant, route: Sequence[int]) -> float:
    """Length of a route given as node ids; TopologyError if a step is not a routable arc."""
    total = 0.0
    for a, b in zip(route, route[1:], strict=False):
        arcs = plant.arc_index.get((a, b))
        if not arcs:
            raise TopologyError(
                f"route step {a} -> {b} is not a routable segment", where=plant.name
            )
        total += min(float(plant.arcs[2][arc]) for arc in arcs)
    return total


MAX_LENGTH = 1e12  # far beyond any plant, small enough that sums of lengths stay finite
MAX_NODE_ID = 2**31 - 1


def is_finite_length(value: object) -> bool:
    """A length (or speed) the routing can add up: a number in 0..MAX_LENGTH."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return 0 <= float(value) <= MAX_LENGTH
    except OverflowError:  # an int too large for a float
        return False
