"""4-connected grid plants from a boolean passability array (MovingAI maps, warehouses, grids).

Cell (x, y) is node ``y * width + x``, (0, 0) top-left, x the column: the MovingAI id scheme.
Node ids, positions and segment ends are computed as arrays and the node and edge objects
made with ``map`` in one pass: a 1000 x 1000 grid is a million nodes and two million edges,
and Python arithmetic per cell would cost several times the objects themselves.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from itertools import repeat

import numpy as np

from .errors import TopologyError
from .limits import check_plant_size
from .model import Edge, Node, Plant


def grid_plant(
    passable: np.ndarray,
    cell_size: float = 1.0,
    roles: Mapping[int, tuple[str, tuple[int, ...]]] | None = None,
    name: str = "grid",
    functions: Mapping[int, str] | None = None,
    source: str | None = None,
) -> Plant:
    """``roles``: node id -> (role, functions) for the cells that are not plain transit
    (each a passable cell: a role on a blocked one is a TopologyError naming the cell).

    Edges come in a fixed order, every east segment row by row and then every south one,
    because arc indices (and so the plant's fingerprint) follow the edge order."""
    passable = np.asarray(passable)
    if passable.ndim != 2 or passable.dtype != bool:
        raise TopologyError(
            f"a grid needs a 2-D boolean array, got {passable.ndim}-D {passable.dtype}", source
        )
    width = passable.shape[1]
    east = passable[:, :-1] & passable[:, 1:]
    south = passable[:-1, :] & passable[1:, :]
    check_plant_size(
        int(np.count_nonzero(passable)),
        int(np.count_nonzero(east)) + int(np.count_nonzero(south)),
        source,
    )
    ids = np.flatnonzero(passable)
    rows, columns = np.divmod(ids, width)
    role_of = ["transit"] * len(ids)
    provides: list[tuple[int, ...]] = [()] * len(ids)
    for node_id, (role, provided) in (roles or {}).items():
        at = int(np.searchsorted(ids, node_id))
        if not (at < len(ids) and ids[at] == node_id):  # a role would be lost without a word
            row, column = divmod(node_id, width)
            where = (
                f"cell {node_id} (row {row}, column {column}) is blocked"
                if 0 <= node_id < passable.size
                else f"cell {node_id} is outside the {passable.shape[0]} x {width} grid"
            )
            raise TopologyError(f"roles: {where}: it has no node to be a {role}", source)
        role_of[at], provides[at] = role, provided
    nodes = map(
        Node,
        ids.tolist(),
        repeat(""),
        (columns * cell_size).tolist(),
        (rows * cell_size).tolist(),
        role_of,
        provides,
    )
    with _collector_paused():
        edges = [
            *_segments(east, width, 1, cell_size, ("E", "W")),
            *_segments(south, width, width, cell_size, ("S", "N")),
        ]
        return Plant.build(nodes, edges, name=name, functions=dict(functions or {}), source=source)


@contextmanager
def _collector_paused() -> Iterator[None]:
    """Pause the cyclic garbage collector while millions of nodes and edges are made.

    None of them can be part of a reference cycle, but every allocation counts towards the
    collector's thresholds, so it would traverse the growing heap again and again (about a
    third of the build time of a million-node grid). A collector that was off stays off."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def _segments(
    pairs: np.ndarray, width: int, step: int, length: float, ports: tuple[str, str]
) -> map[Edge]:
    """Two-way edges from every cell (x, y) marked in ``pairs`` to the node ``step`` ids
    further, in row-major order (``pairs`` may be a column narrower than the grid)."""
    ys, xs = np.nonzero(pairs)
    sources = ys * width + xs
    return map(
        Edge,
        sources.tolist(),
        (sources + step).tolist(),
        repeat(length),
        repeat(None),
        repeat(True),
        repeat(ports[0]),
        repeat(ports[1]),
    )
