"""Plant validation: structural errors raise, reachability gaps warn.

Errors (TopologyError, naming the file and the node or edge): duplicate node ids, unknown
roles, non-finite positions, edges to unknown nodes, self loops, negative/NaN/inf lengths,
two edges on one compass port of a node, functions on nodes that cannot provide them, a
declared function no station provides, a target that cannot be reached from an entry.
Warnings (returned): a target that some other node cannot reach.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse.csgraph import breadth_first_order, connected_components

from .errors import TopologyError
from .model import MAX_LENGTH, MAX_NODE_ID, PORTS, ROLES, is_finite_length

if TYPE_CHECKING:
    from .model import Plant

FUNCTION_ROLES = ("station", "entry", "exit", "charger")
MAX_REACHABILITY_WARNINGS = 20


def validate(plant: Plant, source: str | None = None) -> list[str]:
    _check_nodes(plant, source)
    _check_edges(plant, source)
    _check_functions(plant, source)
    return _check_reachability(plant, source)


def _finite(value: object) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _short(value: object) -> str:
    """repr() for messages, shortened: a 5000-digit number must not flood the terminal."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"


def _check_nodes(plant: Plant, source: str | None) -> None:
    if not plant.nodes:
        raise TopologyError("the plant has no nodes", source)
    seen: set[int] = set()
    for i, node in enumerate(plant.nodes):
        if (
            isinstance(node.id, bool)
            or not isinstance(node.id, int)
            or not 0 <= node.id <= MAX_NODE_ID
        ):
            raise TopologyError(
                f"node id must be an integer 0..{MAX_NODE_ID}, got {_short(node.id)}",
                source,
                f"nodes[{i}]",
            )
        where = f"nodes[{i}] (id {node.id})"
        if node.id in seen:
            raise TopologyError(f"duplicate node id {node.id}", source, where)
        seen.add(node.id)
        if node.role not in ROLES:
            raise TopologyError(
                f"unknown role {node.role!r} (one of {', '.join(ROLES)})", source, where
            )
        for name, value in (("x", node.x), ("y", node.y)):
            if not _finite(value):
                raise TopologyError(
                    f"{name} must be a finite number, got {_short(value)}", source, where
                )
        for f in node.functions:
            if isinstance(f, bool) or not isinstance(f, int) or not 0 <= f <= MAX_NODE_ID:
                raise TopologyError(
                    f"function ids must be integers 0..{MAX_NODE_ID}, got {_short(f)}",
                    source,
                    where,
                )
        if node.functions and node.role not in FUNCTION_ROLES:
            raise TopologyError(
                f"a {node.role} node cannot provide functions (only {', '.join(FUNCTION_ROLES)})",
                source,
                where,
            )


def _check_edges(plant: Plant, source: str | None) -> None:
    ids = plant.index
    ports_used: dict[tuple[int, str], int] = {}
    for i, edge in enumerate(plant.edges):
        where = f"edges[{i}] ({_short(edge.source)} -> {_short(edge.target)})"
        for end in (edge.source, edge.target):
            if end not in ids:
                raise TopologyError(f"unknown node {_short(end)}", source, where)
        if edge.source == edge.target:
            raise TopologyError("self loop: an edge must join two different nodes", source, where)
        if not is_finite_length(edge.length):
            raise TopologyError(
                f"length must be a finite number >= 0 (at most {MAX_LENGTH:g}), got {_short(edge.length)}",
                source,
                where,
            )
        if edge.max_speed is not None and not (
            is_finite_length(edge.max_speed) and edge.max_speed > 0
        ):
            raise TopologyError(
                f"max_speed must be a finite number > 0, got {_short(edge.max_speed)}",
                source,
                where,
            )
        for node, port in ((edge.source, edge.port_source), (edge.target, edge.port_target)):
            if port is None:
                continue
            if port not in PORTS:
                raise TopologyError(
                    f"port {port!r} at node {node} is not one of N, E, S, W", source, where
                )
            other = ports_used.setdefault((node, port), i)
            if other != i:
                raise TopologyError(
                    f"port {port} of node {node} is already used by edges[{other}]", source, where
                )


def _check_functions(plant: Plant, source: str | None) -> None:
    provided = {f for n in plant.nodes for f in n.functions}
    for function, name in plant.functions.items():
        if function not in provided:
            raise TopologyError(
                f"function {function} ({name}) is provided by no station", source, "functions"
            )


def _check_reachability(plant: Plant, source: str | None) -> list[str]:
    targets = plant.targets
    if not targets or plant.n == 0:
        return []
    csr = plant.csr
    for entry in plant.with_role("entry"):
        reached = set(
            breadth_first_order(
                csr, plant.idx(entry), directed=True, return_predecessors=False
            ).tolist()
        )
        for target in targets:
            if plant.idx(target) not in reached:
                raise TopologyError(
                    f"target {target} cannot be reached from entry {entry}", source, "reachability"
                )
    n_components, _labels = connected_components(csr, directed=True, connection="strong")
    if n_components == 1:
        return []
    # Routes end at exits (vehicles leave over the return lane), so exits need not reach anything.
    must_reach = np.array([n.role != "exit" for n in plant.nodes])
    warnings = []
    reverse = csr.T.tocsr()
    for target in targets[:MAX_REACHABILITY_WARNINGS]:
        reaching = breadth_first_order(
            reverse, plant.idx(target), directed=True, return_predecessors=False
        )
        cut_off = np.setdiff1d(np.flatnonzero(must_reach), reaching)
        if len(cut_off):
            examples = ", ".join(str(int(plant.ids[i])) for i in cut_off[:5])
            warnings.append(
                f"target {target} cannot be reached from {len(cut_off)} node(s), e.g. {examples}"
            )
    if warnings and len(targets) > MAX_REACHABILITY_WARNINGS:
        warnings.append(
            f"(reachability reported for the first {MAX_REACHABILITY_WARNINGS} of {len(targets)} targets)"
        )
    return warnings
