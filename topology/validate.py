"""Plant validation: structural errors raise, reachability gaps warn.

Errors (TopologyError, naming the file and the node or edge): more nodes or edges than the
size limits allow, duplicate node ids, unknown roles, non-finite positions, edges to unknown
nodes, self loops, negative/NaN/inf lengths, two edges on one compass port of a node,
functions on nodes that cannot provide them, a queue node without the station it waits for
(or ``queue_for`` on a node that is no queue, or naming no station), a zone that is no
function of the plant, an empty area name, a declared function no station provides, a
target that cannot be reached from an entry; a name (of the plant, a function, a node, an
area) that is not a string of printable text.
Warnings (returned): a target that some other node cannot reach; an edge that joins the
same two nodes in the same direction(s) as an earlier one (a copy-pasted line).

Each rule is a mask over all nodes or all edges, computed for the whole plant at once: a
grid of a million nodes is checked in a second or two, about ten times faster than a loop
over the objects. The error is the one a loop would have raised: the first item that fails a
rule, with the first rule it fails in the order the rules are listed.
"""

from __future__ import annotations

import math
import unicodedata
from collections.abc import Callable
from itertools import repeat
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse.csgraph import breadth_first_order, connected_components

from .errors import TopologyError
from .limits import check_plant_size
from .model import MAX_LENGTH, MAX_NODE_ID, PORTS, ROLES, is_finite_length

if TYPE_CHECKING:
    from .model import Edge, Node, Plant

FUNCTION_ROLES = ("station", "entry", "exit", "charger")
MAX_REACHABILITY_WARNINGS = 20
MAX_DUPLICATE_WARNINGS = 20

NO_PORT, NOT_A_PORT = -1, -2
PORT_CODES: dict[object, int] = {port: code for code, port in enumerate(PORTS)} | {None: NO_PORT}
Rule = tuple[np.ndarray, Callable[[int], str]]  # (mask of the items that pass, message for item i)


def validate(plant: Plant, source: str | None = None) -> list[str]:
    check_plant_size(len(plant.nodes), len(plant.edges), source)
    _check_nodes(plant, source)
    _check_names(plant, source)
    _check_places(plant, source)
    _check_edges(plant, source)
    _check_functions(plant, source)
    return _duplicate_edges(plant) + _check_reachability(plant, source)


def _raise_first_failure(
    rules: list[Rule], source: str | None, where: Callable[[int], str]
) -> None:
    """TopologyError for the first item that fails a rule, with the first rule it fails."""
    ok = np.logical_and.reduce([mask for mask, _ in rules])
    if ok.all():
        return
    i = int(np.argmin(ok))
    message = next(message for mask, message in rules if not mask[i])
    raise TopologyError(message(i), source, where(i))


def _finite(value: object) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _is_id(value: object) -> bool:
    """A node or function id: an integer (not a bool) in 0..MAX_NODE_ID."""
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MAX_NODE_ID


def _floats(values: list[object]) -> np.ndarray | None:
    """The values as float64 when all are plain ints and floats that fit, else None: the
    fast path of the masks below, which otherwise look at each value."""
    if set(map(type, values)) <= {int, float}:
        try:
            return np.array(values, dtype=np.float64)
        except OverflowError:  # an int beyond any float
            return None
    return None


def _coordinate_mask(values: list[object]) -> np.ndarray:
    """Which values are coordinates: finite and within MAX_LENGTH of the origin, so that
    differences of two stay finite (a length, a drawing's extent)."""
    as_floats = _floats(values)
    if as_floats is None:
        finite = [_finite(v) for v in values]
        as_floats = np.array(
            [float(v) if ok else np.inf for v, ok in zip(values, finite, strict=True)]
        )
    return np.abs(as_floats) <= MAX_LENGTH  # False for NaN and infinities


