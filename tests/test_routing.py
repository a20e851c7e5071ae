"""HeuristicTable and IncrementalAStar against an independent oracle, cycle by cycle."""

import math
import time

import networkx as nx
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from blocks.routing.astar import IncrementalAStar
from blocks.routing.constraints import RoutingConstraints
from blocks.routing.heuristic import HeuristicTable, distances_to
from plc_runtime import FunctionBlock, Runtime, VirtualClock
from topology import Edge, Node, Plant, grid, model_plant, route_cost


class Watch(FunctionBlock):
    """Runs after the A* block in the same task and checks its outputs every cycle."""

    def __init__(self, astar: IncrementalAStar, budget: int | None):
        super().__init__()
        self.astar, self.budget, self.log = astar, budget, []

    def cycle(self, ctx):
        a = self.astar
        if self.budget is not None:
            assert a.expansions_last_cycle <= self.budget
        if a.busy:  # nothing partial is ever visible
            assert a.route == () and not a.done and a.cost == 0.0
        self.log.append((a.busy, a.done, a.route))


def search(plant, start, goal, budget=1, heuristic="table", constraints=None, max_cycles=100_000):
    table = HeuristicTable(plant, targets=[goal]) if heuristic == "table" else None
    astar = IncrementalAStar(plant, table, heuristic=heuristic, constraints=constraints)
    watch = Watch(astar, budget)
    rt = Runtime(cycle_time=1.0, clock=VirtualClock())
    rt.add_task("main", [b for b in (table, astar, watch) if b is not None])
    rt.start()
    astar.request, astar.start, astar.goal, astar.budget = True, start, goal, budget
    assert rt.run_until(lambda: astar.done, max_cycles=max_cycles)
    assert rt.state == "RUN", rt.fault_reason
    rt.stop()
    return astar


def oracle_cost(plant, start, goal, constraints=None) -> float:
    """networkx Dijkstra on the same graph with blocked arcs removed and penalties added."""
    g = nx.DiGraph()
    g.add_nodes_from(plant.ids.tolist())
    src, dst, length = plant.arcs
    for arc, (u, v, w) in enumerate(zip(src.tolist(), dst.tolist(), length.tolist(), strict=True)):
        if constraints is not None and constraints.blocked[arc]:
            continue
        w += constraints.penalty[arc] if constraints is not None else 0.0
        a, b = int(plant.ids[u]), int(plant.ids[v])
        if not g.has_edge(a, b) or g[a][b]["weight"] > w:
            g.add_edge(a, b, weight=w)
    try:
        return nx.dijkstra_path_length(g, start, goal)
    except nx.NetworkXNoPath:
        return math.inf


@st.composite
def plants(draw, integer_lengths=False, min_length=0):
    n = draw(st.integers(2, 18))
    ids = draw(st.lists(st.integers(0, 60), min_size=n, max_size=n, unique=True))
    nodes = [
        Node(i, x=float(draw(st.integers(0, 9))), y=float(draw(st.integers(0, 9)))) for i in ids
    ]
    pairs = draw(st.lists(st.tuples(st.sampled_from(ids), st.sampled_from(ids)), max_size=3 * n))
    edges = []
    for a, b in pairs:
        if a == b:
            continue
        length = (
            draw(st.integers(min_length, 20))
            if integer_lengths
            else draw(st.floats(min_length, 20, allow_nan=False, allow_infinity=False))
        )
        edges.append(
            Edge(
                a,
                b,
                float(length),
                bidirectional=draw(st.booleans()),
                routable=draw(st.booleans() | st.just(True)),
            )
        )
    return Plant.build(nodes, edges)


def random_constraints(draw, plant):
    constraints = RoutingConstraints(plant)
    if plant.n_arcs:
        arcs = draw(st.lists(st.integers(0, plant.n_arcs - 1), max_size=plant.n_arcs))
        constraints.blocked[arcs] = True
        for arc in draw(st.lists(st.integers(0, plant.n_arcs - 1), max_size=4)):
            constraints.penalty[arc] = draw(st.floats(0, 100))
    return constraints


SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(st.data())
def test_route_cost_matches_the_oracle_under_blockades_and_penalties(data):
    plant = data.draw(plants())
    start, goal = (
        data.draw(st.sampled_from(plant.ids.tolist())),
        data.draw(st.sampled_from(plant.ids.tolist())),
    )
    constraints = random_constraints(data.draw, plant)
    budget = data.draw(st.sampled_from([1, 2, 5, None]))
    heuristic = data.draw(st.sampled_from(["table", "euclidean", "manhattan", "zero"]))
    astar = search(plant, start, goal, budget, heuristic, constraints)
    expected = oracle_cost(plant, start, goal, constraints)
    if math.isinf(expected):
        assert astar.no_route and astar.route == ()
        return
    assert not astar.no_route
    assert astar.cost == pytest.approx(expected, rel=1e-9, abs=1e-9)
    route = astar.route
    assert route[0] == start and route[-1] == goal
    for a, b in zip(route, route[1:], strict=False):  # a valid route: routable, unblocked arcs
        arcs = plant.arc_index.get((a, b), [])
        assert any(not constraints.blocked[arc] for arc in arcs), (a, b)
    assert route_cost(plant, route) <= astar.cost + 1e-9  # penalties only add


@SETTINGS
@given(st.data())
def test_exact_table_expands_only_the_route(data):
    plant = data.draw(plants(integer_lengths=True, min_length=1))
    start, goal = (
        data.draw(st.sampled_from(plant.ids.tolist())),
        data.draw(st.sampled_from(plant.ids.tolist())),
    )
    astar = search(plant, start, goal, budget=1)
    assume(not astar.no_route)
    assert astar.expansions == len(
        astar.route
    )  # thesis 3.5.2: six nodes on the path, six expansions
    assert astar.cycles == astar.expansions  # one expansion per cycle


@SETTINGS
@given(st.data())
def test_table_is_exact_distance_to_each_target(data):
    plant = data.draw(plants())
    target = data.draw(st.sampled_from(plant.ids.tolist()))
    row = distances_to(plant, [target])[0]
    for node in plant.ids.tolist():
        expected = oracle_cost(plant, node, target)
        got = float(row[plant.idx(node)])
        if math.isinf(expected):
            assert math.isinf(got)
        else:
            assert got <= expected  # rounded down to float32: never overestimates
            assert got == pytest.approx(expected, rel=1e-6, abs=1e-6)


def test_model_plant_routes_and_one_way_lanes():
    plant = model_plant()
    astar = search(plant, 0, 24)
    assert astar.route == (0, 6, 7, 8, 9, 24) and astar.cost == pytest.approx(5.0)
    top = search(plant, 0, 15)  # the top lane is one-way left to right: up through station 23
    assert top.route == (0, 23, 1, 15)
    back = search(plant, 18, 15)  # from the end of the top lane back to its start
    assert back.route[0] == 18 and 23 in back.route and not back.no_route


def test_blockade_and_clearing_at_run_time():
    plant = model_plant()
    constraints = RoutingConstraints(plant)
    constraints.block(7, 8)
    detour = search(plant, 0, 24, constraints=constraints)
    assert (7, 8) not in zip(detour.route, detour.route[1:], strict=False)
    assert detour.cost > 5.0
    constraints.unblock(7, 8)
    assert search(plant, 0, 24, constraints=constraints).cost == pytest.approx(5.0)


def test_penalty_is_not_a_wall():
    plant = model_plant()
    constraints = RoutingConstraints(plant)
    for a, b in [(9, 24)]:  # the only way to the exit is occupied: still routed, at a price
        constraints.penalize(a, b, 1000.0)
    astar = search(plant, 0, 24, constraints=constraints)
    assert astar.route[-2:] == (9, 24) and astar.cost == pytest.approx(1005.0)


def test_new_request_aborts_a_running_search():
    plant = grid(20, 20, obstacles=0.0, stations=0)
    table = HeuristicTable(plant, targets=[399, 19])
    astar = IncrementalAStar(plant, table)
    rt = Runtime(cycle_time=1.0, clock=VirtualClock())
    rt.add_task("main", [table, astar])
    rt.start()
    astar.request, astar.start, astar.goal = True, 0, 399
    rt.step(5)
    assert astar.busy and astar.route == ()
    astar.request = False
    rt.step()
    astar.request, astar.goal = True, 19  # new goal: the old search is dropped
    assert rt.run_until(lambda: astar.done, max_cycles=1000)
    assert astar.route[-1] == 19 and astar.expansions == 20 and astar.cycles == 20
    rt.stop()


