"""The human-editable plant formats: TOML (primary) and JSON, one schema (docs/plant-format.md).

name = "model-plant"
[functions]
2 = "drill"
[[nodes]]
id = 16
name = "drill-1"
x = 1.5
y = 0.0
role = "station"
functions = [2]
zone = 2                 # optional: the function whose cluster zone the node lies in
area = "drill-1"         # optional: a single-vehicle area
[[nodes]]
id = 17
role = "queue"
queue_for = 16           # a queue node: the station it is a waiting place of
[[edges]]
from = 1
to = 16
length = 0.5
directed = true          # default false: drivable both ways
ports = ["E", "W"]       # optional: compass port at 'from', at 'to'
max_speed = 0.4          # optional, m/s
routable = true          # default true; false = a lane routing ignores (return lane)
"""

from __future__ import annotations

import json
import os
import stat
import tomllib
from json.decoder import WHITESPACE, scanstring
from json.scanner import py_make_scanner
from pathlib import Path
from typing import Any

from ..errors import TopologyError
from ..limits import MAX_FILE_BYTES
from ..model import Edge, Node, Plant
from .numbers import parse_int, shown

NODE_KEYS = {"id", "name", "x", "y", "role", "functions", "queue_for", "zone", "area"}
EDGE_KEYS = {"from", "to", "length", "max_speed", "directed", "ports", "routable", "highway"}
TOP_KEYS = {"name", "functions", "nodes", "edges"}


def read_text(path: Path) -> str:
    try:
        mode = os.stat(path).st_mode
        if not stat.S_ISREG(mode):  # a device never ends, a named pipe waits for a writer
            raise TopologyError("not a regular file (a device, a pipe or a socket)", str(path))
        with open(path, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)  # bounded: a huge file or a device never ends
    except OSError as exc:
        raise TopologyError(f"cannot read plant file: {exc.strerror or exc}", str(path)) from None
    if len(raw) > MAX_FILE_BYTES:
        raise TopologyError(
            f"larger than {MAX_FILE_BYTES:,} bytes, the limit for plant files "
            "(docs/plant-format.md, Size limits)",
            str(path),
        )
    if b"\0" in raw:
        raise TopologyError("binary data, not a plant file", str(path))
    try:
        return raw.decode("utf-8-sig")  # an editor on Windows may start it with a BOM
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise TopologyError(f"line {line}: not UTF-8 text (byte {exc.start})", str(path)) from None


def text_lines(text: str) -> list[str]:
    """The lines of a line-based plant file as an editor numbers them: split at LF (CRLF
    too), not at the form feeds, file separators and Unicode line separators that
    ``str.splitlines`` also splits at, so a stray one is reported as what it is, in the
    line an editor shows. A newline at the end ends the last line, it starts none."""
    lines = text.split("\n")
    if lines[-1] == "":
        lines.pop()
    return [line.removesuffix("\r") for line in lines]


def load_toml(path: Path) -> Plant:
    text = read_text(path)  # its own errors are already TopologyErrors
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TopologyError(f"invalid TOML: {exc}", str(path)) from None
    except (ValueError, RecursionError) as exc:  # a 5000-digit integer, nesting thousands deep
        raise TopologyError(f"unreadable TOML: {str(exc)[:80]}", str(path)) from None
    return from_dict(data, str(path))


def load_json(path: Path) -> Plant:
    text = read_text(path)
    try:
        data = json.loads(text, object_pairs_hook=_unique_keys)
    except _DuplicateKey as exc:
        raise _duplicate_key_error(text, exc.key, str(path)) from None
    except json.JSONDecodeError as exc:
        raise TopologyError(
            f"invalid JSON: {exc.msg}", str(path), f"line {exc.lineno}, column {exc.colno}"
        ) from None
    except (ValueError, RecursionError) as exc:  # a 5000-digit integer, nesting thousands deep
        raise TopologyError(f"unreadable JSON: {str(exc)[:80]}", str(path)) from None
    return from_dict(data, str(path))


