"""4-connected grid plants from a boolean passability array (MovingAI maps, warehouses, grids).

Cell (x, y) is node ``y * width + x``, (0, 0) top-left, x the column: the MovingAI id scheme.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .model import Edge, Node, Plant


def grid_plant(
    passable: np.ndarray,
    cell_size: float = 1.0,
    roles: Mapping[int, tuple[str, tuple[int, ...]]] | None = None,
    name: str = "grid",
    functions: Mapping[int, str] | None = None,
    source: str | None = None,
) -> Plant:
    """``roles``: node id -> (role, functions) for the cells that are not plain transit."""
    height, width = passable.shape
    roles = roles or {}
    ys, xs = np.nonzero(passable)
    nodes = []
    for y, x in zip(ys.tolist(), xs.tolist(), strict=True):
        node_id = y * width + x
        role, provided = roles.get(node_id, ("transit", ()))
        nodes.append(Node(node_id, x=x * cell_size, y=y * cell_size, role=role, functions=provided))
    edges = []
    east = passable[:, :-1] & passable[:, 1:]
    for y, x in zip(*np.nonzero(east), strict=True):
        a = int(y) * width + int(x)
        edges.append(Edge(a, a + 1, cell_size, port_source="E", port_target="W"))
    south = passable[:-1, :] & passable[1:, :]
    for y, x in zip(*np.nonzero(south), strict=True):
        a = int(y) * width + int(x)
        edges.append(Edge(a, a + width, cell_size, port_source="S", port_target="N"))
    return Plant.build(nodes, edges, name=name, functions=dict(functions or {}), source=source)
