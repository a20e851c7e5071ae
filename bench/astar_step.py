"""IncrementalAStar: time per cycle against plant size, cycles against route length, and the
exact heuristic table against a Manhattan heuristic (the memory/time trade-off, thesis 4.4.1).

1. One cycle's A* step (budget 1 expansion, the thesis setting) on open grids of 1e2..1e6
   nodes: p50/p99/max of the A* task's execution time per cycle, over searches between
   random starts and a fixed goal, restarted as soon as one ends. It should stay flat: it
   depends on the node degree, not the plant size. Baselines in the same run: the same
   searches done in ONE cycle (the thesis' WHILE loop, budget unbounded) and networkx's
   astar_path with the same exact heuristic, per search.
2. Cycles to a complete route against route length on the warehouse, budgets 1 and 8.
3. Exact table against Manhattan on the warehouse and a MovingAI map: expansions and time
   per complete search (budget unbounded), table memory and build time; networkx astar_path
   with the Manhattan heuristic as the baseline.

The full run takes about 1 minute, most of it in the 1e5- and 1e6-node rows of section 1
(grids, tables and networkx graphs). ``--quick`` stops section 1 at 1e4 nodes, 500 cycles
per row (a few seconds); sections 2 and 3 are cheap and run unchanged.

    .venv/bin/python bench/astar_step.py [--max-nodes 1000000] [--cycles 3000] [--quick]
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from pathlib import Path

import networkx as nx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from blocks.routing.astar import IncrementalAStar  # noqa: E402
from blocks.routing.heuristic import HeuristicTable  # noqa: E402
from plc_runtime import FunctionBlock, Runtime, VirtualClock  # noqa: E402
from topology import load, warehouse  # noqa: E402
from topology.formats import load_scenarios  # noqa: E402
from topology.grid import grid_plant  # noqa: E402

MOVINGAI = Path(__file__).resolve().parents[2] / "shared" / "data" / "movingai"
# --quick lowers these defaults; options given on the command line still win.
QUICK = {"max_nodes": 10_000, "cycles": 500}


class Driver(FunctionBlock):
    """Runs searches back to back: request high until the search ends, one cycle low, next."""

    def __init__(self, astar, starts, goal, budget):
        super().__init__()
        self.astar, self.starts, self.goal, self.budget, self.k = astar, starts, goal, budget, 0
        self.results: list[tuple[int, int, int]] = []  # (route nodes, expansions, cycles)

    def cycle(self, ctx):
        a = self.astar
        if a.request and not a.busy and a.done:  # the search ended in the last cycle
            self.results.append((len(a.route), a.expansions, a.cycles))
            a.request = False
        elif not a.request:
            a.start, a.goal, a.budget = (
                self.starts[self.k % len(self.starts)],
                self.goal,
                self.budget,
            )
            a.request = True
            self.k += 1


def drive(plant, table, starts, goal, budget, cycles, heuristic="table"):
    astar = IncrementalAStar(plant, table, heuristic=heuristic)
    driver = Driver(astar, starts, goal, budget)
    rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=10.0)
    rt.add_task("driver", [driver], priority=0)
    if table is not None:
        rt.add_task("table", [table], priority=1)
    rt.add_task("astar", [astar], priority=2)
    rt.start()
    gc.collect()
    gc.freeze()  # the plant and table are startup data: keep the collector off them (rt mode does this)
    rt.run(cycles=cycles)
    gc.unfreeze()
    stats = rt.stats["astar"]
    rt.stop()
    return stats, driver.results


def exact_heuristic(plant, table_row):
    return lambda u, v: float(table_row[plant.idx(u)])


def nx_graph(plant) -> nx.DiGraph:
    g = nx.DiGraph()
    src, dst, length = plant.arcs
    ids = plant.ids
    g.add_weighted_edges_from(
        zip(ids[src].tolist(), ids[dst].tolist(), length.tolist(), strict=True)
    )
    return g


def section_step_time(max_nodes: int, cycles: int, rng) -> None:
    print("### 1. Time per cycle (budget 1) against plant size")
    print()
    print(
        "| nodes | cycles | A* step p50 us | p99 us | max us | whole search in one cycle, mean ms | networkx astar_path mean ms | p99 step / one-cycle search |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for side in (10, 32, 100, 316, 1000):
        n = side * side
        if n > max_nodes:
            break
        plant = grid_plant(np.ones((side, side), dtype=bool))
        goal = int(plant.ids[-1])
        starts = rng.choice(plant.ids[: n // 2], size=64).tolist()
        table = HeuristicTable(plant, targets=[goal])
        stats, _ = drive(plant, table, starts, goal, 1, cycles)
        p50, p99, mx = (
            stats.exec_percentile_ns(50) / 1e3,
            stats.exec_percentile_ns(99) / 1e3,
            stats.exec_max_ns / 1e3,
        )
        whole, done = drive(
            plant, HeuristicTable(plant, targets=[goal]), starts[:8], goal, None, 16
        )
        searches = [r for r in done]
        whole_ms = (
            whole.exec_mean_ns / 1e6 * (whole.cycles / max(len(searches), 1))
            if searches
            else float("nan")
        )
        row = table.row(goal) if table.row(goal) is not None else None
        g = nx_graph(plant) if n <= 100_000 else None
        if g is not None and row is not None:
            begin = time.perf_counter()
            for s in starts[:8]:
                nx.astar_path(g, s, goal, heuristic=exact_heuristic(plant, row), weight="weight")
            nx_ms = (time.perf_counter() - begin) / 8 * 1e3
            nx_text = f"{nx_ms:,.2f}"
        else:
            nx_text = "- (graph too large for a quick networkx run)"
        print(
            f"| {n:,} | {stats.cycles} | {p50:.1f} | {p99:.1f} | {mx:.1f} | {whole_ms:,.2f} | {nx_text} | {p99 / 1e3 / whole_ms:.4f} |"
        )
    print()


def section_cycles_vs_length(rng) -> None:
    print("### 2. Cycles to a complete route against route length (warehouse, exact table)")
    print()
    plant = warehouse()
    goal = int(plant.with_role("station")[0])
    starts = rng.choice(plant.ids, size=200, replace=False).tolist()
    print("| route nodes | searches | cycles, budget 1 (mean) | cycles, budget 8 (mean) |")
    print("|---|---:|---:|---:|")
    results = {}
    for budget in (1, 8):
        _, done = drive(plant, HeuristicTable(plant, targets=[goal]), starts, goal, budget, 12_000)
        results[budget] = done
    for low, high in ((1, 10), (11, 20), (21, 40), (41, 80)):
        one = [c for length, _e, c in results[1] if low <= length <= high]
        eight = [c for length, _e, c in results[8] if low <= length <= high]
        if one:
            print(f"| {low}-{high} | {len(one)} | {np.mean(one):.1f} | {np.mean(eight):.1f} |")
    print()


def section_table_vs_manhattan(rng) -> None:
    print("### 3. Exact table against Manhattan (complete searches, budget unbounded)")
    print()
    print(
        "| plant | heuristic | searches | expansions mean | search ms mean | table MiB | table build ms | networkx astar (Manhattan) ms mean | networkx / ours |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    cases = [("warehouse 33x46", warehouse(), None)]
    if MOVINGAI.exists():
        scens = load_scenarios(MOVINGAI / "random-32-32-10-random-1.scen")
        cases.append(("MovingAI random-32-32-10", load(MOVINGAI / "random-32-32-10.map"), scens))
    for name, plant, scens in cases:
        if scens:
            pairs = [
                (s.start, s.goal) for s in scens if s.start in plant.index and s.goal in plant.index
            ][:100]
        else:
            ids = plant.ids.tolist()
            pairs = [tuple(rng.choice(ids, size=2, replace=False).tolist()) for _ in range(100)]
        goals = sorted({g for _s, g in pairs})
        g = nx_graph(plant)
        pos = {
            int(i): (x, y)
            for i, (x, y) in zip(plant.ids.tolist(), plant.positions.tolist(), strict=True)
        }

        def manhattan(u, v, pos=pos):
            return abs(pos[u][0] - pos[v][0]) + abs(pos[u][1] - pos[v][1])

        begin = time.perf_counter()
        for s, t in pairs:
            nx.astar_path(g, s, t, heuristic=manhattan, weight="weight")
        nx_ms = (time.perf_counter() - begin) / len(pairs) * 1e3
        for heuristic in ("table", "manhattan", "zero"):
            table = HeuristicTable(plant, targets=goals) if heuristic == "table" else None
            astar = IncrementalAStar(plant, table, heuristic=heuristic)
            rt = Runtime(cycle_time=1.0, clock=VirtualClock(), watchdog=60.0)
            rt.add_task("main", [b for b in (table, astar) if b is not None])
            rt.start()
            expansions, total = [], 0.0
            for s, t in pairs:
                astar.request, astar.start, astar.goal, astar.budget = True, s, t, None
                begin = time.perf_counter()
                rt.step()  # unbounded budget: the whole search runs in this one cycle
                total += time.perf_counter() - begin
                assert astar.done and not astar.busy
                expansions.append(astar.expansions)
                astar.request = False
                rt.step()
            rt.stop()
            ours_ms = total / len(pairs) * 1e3
            mib = f"{table.nbytes / 2**20:.2f}" if table else "0"
            build = f"{table.build_time_s * 1e3:.1f}" if table else "-"
            print(
                f"| {name} | {heuristic} | {len(pairs)} | {np.mean(expansions):.1f} | {ours_ms:.3f} | {mib} "
                f"| {build} | {nx_ms:.3f} | {nx_ms / ours_ms:.1f} |"
            )
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-nodes", type=int, default=1_000_000)
    parser.add_argument("--cycles", type=int, default=3000)
    parser.add_argument(
        "--quick", action="store_true", help="reduced run: --max-nodes 10000 --cycles 500"
    )
    args = parser.parse_args()
    if args.quick:
        parser.set_defaults(**QUICK)
        args = parser.parse_args()
    begin = time.perf_counter()
    rng = np.random.default_rng(7)
    print(f"IncrementalAStar benchmarks, Python {sys.version.split()[0]}")
    print()
    section_step_time(args.max_nodes, args.cycles, rng)
    section_cycles_vs_length(rng)
    section_table_vs_manhattan(rng)
    print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