class _DuplicateKey(Exception):
    """An object of a JSON document gives ``key`` twice (at ``first`` and ``again`` in the
    text, where those are known)."""

    def __init__(self, key: str, first: int = -1, again: int = -1) -> None:
        super().__init__(key)
        self.key, self.first, self.again = key, first, again


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook``: an object as a dict, _DuplicateKey if a key repeats. Python's
    json keeps the last value of a repeated key, so an edit that added a second ``"id"``
    would change the plant without a word."""
    table = dict(pairs)
    if len(table) != len(pairs):
        seen: set[str] = set()
        for key, _value in pairs:
            if key in seen:
                raise _DuplicateKey(key)
            seen.add(key)
    return table


class _KeyLocator(json.JSONDecoder):
    """Reads a JSON document with json's own pure-Python scanner, its object parser
    replaced by one that raises _DuplicateKey with the positions of both keys at the first
    key given twice. The fast C scanner that ``json.loads`` uses reports no positions to an
    ``object_pairs_hook``, so this slower reading is only done on a document known to have
    a repeated key, and the objects' values are not kept."""

    def __init__(self) -> None:
        super().__init__()
        self.parse_object = self._object
        self.scan_once = py_make_scanner(self)

    @staticmethod
    def _object(
        s_and_end: tuple[str, int], strict: bool, scan_once: Any, *_hooks: Any
    ) -> tuple[None, int]:
        text, end = s_and_end
        seen: dict[str, int] = {}
        end = WHITESPACE.match(text, end).end()
        while text[end] != "}":
            key, after = scanstring(text, end + 1, strict)  # text[end] is the opening quote
            if key in seen:
                raise _DuplicateKey(key, seen[key], end)
            seen[key] = end
            colon = WHITESPACE.match(text, after).end()
            _value, end = scan_once(text, WHITESPACE.match(text, colon + 1).end())
            end = WHITESPACE.match(text, end).end()
            if text[end] == ",":
                end = WHITESPACE.match(text, end + 1).end()
        return None, end + 1


def _duplicate_key_error(text: str, key: str, source: str) -> TopologyError:
    """The error for a JSON document with a repeated key, with the line and column of the
    first repetition and of the key's first occurrence. ``json.loads`` read the document
    up to the end of an object with a repeated key, so the text up to the first repetition
    is valid JSON; the locating reader may still run out of stack in a document nested
    hundreds deep, and then the key alone is named."""
    first = again = -1
    try:
        _KeyLocator().decode(text)
    except _DuplicateKey as exc:
        key, first, again = exc.key, exc.first, exc.again
    except RecursionError:
        pass
    if again < 0:
        return TopologyError(f"duplicate key {shown(key)} in one object", source)
    return TopologyError(
        f"duplicate key {shown(key)} in one object (first on {_line_column(text, first)}): "
        "each key may be given once",
        source,
        _line_column(text, again),
    )


def _line_column(text: str, position: int) -> str:
    """``line L, column C`` of a position in the text, counted from 1 as an editor does."""
    line = text.count("\n", 0, position) + 1
    column = position - text.rfind("\n", 0, position)  # rfind is -1 on the first line
    return f"line {line}, column {column}"


def _typed(value: Any, kinds: type | tuple[type, ...], what: str, source: str, where: str) -> Any:
    if isinstance(value, bool) and bool not in (kinds if isinstance(kinds, tuple) else (kinds,)):
        raise TopologyError(f"{what} must be {_kind_name(kinds)}, got {value!r}", source, where)
    if not isinstance(value, kinds):
        raise TopologyError(f"{what} must be {_kind_name(kinds)}, got {value!r}", source, where)
    return value


def _kind_name(kinds: type | tuple[type, ...]) -> str:
    names = {
        int: "an integer",
        float: "a number",
        str: "a string",
        bool: "true or false",
        list: "a list",
    }
    kinds = kinds if isinstance(kinds, tuple) else (kinds,)
    return " or ".join(dict.fromkeys(names.get(k, k.__name__) for k in kinds))


def from_dict(data: Any, source: str) -> Plant:
    """Build a plant from the parsed TOML/JSON document; errors name the key path."""
    if not isinstance(data, dict):
        raise TopologyError("expected a table/object with 'nodes' and 'edges'", source)
    unknown = set(data) - TOP_KEYS
    if unknown:
        hint = (
            " (this looks like a fleet configuration: its plant is the file or sample its "
            "[plant] table names)"
            if "plant" in unknown
            else ""
        )
        raise TopologyError(f"unknown top-level key(s): {_key_list(unknown)}{hint}", source)
    for key in ("nodes", "edges"):
        if key not in data:
            raise TopologyError(f"missing: a plant needs [[{key}]] tables", source, key)
        if not isinstance(data[key], list):
            raise TopologyError(f"'{key}' must be a list of tables", source, key)
    name = _typed(data.get("name", Path(source).stem), str, "name", source, "name")
    functions: dict[int, str] = {}
    spelt: dict[int, str] = {}  # how each id was written, to name a second spelling
    for key, value in _typed(
        data.get("functions", {}), dict, "functions", source, "functions"
    ).items():
        function = parse_int(key)
        if function is None or function < 0:
            raise TopologyError(
                f"function id {key!r} is not an integer >= 0 in ASCII digits", source, "functions"
            )
        if function in functions:
            raise TopologyError(
                f"function id {key!r} is function {function} again (given as {spelt[function]!r})",
                source,
                "functions",
            )
        spelt[function] = key
        functions[function] = _typed(value, str, f"name of function {key}", source, "functions")
    nodes = [_node(item, i, source) for i, item in enumerate(data["nodes"])]
    edges = [_edge(item, i, source) for i, item in enumerate(data["edges"])]
    return Plant.build(nodes, edges, name=name, functions=functions, source=source)


