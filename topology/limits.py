"""Size limits of plants: how large a plant file, and a plant, may be.

A plant is held as Python objects (a node and an edge cost about 150 bytes each, the routing
arrays and neighbour lists about as much again), and a loader builds them before anyone could
look at the size: a map of 1.4 MB, 1200 x 1200 open cells, would take 2 GB. With these limits
the worst accepted case is known and documented (docs/plant-format.md, "Size limits").

The node limit admits MovingAI maps up to 1024 x 1024 (the size of its street maps) and the
1,000,000-node grids of the benchmarks; a 4-connected grid has fewer than two edges per node,
so the edge limit is twice the node limit. The file limit holds a 1024 x 1024 map several
times over, and keeps parsing a TOML plant (the slowest format, under 1 MB/s) to seconds.
"""

from __future__ import annotations

from .errors import TopologyError

MAX_FILE_BYTES = 4 * 2**20  # 4 MiB
MAX_NODES = 2**20  # 1,048,576 = 1024 x 1024 cells
MAX_EDGES = 2 * MAX_NODES  # 2,097,152


def check_plant_size(
    nodes: int, edges: int, source: str | None = None, where: str | None = None
) -> None:
    """TopologyError naming the count and the limit when a plant would be too large."""
    for count, limit, what in ((nodes, MAX_NODES, "nodes"), (edges, MAX_EDGES, "edges")):
        if count > limit:
            raise TopologyError(
                f"{count:,} {what}: a plant may have at most {limit:,} {what} "
                "(docs/plant-format.md, Size limits)",
                source,
                where,
            )