def _length_mask(values: list[object]) -> np.ndarray:
    """Which values pass ``is_finite_length``."""
    as_floats = _floats(values)
    if as_floats is not None:
        return (as_floats >= 0) & (as_floats <= MAX_LENGTH)  # False for NaN
    return np.fromiter(map(is_finite_length, values), bool, len(values))


def _id_mask(values: list[object]) -> np.ndarray:
    """Which values pass ``_is_id`` (``values`` is not empty)."""
    if set(map(type, values)) == {int} and min(values) >= 0 and max(values) <= MAX_NODE_ID:
        return np.ones(len(values), dtype=bool)
    return np.fromiter(map(_is_id, values), bool, len(values))


def _short(value: object) -> str:
    """repr() for messages, shortened: a 5000-digit number must not flood the terminal."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"


def _check_nodes(plant: Plant, source: str | None) -> None:
    nodes = plant.nodes
    if not nodes:
        raise TopologyError("the plant has no nodes", source)
    n = len(nodes)
    ids = [node.id for node in nodes]
    id_ok = _id_mask(ids)
    roles = [node.role for node in nodes]
    xs, ys = [node.x for node in nodes], [node.y for node in nodes]
    functions_ok = np.ones(n, dtype=bool)
    may_provide = np.ones(n, dtype=bool)
    once = np.ones(n, dtype=bool)  # no function listed twice on one node
    for i in (i for i, node in enumerate(nodes) if node.functions):
        functions_ok[i] = all(map(_is_id, nodes[i].functions))
        may_provide[i] = roles[i] in FUNCTION_ROLES
        once[i] = not functions_ok[i] or len(set(nodes[i].functions)) == len(nodes[i].functions)

    def bad_function(i: int) -> str:
        wrong = next(f for f in nodes[i].functions if not _is_id(f))
        return f"function ids must be integers 0..{MAX_NODE_ID}, got {_short(wrong)}"

    def function_twice(i: int) -> str:
        functions = nodes[i].functions
        twice = next(f for k, f in enumerate(functions) if f in functions[:k])
        return f"function {twice} is listed twice"

    _raise_first_failure(
        [
            (id_ok, lambda i: f"node id must be an integer 0..{MAX_NODE_ID}, got {_short(ids[i])}"),
            (~_repeated(ids, id_ok), lambda i: f"duplicate node id {ids[i]}"),
            (
                _role_mask(roles),
                lambda i: f"unknown role {roles[i]!r} (one of {', '.join(ROLES)})",
            ),
            (
                _coordinate_mask(xs),
                lambda i: (
                    f"x must be a finite number within ±{MAX_LENGTH:g} m, got {_short(xs[i])}"
                ),
            ),
            (
                _coordinate_mask(ys),
                lambda i: (
                    f"y must be a finite number within ±{MAX_LENGTH:g} m, got {_short(ys[i])}"
                ),
            ),
            (functions_ok, bad_function),
            (once, function_twice),
            (
                may_provide,
                lambda i: (
                    f"a {roles[i]} node cannot provide functions (only {', '.join(FUNCTION_ROLES)})"
                ),
            ),
        ],
        source,
        lambda i: f"nodes[{i}] (id {ids[i]})" if id_ok[i] else f"nodes[{i}]",
    )


# Characters refused in names: names reach terminals, log files, the drawing and the
# operator page, where a control character (ESC starts a terminal escape sequence), a line
# or paragraph separator (one message, one line) or a bidirectional embedding, override or
# isolate (U+202A..U+202E, U+2066..U+2069: what follows is shown reordered) would make the
# text show something other than what it is. Surrogates are no text at all: they cannot be
# written as UTF-8, so printing or drawing the name fails. Other invisible format
# characters stay allowed: the left-to-right and right-to-left marks that set digits beside
# Hebrew or Arabic, soft hyphens, joiners, the tags of flag emoji move nothing.
REFUSED_CATEGORIES = {
    "Cc": "a control character",
    "Zl": "a line separator",
    "Zp": "a paragraph separator",
    "Cs": "a lone surrogate, not text (it cannot be written as UTF-8)",
}
BIDI_CONTROLS = frozenset(map(chr, [*range(0x202A, 0x202F), *range(0x2066, 0x206A)]))
# A name is read on a screen, a drawing and a terminal line: a megabyte of one is no name.
MAX_NAME_CHARS = 1024


def text_problem(value: object) -> str | None:
    """What makes ``value`` unfit to name something an operator reads, None if nothing."""
    if not isinstance(value, str):
        return f"must be a string, got {_short(value)}"
    if len(value) > MAX_NAME_CHARS:
        return f"{_short(value)} is too long: a name has at most {MAX_NAME_CHARS} characters"
    if value.isprintable():  # the fast path: no character of any refused kind
        return None
    for position, char in enumerate(value, start=1):
        kind = REFUSED_CATEGORIES.get(unicodedata.category(char))
        if kind is None and char in BIDI_CONTROLS:
            kind = "a bidirectional control (it reorders the text after it)"
        if kind is not None:
            return (
                f"{_short(value)}: character {position} (U+{ord(char):04X}) is {kind}; "
                "a name must be printable text"
            )
    return None


def escaped_name(text: str) -> str:
    """``text`` with every character a name may not hold written as its escape: for names
    a plant takes from its file name, which the file system gives as it is (a tab, a byte
    that is not UTF-8) and which nobody wrote as a name."""
    if text_problem(text) is None:
        return text
    return "".join(
        char if text_problem(char) is None else char.encode("unicode_escape").decode("ascii")
        for char in text
    )


def _first_unfit(values: list[object]) -> tuple[int, str] | None:
    """The index of the first value with a ``text_problem`` and that problem; None if every
    value is fit. Plants repeat few names (a grid's are all empty), so each distinct one is
    looked at once."""
    try:
        distinct = set(values)
    except TypeError:  # an unhashable value: certainly no name, found below
        distinct = None
    if distinct is not None and not any(map(text_problem, distinct)):
        return None
    return next(((i, p) for i, value in enumerate(values) if (p := text_problem(value))), None)


def _check_names(plant: Plant, source: str | None) -> None:
    """The plant's name, its functions' names, and the names and areas of its nodes."""
    problem = text_problem(plant.name)
    if problem:
        raise TopologyError(f"the plant's name {problem}", source, "name")
    for function, name in plant.functions.items():
        problem = text_problem(name)
        if problem:
            raise TopologyError(f"the name of function {function} {problem}", source, "functions")
    nodes = plant.nodes
    for key, values in (
        ("name", [node.name for node in nodes]),
        # an area that is no string at all is refused with the other places (_place_problem)
        ("area", [node.area if isinstance(node.area, str) else "" for node in nodes]),
    ):
        unfit = _first_unfit(values)
        if unfit is not None:
            i, problem = unfit
            raise TopologyError(f"{key} {problem}", source, f"nodes[{i}] (id {nodes[i].id})")


def _check_places(plant: Plant, source: str | None) -> None:
    """The dispatching annotations: queue nodes and the stations they wait for, cluster
    zones, single-vehicle areas. Checked once the node ids are known to be unique, so
    ``queue_for`` can be looked up. Few nodes carry them, so a plain loop over those."""
    marked = [
        i
        for i, node in enumerate(plant.nodes)
        if node.role == "queue"
        or node.queue_for is not None
        or node.zone is not None
        or node.area is not None
    ]
    if not marked:
        return
    functions = set(plant.functions) | {f for node in plant.nodes for f in node.functions}
    for i in marked:
        problem = _place_problem(plant, plant.nodes[i], functions)
        if problem:
            raise TopologyError(problem, source, f"nodes[{i}] (id {plant.nodes[i].id})")


def _place_problem(plant: Plant, node: Node, functions: set[int]) -> str | None:
    """What is wrong with a node's queue_for, zone and area, None if nothing."""
    if node.role == "queue" and node.queue_for is None:
        return "a queue node needs queue_for = <id of the station it is the queue of>"
    if node.queue_for is not None:
        if node.role != "queue":
            return (
                f"queue_for is only for queue nodes, this one has role {node.role!r} "
                '(set role = "queue")'
            )
        if not _is_id(node.queue_for):
            return f"queue_for must be a node id 0..{MAX_NODE_ID}, got {_short(node.queue_for)}"
        at = _lookup(plant.index, node.queue_for)
        if at < 0:
            return f"queue_for names node {node.queue_for}, which is not in the plant"
        station = plant.nodes[at]
        if station.role != "station":
            named = f" ({station.name})" if station.name else ""
            return (
                f"queue_for names node {station.id}{named}, whose role is {station.role!r}: "
                "a queue waits for a station"
            )
    if node.zone is not None:
        if not _is_id(node.zone):
            return f"zone must be a function id 0..{MAX_NODE_ID}, got {_short(node.zone)}"
        if node.zone not in functions:
            known = ", ".join(map(str, sorted(functions))) or "none"
            return f"zone {node.zone} is not a function of the plant (its functions: {known})"
    if node.area is not None and not (isinstance(node.area, str) and node.area.strip()):
        return f"area must be a non-empty name, got {_short(node.area)}"
    return None


def _role_mask(roles: list[object]) -> np.ndarray:
    try:
        if set(roles) <= set(ROLES):
            return np.ones(len(roles), dtype=bool)
    except TypeError:  # an unhashable value: not a role, found below
        pass
    return np.fromiter((role in ROLES for role in roles), bool, len(roles))


def _repeated(ids: list[object], id_ok: np.ndarray) -> np.ndarray:
    """Which of the valid ids already occurred earlier in the list."""
    valid = np.flatnonzero(id_ok)
    numbers = np.array([ids[i] for i in valid.tolist()], dtype=np.int64)
    order = np.argsort(numbers, kind="stable")  # equal ids stay in list order
    later = order[1:][numbers[order[1:]] == numbers[order[:-1]]]
    repeated = np.zeros(len(ids), dtype=bool)
    repeated[valid[later]] = True
    return repeated


def _check_edges(plant: Plant, source: str | None) -> None:
    edges = plant.edges
    if not edges:
        return
    n = len(edges)
    sources, targets = [e.source for e in edges], [e.target for e in edges]
    lengths, speeds = [e.length for e in edges], [e.max_speed for e in edges]
    ends = [
        (sources, [e.port_source for e in edges], _node_indices(plant, sources)),
        (targets, [e.port_target for e in edges], _node_indices(plant, targets)),
    ]
    codes = [_port_codes(ports) for _, ports, _ in ends]
    reused = _reused_ports([at for _, _, at in ends], codes)
    port_rules: list[Rule] = []
    for (node, ports, _at), code, again in zip(ends, codes, reused, strict=True):
        port_rules += [
            (
                code != NOT_A_PORT,
                lambda i, node=node, ports=ports: (
                    f"port {ports[i]!r} at node {node[i]} is not one of N, E, S, W"
                ),
            ),
            (
                ~again,
                lambda i, node=node, ports=ports: (
                    f"port {ports[i]} of node {node[i]} is "
                    f"already used by edges[{_first_user(edges, node[i], ports[i])}]"
                ),
            ),
        ]
    _raise_first_failure(
        [
            (ends[0][2] >= 0, lambda i: f"unknown node {_short(sources[i])}"),
            (ends[1][2] >= 0, lambda i: f"unknown node {_short(targets[i])}"),
            (
                ends[0][2] != ends[1][2],  # the same node (unknown ends fail the rules above)
                lambda i: "self loop: an edge must join two different nodes",
            ),
            (
                _length_mask(lengths),
                lambda i: (
                    f"length must be a finite number >= 0 (at most {MAX_LENGTH:g}), "
                    f"got {_short(lengths[i])}"
                ),
            ),
            (
                np.fromiter(
                    (s is None or (is_finite_length(s) and s > 0) for s in speeds), bool, n
                ),
                lambda i: f"max_speed must be a finite number > 0, got {_short(speeds[i])}",
            ),
            (
                np.fromiter((e.bidirectional or not e.highway for e in edges), bool, n),
                lambda i: (
                    "highway on a directed edge: only a two-way edge has a direction "
                    "to prefer (drop 'directed' or 'highway')"
                ),
            ),
            (
                np.fromiter((e.routable or not e.highway for e in edges), bool, n),
                lambda i: (
                    "highway on an edge that is not routable: routing never uses it, "
                    "so it has no direction to prefer (drop 'routable' or 'highway')"
                ),
            ),
            (
                _not_against_another_highway(edges),
                lambda i: (
                    f"highway undone by edges[{_against(edges, i)}], which joins the same two "
                    f"nodes and lets vehicles drive {targets[i]} -> {sources[i]} at no extra "
                    "cost (drop one of them)"
                ),
            ),
            *port_rules,
        ],
        source,
        lambda i: f"edges[{i}] ({_short(sources[i])} -> {_short(targets[i])})",
    )


def _duplicate_edges(plant: Plant) -> list[str]:
    """A warning for each routable edge that joins the same two nodes in the same
    direction(s) as an earlier one at the same speed limit: of the two, routing only ever
    drives the shorter (both traffic modes), so a copy-pasted line changes nothing, and an
    edited copy (its length fixed in one line) silently loses its edit. Parallel lanes with
    different limits are left alone (one may be the faster way), as is a return lane (not
    routable) beside a lane. One sort over the edges, as the rules are (plants have
    hundreds of thousands)."""
    edges = [k for k, e in enumerate(plant.edges) if e.routable]
    if len(edges) < 2:
        return []
    chosen = [plant.edges[k] for k in edges]
    s = _node_indices(plant, [e.source for e in chosen])
    t = _node_indices(plant, [e.target for e in chosen])
    both = np.fromiter((e.bidirectional for e in chosen), bool, len(chosen))
    limit = np.fromiter(
        (math.inf if e.max_speed is None else e.max_speed for e in chosen), float, len(chosen)
    )
    keys = np.stack(
        [np.where(both, np.minimum(s, t), s), np.where(both, np.maximum(s, t), t), both, limit],
        axis=1,
    )
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    earlier = first[inverse.ravel()]
    again = np.flatnonzero(earlier != np.arange(len(chosen)))
    warnings = [
        _duplicate_warning(plant.edges, edges[int(earlier[j])], edges[int(j)]) for j in again
    ]
    if len(again) > MAX_DUPLICATE_WARNINGS:
        warnings = warnings[:MAX_DUPLICATE_WARNINGS] + [
            f"(duplicate edges reported for the first {MAX_DUPLICATE_WARNINGS} of {len(again)})"
        ]
    return warnings


def _duplicate_warning(edges: tuple[Edge, ...], i: int, j: int) -> str:
    e, f = edges[i], edges[j]
    way = "both ways" if e.bidirectional else "one way"
    if e.length == f.length:
        advice = "a copy? drop one of them"
    else:
        advice = "only the shorter is ever driven: drop the other, or give it its own speed limit"
    return f"edges[{j}] joins nodes {e.source} and {e.target} {way}, as edges[{i}] does: {advice}"


def _not_against_another_highway(edges) -> np.ndarray:
    """For each edge: False if it is a highway and another routable edge joins the same two
    nodes and lets vehicles drive against it without its price (a highway the other way, or
    any edge from its target to its source, or a plain two-way edge): routing would take
    that one, and the highway would prefer nothing."""
    ok = np.ones(len(edges), dtype=bool)
    if any(e.highway for e in edges):
        against = _against_index(edges)
        for i, e in enumerate(edges):
            ok[i] = not (e.highway and _against(edges, i, against) is not None)
    return ok


def _against_index(edges) -> dict[tuple, list[int]]:
    """Routable edges by the (from, to) they let vehicles drive unpriced: one lookup per
    highway, not a walk over every edge (plants have hundreds of thousands)."""
    index: dict[tuple, list[int]] = {}
    for k, o in enumerate(edges):
        if o.routable:
            index.setdefault((o.source, o.target), []).append(k)
            if o.bidirectional and not o.highway:
                index.setdefault((o.target, o.source), []).append(k)
    return index


def _against(edges, i: int, index: dict[tuple, list[int]] | None = None) -> int | None:
    """The index of an edge that lets vehicles drive against highway ``edges[i]`` unpriced."""
    e = edges[i]
    index = _against_index(edges) if index is None else index
    return next((k for k in index.get((e.target, e.source), ()) if k != i), None)


def _node_indices(plant: Plant, values: list[object]) -> np.ndarray:
    """The dense index of the node each value names, -1 where it names none."""
    if set(map(type, values)) == {int}:
        try:
            numbers = np.array(values, dtype=np.int64)
        except OverflowError:  # beyond int64: certainly no node, found one by one below
            numbers = None
        if numbers is not None:
            order = np.argsort(plant.ids)
            known = plant.ids[order]
            at = np.searchsorted(known, numbers).clip(max=len(known) - 1)
            return np.where(known[at] == numbers, order[at], -1)
    index = plant.index
    return np.array([_lookup(index, v) for v in values], dtype=np.int64)


def _lookup(index: dict[int, int], value: object) -> int:
    try:
        return index.get(value, -1)  # type: ignore[call-overload]
    except TypeError:  # unhashable: no node id
        return -1


def _port_codes(ports: list[object]) -> np.ndarray:
    """0..3 for N, E, S, W, NO_PORT for None, NOT_A_PORT for anything else."""
    try:
        return np.fromiter(map(PORT_CODES.get, ports, repeat(NOT_A_PORT)), np.int64, len(ports))
    except TypeError:  # an unhashable value: certainly not a port
        return np.array(
            [PORTS.index(p) if p in PORTS else NO_PORT if p is None else NOT_A_PORT for p in ports],
            dtype=np.int64,
        )


def _speed_mask(speeds: list[object]) -> np.ndarray:
    """Which max_speed values are None (no limit) or finite numbers > 0."""
    if set(map(type, speeds)) == {type(None)}:
        return np.ones(len(speeds), dtype=bool)
    return np.fromiter(
        (s is None or (is_finite_length(s) and s > 0) for s in speeds), bool, len(speeds)
    )


def _reused_ports(at: list[np.ndarray], codes: list[np.ndarray]) -> list[np.ndarray]:
    """For the source and the target end of every edge: whether an earlier edge already
    uses that port of that node (at either of its ends). The drive control turns by
    compass port, so a port leads to one segment."""
    n = len(at[0])
    key = np.concatenate([a * len(PORTS) + c for a, c in zip(at, codes, strict=True)])
    edge = np.tile(np.arange(n), 2)
    used = np.flatnonzero(
        np.concatenate([(a >= 0) & (c >= 0) for a, c in zip(at, codes, strict=True)])
    )
    order = used[np.lexsort((edge[used], key[used]))]  # by port, then by edge
    group_start = np.ones(len(order), dtype=bool)
    group_start[1:] = key[order][1:] != key[order][:-1]
    first = np.maximum.accumulate(np.where(group_start, np.arange(len(order)), 0))
    reused = np.zeros(2 * n, dtype=bool)
    reused[order] = edge[order][first] < edge[order]
    return [reused[:n], reused[n:]]


def _first_user(edges: tuple[Edge, ...], node: object, port: object) -> int:
    """The first edge that uses ``port`` of ``node``, for the message."""
    return next(
        i
        for i, e in enumerate(edges)
        if (e.source == node and e.port_source == port)
        or (e.target == node and e.port_target == port)
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
