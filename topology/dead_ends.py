"""Dead ends of a plant: the parts a vehicle can only leave the way it came in.

A station's spur, a queue or parking siding, a dead-end aisle: the nodes outside the
plant's 2-core (what is left after removing, again and again, every node with at most one
neighbour, the segments taken both ways). Each connected group of them is a **pocket**
that hangs off the rest of the plant by exactly one segment, from its *mouth* (a node of
the core) to its *root* (the pocket's node next to it): no path between two nodes outside
a pocket ever runs through it, so a vehicle enters one only to reach something in it, or
to wait there. Arrays in, arrays out, like ``scipy.sparse.csgraph``.
"""

from __future__ import annotations

import numpy as np

from .model import Plant

NO_POCKET = -1


def dead_end_pockets(plant: Plant) -> np.ndarray:
    """For each node index, the index of the root of the pocket it lies in (its own index
    for a root), or :data:`NO_POCKET` for the nodes of the core. A plant without any cycle
    (a line, a tree) has no core to hang pockets off: every node is then NO_POCKET, as
    no part of it is more of a dead end than another."""
    src, dst, _ = plant.arcs
    n = plant.n
    neighbours: list[set[int]] = [set() for _ in range(n)]
    for u, v in zip(src.tolist(), dst.tolist(), strict=True):
        if u != v:
            neighbours[u].add(v)
            neighbours[v].add(u)
    degree = [len(s) for s in neighbours]
    peeled = [False] * n
    stack = [u for u in range(n) if degree[u] <= 1]
    while stack:
        u = stack.pop()
        if peeled[u]:
            continue
        peeled[u] = True
        for v in neighbours[u]:
            if not peeled[v]:
                degree[v] -= 1
                if degree[v] <= 1:
                    stack.append(v)
    pocket = np.full(n, NO_POCKET, dtype=np.int64)
    if all(peeled):
        return pocket
    # each pocket from its root outwards: the root is the peeled node next to the core
    for root in range(n):
        if not peeled[root] or not any(not peeled[v] for v in neighbours[root]):
            continue
        pocket[root] = root
        stack = [root]
        while stack:
            u = stack.pop()
            for v in neighbours[u]:
                if peeled[v] and pocket[v] == NO_POCKET:
                    pocket[v] = root
                    stack.append(v)
    return pocket


def pocket_entries(plant: Plant, pocket: np.ndarray) -> dict[int, list[int]]:
    """For each pocket (by its root's index), the arc ids that drive into it from the
    core: closing them keeps a search out of the whole pocket."""
    src, dst, _ = plant.arcs
    out: dict[int, list[int]] = {}
    for arc, (u, v) in enumerate(zip(src.tolist(), dst.tolist(), strict=True)):
        if pocket[u] == NO_POCKET and pocket[v] != NO_POCKET:
            out.setdefault(int(pocket[v]), []).append(arc)
    return out
