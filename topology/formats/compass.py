"""The thesis' compass node list: one record per node with its neighbour on each port.

    # id   N  dist   E  dist   S  dist   W  dist   [key=value ...]
    0     -1  0      1  1.0   -1  0     -1  0      role=entry functions=0
    1     -1  0      2  1.0    6  0.8    0  1.0

-1 means "not connected". Each record lists the arcs leaving the node; a segment listed
from both ends with the same distance becomes one two-way edge, otherwise one-way edges.
Optional key=value tokens: role, name, functions (joined by '+', e.g. 2+3), x, y. Without x/y the
positions are laid out from the ports (N is up), for drawing only.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

from ..errors import TopologyError
from ..model import Edge, Node, Plant
from .structured import read_text

PORT_ORDER = ("N", "E", "S", "W")
STEP = {"N": (0.0, -1.0), "E": (1.0, 0.0), "S": (0.0, 1.0), "W": (-1.0, 0.0)}


def load_nodes(path: Path) -> Plant:
    source = str(path)
    records: dict[int, tuple[dict[str, object], list[tuple[str, int, float]], int]] = {}
    for number, raw in enumerate(read_text(path).splitlines(), start=1):
        line = raw.split("#", 1)[0].replace(",", " ").split()
        if not line:
            continue
        where = f"line {number}"
        fields = [t for t in line if "=" not in t]
        options = dict(t.split("=", 1) for t in line if "=" in t)
        if len(fields) != 9:
            raise TopologyError(
                f"expected id and 4 x (neighbour, distance), got {len(fields)} fields",
                source,
                where,
            )
        try:
            node_id = int(fields[0])
            ports = [
                (PORT_ORDER[k], int(fields[1 + 2 * k]), float(fields[2 + 2 * k])) for k in range(4)
            ]
        except ValueError:
            raise TopologyError(
                "ids must be integers and distances numbers", source, where
            ) from None
        if node_id in records:
            raise TopologyError(
                f"node {node_id} is listed twice (first on line {records[node_id][2]})",
                source,
                where,
            )
        records[node_id] = (options, [p for p in ports if p[1] != -1], number)
    nodes = [
        _node(node_id, options, source, f"line {line}")
        for node_id, (options, _p, line) in records.items()
    ]
    edges: list[Edge] = []
    done: set[tuple[int, int, str]] = set()
    for node_id, (_options, ports, line) in records.items():
        for port, other, dist in ports:
            if other not in records:
                raise TopologyError(
                    f"port {port} of node {node_id}: unknown node {other}", source, f"line {line}"
                )
            if (node_id, other, port) in done:
                continue
            back = [
                (p, d)
                for p, o, d in records[other][1]
                if o == node_id and (other, node_id, p) not in done
            ]
            match = next(((p, d) for p, d in back if d == dist), None)
            if match:
                done.add((other, node_id, match[0]))
                edges.append(Edge(node_id, other, dist, port_source=port, port_target=match[0]))
            else:
                edges.append(Edge(node_id, other, dist, bidirectional=False, port_source=port))
            done.add((node_id, other, port))
    if not any(("x" in o or "y" in o) for o, _p, _l in records.values()):
        nodes = _layout(nodes, edges)
    return Plant.build(nodes, edges, name=path.stem, source=source)


def _node(node_id: int, options: dict[str, object], source: str, where: str) -> Node:
    unknown = set(options) - {"role", "name", "functions", "x", "y"}
    if unknown:
        raise TopologyError(f"unknown option(s): {', '.join(sorted(unknown))}", source, where)
    try:
        functions = tuple(int(f) for f in str(options.get("functions", "")).split("+") if f)
        return Node(
            node_id,
            name=str(options.get("name", "")),
            x=float(options.get("x", 0.0)),
            y=float(options.get("y", 0.0)),
            role=str(options.get("role", "transit")),
            functions=functions,
        )
    except ValueError:
        raise TopologyError(
            "x, y must be numbers and functions integers joined by '+'", source, where
        ) from None


def _layout(nodes: list[Node], edges: list[Edge]) -> list[Node]:
    """Positions from ports and distances, breadth first from the first node."""
    if not nodes:
        return nodes
    step: dict[int, list[tuple[int, str, float]]] = {}
    flip = {"N": "S", "S": "N", "E": "W", "W": "E"}
    for e in edges:
        if e.port_source:
            step.setdefault(e.source, []).append((e.target, e.port_source, e.length))
        if e.port_target:
            step.setdefault(e.target, []).append((e.source, e.port_target, e.length))
        elif e.port_source:
            step.setdefault(e.target, []).append((e.source, flip[e.port_source], e.length))
    position = {nodes[0].id: (0.0, 0.0)}
    queue = deque([nodes[0].id])
    while queue:
        here = queue.popleft()
        x, y = position[here]
        for other, port, dist in step.get(here, []):
            if other not in position:
                dx, dy = STEP[port]
                position[other] = (x + dx * max(dist, 0.1), y + dy * max(dist, 0.1))
                queue.append(other)
    return [
        Node(n.id, n.name, *position.get(n.id, (0.0, 0.0)), role=n.role, functions=n.functions)
        for n in nodes
    ]
