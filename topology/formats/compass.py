"""The thesis' compass node list: one record per node with its neighbour on each port.

    # id   N  dist   E  dist   S  dist   W  dist   [key=value ...]
    0     -1  0      1  1.0   -1  0     -1  0      role=entry functions=0
    1     -1  0      2  1.0    6  0.8    0  1.0

-1 means "not connected". Each record lists the arcs leaving the node; a segment listed
from both ends with the same distance becomes one two-way edge, otherwise one-way edges.
Optional key=value tokens: role, name, functions (joined by '+', e.g. 2+3), x, y, each at
most once. Without x/y the positions are laid out from the ports (N is up), for drawing only.
Numbers are ASCII decimal (see numbers.py): ``٣`` is not node 3, ``nan`` is not a distance.
"""

from __future__ import annotations

import re
from collections import deque
from pathlib import Path
from typing import TypeVar

from ..errors import TopologyError
from ..model import MAX_NODE_ID, Edge, Node, Plant
from ..validate import escaped_name, text_problem
from .numbers import parse_float, parse_int, shown
from .structured import read_text, text_lines

PORT_ORDER = ("N", "E", "S", "W")
T = TypeVar("T", int, float)
OPTIONS = ("role", "name", "functions", "x", "y")
STEP = {"N": (0.0, -1.0), "E": (1.0, 0.0), "S": (0.0, 1.0), "W": (-1.0, 0.0)}


def load_nodes(path: str | Path) -> Plant:
    path = Path(path)
    source = str(path)
    records: dict[int, tuple[dict[str, str], list[tuple[str, int, float]], int]] = {}
    for number, raw in enumerate(text_lines(read_text(path)), start=1):
        line = raw.split("#", 1)[0].replace(",", " ").split()
        if not line:
            continue
        where = f"line {number}"
        fields = [t for t in line if "=" not in t]
        if len(fields) != 9:
            raise TopologyError(
                f"expected id and 4 x (neighbour, distance), got {len(fields)} fields",
                source,
                where,
            )
        node_id = _integer(fields[0], "node id", source, where)
        if not 0 <= node_id <= MAX_NODE_ID:
            raise TopologyError(f"node id must be 0..{MAX_NODE_ID}, got {node_id}", source, where)
        ports = []
        for k, port in enumerate(PORT_ORDER):
            other = _integer(fields[1 + 2 * k], f"{port} neighbour", source, where)
            dist = _number(fields[2 + 2 * k], f"{port} distance", source, where)
            if other == -1:
                continue  # not connected: the distance is a placeholder
            if dist < 0:
                raise TopologyError(f"{port} distance must be >= 0, got {dist:g}", source, where)
            ports.append((port, other, dist))
        if node_id in records:
            raise TopologyError(
                f"node {node_id} is listed twice (first on line {records[node_id][2]})",
                source,
                where,
            )
        records[node_id] = (_options(line, source, where), ports, number)
    nodes = [
        _node(node_id, options, source, f"line {line}")
        for node_id, (options, _p, line) in records.items()
    ]
    edges: list[Edge] = []
    done: set[tuple[int, int, str]] = set()
    for node_id, (_given, ports, line) in records.items():
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
    placed = [("x" in o) + ("y" in o) for o, _p, _l in records.values()]
    if not any(placed):
        nodes = _layout(nodes, edges)
    elif not all(count == 2 for count in placed):
        # some at their given place, the others at (0, 0): a drawing that lies
        line = next(r[2] for r, n in zip(records.values(), placed, strict=True) if n < 2)
        raise TopologyError(
            "x and y are given on some nodes but not both here: give them on every node, "
            "or on none (positions are then laid out from the ports)",
            source,
            f"line {line}",
        )
    try:
        return Plant.build(nodes, edges, name=escaped_name(path.stem), source=source)
    except TopologyError as exc:
        raise _on_its_line(exc, [line for _o, _p, line in records.values()]) from None


def _on_its_line(exc: TopologyError, lines: list[int]) -> TopologyError:
    """A check of the plant names a node by its place in the list ("nodes[3] (id 7)"); in
    a file of lines, its line says where to look."""
    found = re.match(r"nodes\[(\d+)\](.*)", exc.where or "")
    if found is None or int(found[1]) >= len(lines):
        return exc
    return TopologyError(exc.message, exc.source, f"line {lines[int(found[1])]}{found[2]}")


def _integer(text: str, field: str, source: str, where: str) -> int:
    return _parsed(parse_int(text), text, field, source, where)


def _number(text: str, field: str, source: str, where: str) -> float:
    return _parsed(parse_float(text), text, field, source, where)


def _parsed(value: T | None, text: str, field: str, source: str, where: str) -> T:
    if value is None:
        raise TopologyError(
            f"ids must be integers and distances numbers (ASCII digits): {field} is {shown(text)}",
            source,
            where,
        )
    return value


def _options(tokens: list[str], source: str, where: str) -> dict[str, str]:
    """The key=value tokens of a record; a key given twice is an error, not "the last wins"."""
    options: dict[str, str] = {}
    for token in tokens:
        if "=" not in token:
            continue
        key, value = token.split("=", 1)
        if key not in OPTIONS:
            raise TopologyError(
                f"unknown option {shown(key)} (known: {', '.join(OPTIONS)})", source, where
            )
        if key in options:
            raise TopologyError(
                f"option {key} given twice ({key}={shown(options[key])} and {key}={shown(value)})",
                source,
                where,
            )
        options[key] = value
    return options


def _node(node_id: int, options: dict[str, str], source: str, where: str) -> Node:
    functions = []
    for text in options.get("functions", "").split("+") if options.get("functions") else []:
        function = parse_int(text)
        if function is None or function < 0:
            raise TopologyError(
                f"functions must be integers >= 0 joined by '+' (ASCII digits), got "
                f"{shown(options['functions'])}",
                source,
                where,
            )
        functions.append(function)
    position = {}
    for axis in ("x", "y"):
        text = options.get(axis, "0")
        value = parse_float(text)
        if value is None:
            raise TopologyError(
                f"{axis} must be a finite number (ASCII digits), got {shown(text)}", source, where
            )
        position[axis] = value
    name = options.get("name", "")
    problem = text_problem(name)  # here too, not only in validation: this knows the line
    if problem:
        raise TopologyError(f"name {problem}", source, where)
    return Node(
        node_id,
        name=name,
        x=position["x"],
        y=position["y"],
        role=options.get("role", "transit"),
        functions=tuple(functions),
    )


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