def test_time_budget_and_unknown_nodes():
    plant = grid(30, 30, obstacles=0.0, stations=0)
    astar = search(plant, 0, 899, budget=None, heuristic="zero")  # 1 s task budget: done at once
    assert astar.cycles == 1 and astar.cost == pytest.approx(58.0)
    bad = search(plant, 0, 5000, heuristic="zero")
    assert bad.no_route and bad.error == "unknown goal node 5000"


def test_first_use_row_and_topology_change():
    plant = model_plant()
    expected = search(plant, 0, 17).cost  # the oracle run first: one runtime at a time
    table = HeuristicTable(plant, targets=[24])
    astar = IncrementalAStar(plant, table)
    rt = Runtime(cycle_time=1.0, clock=VirtualClock())
    rt.add_task("main", [table, astar])
    rt.start()
    astar.request, astar.start, astar.goal = True, 0, 17  # 17 is not in the table
    assert rt.run_until(lambda: astar.done, max_cycles=100)
    assert table.rows_computed_in_cycle == 1 and astar.cost == pytest.approx(expected)
    bigger = Plant.build(
        plant.nodes, (*plant.edges, Edge(0, 24, 0.5)), name="shortcut", functions=plant.functions
    )
    table.plant = bigger
    rt.step()
    assert "topology change rejected" in table.error and table.served_plant is plant
    rt.stop()
    rt.start()  # the restart adopts the new topology
    assert table.error is None and table.served_plant is bigger
    rt.stop()


def test_budget_bounds_every_cycle_on_a_large_grid():
    plant = grid(60, 60, obstacles=0.2, seed=3, stations=0)
    ids = plant.ids.tolist()
    astar = search(plant, ids[0], ids[-1], budget=7, heuristic="manhattan")
    expected = oracle_cost(plant, ids[0], ids[-1])
    assert astar.no_route == math.isinf(expected)
    if not astar.no_route:
        assert astar.cost == pytest.approx(expected)


def test_microsecond_budget_always_progresses_and_stops_in_time():
    plant = grid(15, 15, obstacles=0.0, stations=0)
    table = HeuristicTable(plant, targets=[224])
    astar = IncrementalAStar(plant, table)
    per_cycle = []
    rt = Runtime(cycle_time=1.0, clock=VirtualClock())
    rt.add_task("main", [table, astar, Watch(astar, None)])
    rt.start()
    astar.request, astar.start, astar.goal, astar.budget, astar.budget_us = True, 0, 224, None, 0
    while not astar.done:
        rt.step()
        per_cycle.append(astar.expansions_last_cycle)
    # no time at all: exactly the one expansion every cycle is guaranteed, never more
    assert per_cycle == [1] * len(per_cycle) and astar.cycles == len(astar.route) == 29
    astar.request = False
    rt.step()
    astar.request, astar.budget_us = True, 1_000_000  # a whole second: done in one cycle
    rt.step()
    assert astar.done and astar.cycles == 1 and astar.cost == 28.0
    rt.stop()


class Slow(FunctionBlock):
    """A block before the search that uses up more real time than the scan's budget."""

    def cycle(self, ctx):
        end = time.perf_counter() + 0.003
        while time.perf_counter() < end:
            pass


def expansions_after_a_slow_block(clock) -> list[int]:
    plant = grid(15, 15, obstacles=0.0, stations=0)
    table = HeuristicTable(plant, targets=[224])
    astar = IncrementalAStar(plant, table)
    # a 2 ms budget that the slow block always exceeds; the watchdog is not what this tests
    rt = Runtime(cycle_time=1.0, clock=clock, watchdog=60.0)
    rt.add_task("main", [table, Slow(), astar], budget=0.002)
    rt.start()
    astar.request, astar.start, astar.goal, astar.budget = True, 0, 224, 5
    per_cycle = []
    while not astar.done:
        rt.step()
        per_cycle.append(astar.expansions_last_cycle)
    rt.stop()
    assert astar.route and astar.cost == 28.0
    return per_cycle