def _check_table(
    item: Any, keys: set[str], required: tuple[str, ...], source: str, where: str
) -> None:
    """A node or edge entry: a table with known keys and the required ones present."""
    if not isinstance(item, dict):
        raise TopologyError("expected a table", source, where)
    unknown = set(item) - keys
    if unknown:
        raise TopologyError(f"unknown key(s): {_key_list(unknown)}", source, where)
    for key in required:
        if key not in item:
            raise TopologyError(f"missing '{key}'", source, where)


def _key_list(keys: set[str]) -> str:
    """Keys for a message: as written, or quoted with escapes where a key has characters
    that are not printable, so that no control sequence of a file reaches the terminal."""
    return ", ".join(key if key.isprintable() else shown(key) for key in sorted(keys))


def _node(item: Any, i: int, source: str) -> Node:
    where = f"nodes[{i}]"
    _check_table(item, NODE_KEYS, ("id",), source, where)
    functions = _typed(item.get("functions", []), list, "functions", source, where)
    return Node(
        id=_typed(item["id"], int, "id", source, where),
        name=_typed(item.get("name", ""), str, "name", source, where),
        x=_typed(item.get("x", 0.0), (int, float), "x", source, where),
        y=_typed(item.get("y", 0.0), (int, float), "y", source, where),
        role=_typed(item.get("role", "transit"), str, "role", source, where),
        functions=tuple(_typed(f, int, "function id", source, where) for f in functions),
        queue_for=_optional(item, "queue_for", int, source, where),
        zone=_optional(item, "zone", int, source, where),
        area=_optional(item, "area", str, source, where),
    )


def _optional(item: dict[str, Any], key: str, kind: type, source: str, where: str) -> Any:
    """An optional key's value of the given type; absent (or JSON null) is None."""
    value = item.get(key)
    return None if value is None else _typed(value, kind, key, source, where)


def _edge(item: Any, i: int, source: str) -> Edge:
    where = f"edges[{i}]"
    _check_table(item, EDGE_KEYS, ("from", "to", "length"), source, where)
    ports = _typed(item.get("ports", [None, None]), list, "ports", source, where)
    if len(ports) != 2 or not all(p is None or isinstance(p, str) for p in ports):
        raise TopologyError(
            "ports must be a list of two compass letters: [at 'from', at 'to']", source, where
        )
    max_speed = item.get("max_speed")
    return Edge(
        source=_typed(item["from"], int, "from", source, where),
        target=_typed(item["to"], int, "to", source, where),
        length=_typed(item["length"], (int, float), "length", source, where),
        max_speed=None
        if max_speed is None
        else _typed(max_speed, (int, float), "max_speed", source, where),
        bidirectional=not _typed(item.get("directed", False), bool, "directed", source, where),
        port_source=ports[0] or None,  # "" and null both mean "no port"
        port_target=ports[1] or None,
        routable=_typed(item.get("routable", True), bool, "routable", source, where),
        highway=_typed(item.get("highway", False), bool, "highway", source, where),
    )


def to_dict(plant: Plant) -> dict[str, Any]:
    """The document ``from_dict`` reads back (None-valued optional keys left out)."""
    nodes = []
    for n in plant.nodes:
        node: dict[str, Any] = {"id": n.id, "x": n.x, "y": n.y, "role": n.role}
        if n.name:
            node["name"] = n.name
        if n.functions:
            node["functions"] = list(n.functions)
        for key in ("queue_for", "zone", "area"):
            if getattr(n, key) is not None:
                node[key] = getattr(n, key)
        nodes.append(node)
    edges = []
    for e in plant.edges:
        edge: dict[str, Any] = {"from": e.source, "to": e.target, "length": e.length}
        if not e.bidirectional:
            edge["directed"] = True
        if e.port_source or e.port_target:
            edge["ports"] = [e.port_source or "", e.port_target or ""]
        if e.max_speed is not None:
            edge["max_speed"] = e.max_speed
        if not e.routable:
            edge["routable"] = False
        if e.highway:
            edge["highway"] = True
        edges.append(edge)
    return {
        "name": plant.name,
        "functions": {str(k): v for k, v in plant.functions.items()},
        "nodes": nodes,
        "edges": edges,
    }


def dump_json(plant: Plant) -> str:
    return json.dumps(to_dict(plant), indent=1)


def dump_toml(plant: Plant) -> str:
    """TOML text for the schema above (a tiny writer: the schema has only flat tables)."""
    doc = to_dict(plant)
    lines = [f"name = {json.dumps(doc['name'])}", ""]
    if doc["functions"]:
        lines.append("[functions]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in doc["functions"].items()]
        lines.append("")
    for section in ("nodes", "edges"):
        for item in doc[section]:
            lines.append(f"[[{section}]]")
            lines += [f"{key} = {json.dumps(value)}" for key, value in item.items()]
            lines.append("")
    return "\n".join(lines)
