"""Path heat: the congestion-aware arc weights of time-window planning's offline stage.

Plain shortest paths pile vehicles onto the same few arcs. The offline stage of the
time-window planner counts how often each arc is used by the period's shortest paths
(``h``), takes how many vehicles are on each arc now (``b``), and weights every arc by

    w_k = 1 + F_k,   F_k = (b_k + 1) h_k / sum_g(b_g h_g)

so arcs that many planned paths share, and more so those already occupied, cost more, and a
second search spreads the paths. The weight multiplies only the arc's travel time in the
search's cost (see :class:`SafeIntervalSearch`), never its time.

The source leaves a zero denominator (no vehicle on any used arc, e.g. at the start of a
period) to the implementer. Here it is then taken as 1, its smallest value that is not zero
(one vehicle on an arc one path uses), so the weights do not jump when the first vehicle
sets off: with nobody driving yet, ``F_k = h_k``, an arc costs one extra travel time per
planned path that uses it. Arrays in,
arrays out, in the order of ``plant.arcs``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from topology import Plant


def arc_usage(plant: Plant, routes: Iterable[Sequence[int]]) -> np.ndarray:
    """h: per arc, how many of ``routes`` (node id sequences) drive it. A segment with
    parallel arcs counts on the shortest one, the one routing takes."""
    h = np.zeros(plant.n_arcs, dtype=np.int64)
    _, _, length = plant.arcs
    for route in routes:
        for a, b in zip(route, route[1:], strict=False):
            arcs = plant.arc_index.get((a, b))
            if not arcs:
                raise ValueError(
                    f"route {list(route)} uses {a} -> {b}, which is no arc of the plant"
                )
            h[min(arcs, key=lambda k: length[k])] += 1
    return h


def usage_along_distances(
    plant: Plant, routes: Iterable[tuple[int, Sequence[float]]], limit: int | None = None
) -> np.ndarray:
    """h for shortest routes given by where they start and their goal's distance row:
    ``routes`` is (start node index, distances of every node index to the goal). Each
    route is followed down the distances (the first out-arc whose length closes the gap
    exactly; what the heuristic table's A* would drive), for at most ``limit`` arcs
    (None: the plant's node count). Counts per arc, in the order of ``plant.arcs``."""
    h = np.zeros(plant.n_arcs, dtype=np.int64)
    neighbors = plant.neighbors
    cap = plant.n if limit is None else limit
    for start, row in routes:
        node = start
        for _ in range(cap):
            here = row[node]
            if not here > 0 or not math.isfinite(here):
                break  # at the goal, or cut off from it
            step = next(
                (
                    (v, arc)
                    for v, arc, length in neighbors[node]
                    if abs(length + row[v] - here) <= 1e-6 * max(1.0, here)
                ),
                None,
            )
            if step is None:
                break
            node, arc = step
            h[arc] += 1
    return h


def heat_weights(usage: np.ndarray, occupancy: np.ndarray | None = None) -> np.ndarray:
    """w = 1 + F per arc from usage ``h`` and live occupancy ``b`` (vehicles on each arc;
    None: nobody)."""
    h = np.asarray(usage, dtype=np.float64)
    b = np.zeros_like(h) if occupancy is None else np.asarray(occupancy, dtype=np.float64)
    if h.shape != b.shape:
        raise ValueError(f"usage and occupancy differ in length: {h.shape} and {b.shape}")
    if (h < 0).any() or (b < 0).any():
        raise ValueError("usage and occupancy are counts and cannot be negative")
    denominator = float((b * h).sum())
    return 1.0 + (b + 1.0) * h / (denominator if denominator > 0 else 1.0)
