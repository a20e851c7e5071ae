"""What a conflict window saves a safe-interval search: cost per search, with and without.

The time-window traffic mode plans every vehicle by a safe-interval search over (node,
heading) through the windows of the vehicles planned before it (``blocks/traffic/sipp.py``).
Without a cut-off a search to a far goal explores, turn by turn, the many equally short
ways there; with one (``until``) conflicts are resolved only up to the cut-off and the
plan goes on down the heuristic table's distances past it, so the search ends soon after
the cut-off. This bench measures both on the same searches.

Setting, as in a planning round of the fleet: ``--others`` vehicles (10 % of the nodes by
default, at most 500) from random nodes to random nodes are planned one after another
with the window, each booked up to a 20 s horizon; then ``--searches`` further vehicles are
searched through that table, once without a cut-off (the baseline) and once with the 30 s
window, from the same start to the same goal. Plants: the 99 x 138 warehouse of
``bench/fleet_scale.py``'s 1000-vehicle run (8,382 nodes) and the 33 x 46 kiva map (1,278
nodes, no highway weights). Speed 0.5 m/s (1 m cells, 2 s a cell), 1 s per 90-degree
turn, 2 s per U-turn, a 0.5 s gap: the simulated AGV's.

Reported per plant: expansions and steps down the distances per search (means), the median
milliseconds per search (wall clock, this machine), the ratio windowed / baseline, and the windowed plans'
arrival against the baseline's (the price of not searching past the cut-off; 1.00 = the
same arrival).

    .venv/bin/python bench/windowed_search.py [--searches 60] [--others N] [--quick]

``--quick``: kiva only, 15 searches beside 40 others (a few seconds).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from fleet_scale import plant_for  # noqa: E402

from blocks.routing.heuristic import distances_to  # noqa: E402
from blocks.traffic.sipp import ArcGeometry, SafeIntervalSearch, TurnTimes  # noqa: E402
from blocks.traffic.time_windows import TimeWindowTable  # noqa: E402
from topology import Plant, kiva  # noqa: E402

SPEED = 0.5  # m/s: one 1 m cell per 2 s timestep
TURNS = TurnTimes(1.0, 2.0)
GAP_S = 0.5
WINDOW_S = 30.0  # the fleet's default conflict window
HORIZON_S = 20.0  # others' plans are booked this far, as in a planning round


def search(plant, table, geometry, vehicle, start, goal, row, until) -> SafeIntervalSearch:
    s = SafeIntervalSearch(
        plant,
        table,
        vehicle,
        start,
        goal,
        0.0,
        speed=SPEED,
        turns=TURNS,
        to_goal=row,
        hold_s=4.0,
        geometry=geometry,
        until=until,
        labels="cheapest",
    )
    s.step(None)
    return s


def book_horizon(table: TimeWindowTable, plan) -> None:
    """Book the plan's steps that start within the horizon."""
    last = 0
    while last + 1 < len(plan.nodes) and plan.claims[last + 1] < HORIZON_S:
        last += 1
    nodes = [(plan.nodes[i], plan.claims[i], plan.depart[i]) for i in range(last + 1)]
    segments = [
        (plan.nodes[i], plan.nodes[i + 1], plan.depart[i], plan.arrive[i + 1]) for i in range(last)
    ]
    table.book(plan.vehicle, nodes, segments)


def measure(name: str, plant: Plant, searches: int, others: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    geometry = ArcGeometry(plant)
    ids = [int(i) for i in plant.ids]
    picks = rng.choice(len(ids), size=2 * (others + searches), replace=False)
    starts = [ids[i] for i in picks[: others + searches]]
    goals = [ids[i] for i in picks[others + searches :]]
    rows = distances_to(plant, goals)
    table = TimeWindowTable(GAP_S)
    for k in range(others):
        plan = search(plant, table, geometry, k + 1, starts[k], goals[k], rows[k], WINDOW_S).plan
        if plan is not None:
            book_horizon(table, plan)
    out = {"plant": f"{name} ({plant.n:,} nodes)", "others": others, "searches": searches}
    runs = {"baseline": ([], [], [], []), "windowed": ([], [], [], [])}
    settings = [("baseline", math.inf), ("windowed", WINDOW_S)]
    for k in range(others, others + searches):
        # each search both ways in turn, first one then the other, so that a busy machine
        # slows both alike
        for label, until in settings if k % 2 else settings[::-1]:
            expansions, steps, seconds, arrivals = runs[label]
            begin = time.perf_counter()
            s = search(plant, table, geometry, k + 1, starts[k], goals[k], rows[k], until)
            seconds.append(time.perf_counter() - begin)
            expansions.append(s.expansions)
            steps.append(s.descended)
            arrivals.append(s.plan.arrival if s.plan is not None else math.nan)
    for label, (expansions, steps, seconds, _) in runs.items():
        out[label] = {
            "expansions": float(np.mean(expansions)),
            "descent": float(np.mean(steps)),
            "ms": 1e3 * float(np.median(seconds)),  # robust to a busy machine's preemptions
        }
    base, win = np.array(runs["baseline"][3]), np.array(runs["windowed"][3])
    both = ~np.isnan(base) & ~np.isnan(win)
    out["found"] = (int((~np.isnan(base)).sum()), int((~np.isnan(win)).sum()))
    out["arrival_ratio"] = float(np.mean(win[both] / np.maximum(base[both], 1e-9)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--searches", type=int, default=60)
    ap.add_argument("--others", type=int, default=None, help="default: 10 %% of nodes, <= 500")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="kiva only, 15 searches, 40 others")
    args = ap.parse_args()
    begin = time.perf_counter()
    plants = [("kiva", kiva())]
    if not args.quick:
        plants.insert(0, ("warehouse 99x138", plant_for(1000)[0]))
    searches = 15 if args.quick else args.searches
    print(
        f"Safe-interval search with and without a {WINDOW_S:g} s conflict window, Python "
        f"{sys.version.split()[0]}: {searches} searches per plant through the windows of "
        "others planned before them"
    )
    print()
    print(
        "| plant | others | searches found (baseline / windowed) | expansions baseline | "
        "expansions windowed | descent steps windowed | median ms baseline | median ms windowed | "
        "windowed / baseline ms | arrival windowed / baseline |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, plant in plants:
        others = 40 if args.quick else (args.others or min(500, plant.n // 10))
        r = measure(name, plant, searches, others, args.seed)
        b, w = r["baseline"], r["windowed"]
        print(
            f"| {r['plant']} | {others} | {r['found'][0]} / {r['found'][1]} | "
            f"{b['expansions']:.1f} | {w['expansions']:.1f} | {w['descent']:.1f} | "
            f"{b['ms']:.2f} | {w['ms']:.2f} | {w['ms'] / b['ms']:.2f} | "
            f"{r['arrival_ratio']:.3f} |"
        )
    print()
    print(f"wall time {time.perf_counter() - begin:.1f} s")


if __name__ == "__main__":
    main()
