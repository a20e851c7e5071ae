"""Heuristic-table build time: exact distance of every node to each target.

Plants: open square grids (4-connected, unit lengths) of about 1e3, 1e4, 1e5 and 1e6 nodes;
targets: 10, 100 and 1000 random nodes. Ours: ``blocks.routing.heuristic.distances_to`` (scipy
csgraph Dijkstra on the reversed graph, float32 rounded down). Baseline, in the same run:
networkx ``single_source_dijkstra_path_length`` on the reversed DiGraph, one call per target,
timed over as many targets as fit in ``--nx-seconds`` and reported per target (networkx
on every target of the large cells would take hours). A table whose float32 matrix would
exceed ``--max-gib`` is not built.

The full run takes about 3 minutes, nearly all of it in the 1e5- and 1e6-node rows.
``--quick`` stops at 1e4 nodes and gives networkx 0.2 s per cell (a few seconds).

    .venv/bin/python bench/heuristic_table.py [--max-nodes 1000000] [--nx-seconds 5] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import networkx as nx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from blocks.routing.heuristic import distances_to  # noqa: E402
from topology.grid import grid_plant  # noqa: E402

# --quick lowers these defaults; options given on the command line still win.
QUICK = {"max_nodes": 10_000, "nx_seconds": 0.2}


def networkx_reverse(plant) -> nx.DiGraph:
    g = nx.DiGraph()
    src, dst, length = plant.arcs
    g.add_weighted_edges_from(zip(dst.tolist(), src.tolist(), length.tolist(), strict=True))
    return g


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-nodes", type=int, default=1_000_000)
    parser.add_argument(
        "--nx-seconds", type=float, default=5.0, help="networkx time budget per cell"
    )
    parser.add_argument("--max-gib", type=float, default=2.0, help="largest table to build")
    parser.add_argument(
        "--quick", action="store_true", help="reduced run: --max-nodes 10000 --nx-seconds 0.2"
    )
    args = parser.parse_args()
    if args.quick:
        parser.set_defaults(**QUICK)
        args = parser.parse_args()
    begin_run = time.perf_counter()
    rng = np.random.default_rng(1)
    print(f"Heuristic table build, open grids, Python {sys.version.split()[0]}")
    print()
    print(
        "| nodes | targets | ours s | ours ms/target | table MiB | networkx ms/target (targets timed) | networkx / ours |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for side in (32, 100, 316, 1000):
        n = side * side
        if n > args.max_nodes:
            break
        plant = grid_plant(np.ones((side, side), dtype=bool))
        _ = plant.csr  # the adjacency is built at startup in the runtime too; not part of the table
        reverse = networkx_reverse(plant)
        for k in (10, 100, 1000):
            mib = k * n * 4 / 2**20
            if mib / 1024 > args.max_gib:
                print(
                    f"| {n:,} | {k} | - | - | {mib:,.0f} | - | - (table over {args.max_gib:g} GiB, not built) |"
                )
                continue
            targets = rng.choice(plant.ids, size=k, replace=False).tolist()
            begin = time.perf_counter()
            table = distances_to(plant, targets)
            ours = time.perf_counter() - begin
            timed, begin = 0, time.perf_counter()
            while timed < k and (timed == 0 or time.perf_counter() - begin < args.nx_seconds):
                nx.single_source_dijkstra_path_length(reverse, targets[timed])
                timed += 1
            nx_per_target = (time.perf_counter() - begin) / timed
            ours_per_target = ours / k
            print(
                f"| {n:,} | {k} | {ours:.3f} | {ours_per_target * 1e3:.2f} | {table.nbytes / 2**20:,.1f} "
                f"| {nx_per_target * 1e3:.2f} ({timed}) | {nx_per_target / ours_per_target:.1f} |"
            )
            del table
    print()
    print(f"wall time {time.perf_counter() - begin_run:.1f} s")


if __name__ == "__main__":
    main()
