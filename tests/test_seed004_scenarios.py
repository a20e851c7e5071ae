"""The time-window planning study's experiments as tests (bench/time_windows.py runs them
with the tables): the head-on ordering, and its task sets planned without a conflict."""

import importlib.util
import sys
from pathlib import Path

import pytest
from plan_monitor import PlanMonitor

from blocks.traffic.path_heat import arc_usage, heat_weights
from blocks.traffic.time_windows import TimeWindowTable

ROOT = Path(__file__).resolve().parent.parent
spec = importlib.util.spec_from_file_location(
    "bench_time_windows", ROOT / "bench" / "time_windows.py"
)
bench = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = bench  # its dataclasses look their module up
spec.loader.exec_module(bench)


@pytest.fixture(scope="module")
def plant():
    return bench.seed_grid(6.0)


def test_head_on_waiting_costs_more_than_the_detour_which_costs_more_than_no_conflict(plant):
    h = bench.head_on(plant, dwell_s=10.0)
    assert h.no_conflict.arrival < h.detour.arrival < h.waiting.arrival
    # the routes meet on column 14 between rows 5 and 10, where the study says they do
    (a, b) = h.conflict
    assert {bench.xy(a)[0], bench.xy(b)[0]} == {14}
    assert all(5 <= bench.xy(n)[1] <= 10 for n in (a, b))
    # waiting keeps the route and only waits; the detour leaves it beside the conflict
    route = bench.along(bench.H2)
    assert h.waiting.nodes == tuple(route) and h.no_conflict.nodes == tuple(route)
    off = [bench.xy(n) for n in h.detour.nodes if n not in route]
    assert off and all(x in (13, 15) and 5 <= y <= 9 for x, y in off)
    # with the study's speed and cell size, no-conflict time is the study's to within 1 s
    assert h.no_conflict.arrival == pytest.approx(bench.PUBLISHED_HEAD_ON["no conflict"], abs=1.0)


def test_both_head_on_plans_keep_clear_of_h1(plant):
    h = bench.head_on(plant, dwell_s=10.0)
    r1 = bench.along(bench.H1)
    table = TimeWindowTable(bench.GAP_S)
    h1 = bench.plan(plant, table, 1, r1[0], r1[-1], 10.0, allowed=bench.arcs_of(plant, r1))
    monitor = PlanMonitor(bench.GAP_S)
    monitor.add(h1)
    assert monitor.conflicts(h.waiting) == [] and monitor.conflicts(h.detour) == []
    assert monitor.conflicts(h.no_conflict) != []  # it would meet h1 head-on


@pytest.mark.parametrize("mode", ["dijkstra", "time_windows", "heat"])
def test_twelve_tasks_are_all_planned_and_no_two_plans_conflict(plant, mode):
    totals = bench.run_tasks(plant, 12, mode, dwell_s=10.0)
    assert totals.planned == 12
    # replay the same planning and check every pair of plans independently
    tasks = [(bench.cell(*s), bench.cell(*g)) for s, g in bench.TASKS]
    routes = [bench.dijkstra_route(plant, s, g) for s, g in tasks]
    weights = heat_weights(arc_usage(plant, routes)).tolist() if mode == "heat" else None
    table, monitor = TimeWindowTable(bench.GAP_S), PlanMonitor(bench.GAP_S)
    for vehicle, ((s, g), route) in enumerate(zip(tasks, routes, strict=True), start=1):
        kw = (
            {"allowed": bench.arcs_of(plant, route)} if mode == "dijkstra" else {"weights": weights}
        )
        p = bench.plan(plant, table, vehicle, s, g, 10.0, **kw) or bench.plan(
            plant, table, vehicle, s, g, 10.0
        )
        assert monitor.conflicts(p) == []
        monitor.add(p)


def test_the_time_window_planner_is_never_slower_in_total_than_dijkstra_with_waiting(plant):
    for n in (4, 8, 12):
        base = bench.run_tasks(plant, n, "dijkstra", 10.0)
        tw = bench.run_tasks(plant, n, "time_windows", 10.0)
        assert tw.time <= base.time


def test_path_heat_weights_follow_the_studys_formula():
    import numpy as np

    h = np.array([0, 1, 2, 3])
    assert heat_weights(h).tolist() == [1.0, 2.0, 3.0, 4.0]  # nobody driving: the guard
    b = np.array([0, 1, 0, 2])
    # sum(b h) = 1 + 6 = 7; F = (b + 1) h / 7
    assert heat_weights(h, b) == pytest.approx([1.0, 1 + 2 / 7, 1 + 2 / 7, 1 + 9 / 7])
    with pytest.raises(ValueError, match="differ in length"):
        heat_weights(h, np.array([1]))
    with pytest.raises(ValueError, match="negative"):
        heat_weights(np.array([-1]))


def test_path_heat_usage_follows_each_shortest_route_down_its_distances():
    """h counts, per arc, the shortest routes that drive it: two routes along the top row
    of a 2 x 4 grid share its last arcs; a route already at its goal, or cut off from it,
    counts nothing."""
    import numpy as np

    from blocks.routing.heuristic import distances_to
    from blocks.traffic.path_heat import usage_along_distances
    from topology.grid import grid_plant

    grid = grid_plant(np.ones((2, 4), dtype=bool))  # ids 0..3 top row, 4..7 below
    to_3 = distances_to(grid, [3])[0]
    h = usage_along_distances(grid, [(grid.idx(0), to_3), (grid.idx(1), to_3), (grid.idx(3), to_3)])
    src, dst, _ = grid.arcs
    ids = grid.ids
    used = {
        (int(ids[u]), int(ids[v])): int(n)
        for u, v, n in zip(src.tolist(), dst.tolist(), h.tolist(), strict=True)
        if n
    }
    assert sum(used.values()) == 3 + 2  # 0 -> 3 is three arcs, 1 -> 3 two
    assert used.get((2, 3), 0) + used.get((6, 7), 0) + used.get((7, 3), 0) >= 1
    assert all(n <= 2 for n in used.values())
    cut_off = np.full(grid.n, np.inf)
    assert usage_along_distances(grid, [(grid.idx(0), cut_off)]).sum() == 0