def test_virtual_clock_search_does_not_depend_on_the_hosts_speed():
    """Past its scan's deadline on the wall clock a search stops after one expansion; on
    the virtual clock the deadline never comes, so the search does its whole budget every
    cycle and a run is the same whatever else the machine is doing."""
    assert expansions_after_a_slow_block(VirtualClock()) == [5] * 5 + [4]
    charged = expansions_after_a_slow_block(VirtualClock(charge_execution=True))
    assert charged == [1] * 29


@SETTINGS
@given(st.data())
def test_optimal_where_float32_rounding_of_the_table_matters(data):
    """Long segments plus fractions: the float32 table is then not exactly consistent; the
    search must still return the optimal cost (it re-opens nodes instead of trusting h)."""
    n = data.draw(st.integers(3, 8))
    pairs = data.draw(
        st.lists(
            st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), min_size=2, max_size=3 * n
        )
    )
    edges = [
        Edge(
            a,
            b,
            data.draw(st.sampled_from([0.0, 0.25, 0.5, 1.0, 1.3]))
            + data.draw(st.sampled_from([0.0, 1.6e7, 3e7])),
            bidirectional=data.draw(st.booleans()),
        )
        for a, b in pairs
        if a != b
    ]
    plant = Plant.build([Node(i) for i in range(n)], edges)
    astar = search(plant, 0, n - 1, budget=100)
    expected = oracle_cost(plant, 0, n - 1)
    assert astar.no_route == math.isinf(expected)
    if not astar.no_route:
        assert astar.cost == expected


def test_first_use_row_is_for_the_goal_the_search_started_with():
    plant = Plant.build(
        [Node(i) for i in range(4)],
        [Edge(0, 1, 1.0), Edge(1, 2, 1.0), Edge(3, 2, 1.0, bidirectional=False)],
    )
    table = HeuristicTable(plant, targets=[])  # every row on first use
    astar = IncrementalAStar(plant, table)
    rt = Runtime(cycle_time=1.0, clock=VirtualClock())
    rt.add_task("main", [table, astar])
    rt.start()
    astar.start, astar.goal, astar.request = 0, 2, True
    rt.step()
    astar.goal = 3  # the input changes, but without a new rising edge
    assert rt.run_until(lambda: astar.done, max_cycles=50)
    assert astar.route == (0, 1, 2) and not astar.no_route
    rt.stop()


def test_reordered_plant_is_another_topology_for_the_table():
    plant = model_plant()
    same = Plant.build(plant.nodes, plant.edges, name="reloaded", functions=plant.functions)
    reordered = Plant.build(tuple(reversed(plant.nodes)), plant.edges, functions=plant.functions)
    assert same.fingerprint == plant.fingerprint
    assert (
        reordered.fingerprint != plant.fingerprint
    )  # indices differ: tables and constraints would not fit
    table = HeuristicTable(plant)
    astar = IncrementalAStar(plant, table)
    rt = Runtime(cycle_time=1.0, clock=VirtualClock())
    rt.add_task("main", [table, astar])
    rt.start()
    table.plant = same
    rt.step()
    assert table.error is None and table.served_plant is same  # the same topology: adopted
    table.plant = reordered
    rt.step()
    assert "topology change rejected" in table.error and table.served_plant is same
    rt.stop()


@pytest.mark.parametrize("a", ["7", 7.0, True])
def test_a_segment_named_by_something_else_than_integers_says_so(a):
    """block("7", "8") is a type mistake, not a segment the plant lacks."""
    from topology import TopologyError

    with pytest.raises(TopologyError, match="node ids are integers, got"):
        RoutingConstraints(model_plant()).block(a, 8)
    with pytest.raises(TypeError, match="penalty must be a number, got '3'"):
        RoutingConstraints(model_plant()).penalize(7, 8, "3")


def test_a_table_asked_before_its_startup_says_how_to_get_one():
    """Outside a runtime the table is not built yet: the error says so and names the
    function that gives exact distances without one (it was an AttributeError on None)."""
    plant = model_plant()
    table = HeuristicTable(plant)
    with pytest.raises(RuntimeError, match=r"built at startup.*distances_to\(plant, targets\)"):
        table.distance(0, 24)
    assert distances_to(plant, [24])[0][plant.idx(0)] > 0
