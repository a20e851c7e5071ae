"""Property-based tests of the fleet program on random plants, fleets, recipes and blockades.

Safety (every cycle, from the independent monitor): no head-on conflict, no node conflict,
the A* budget is kept. Liveness (docs/fleet-config.md, "Liveness"): on plants that meet
the stated condition every vehicle keeps completing recipes within a bound.
"""

from __future__ import annotations

from dataclasses import replace

import networkx as nx
from fleet_scenarios import make_config, run
from hypothesis import HealthCheck, Phase, assume, given, settings
from hypothesis import strategies as st

from fleet.config import Blockade
from fleet.program import FleetProgram
from topology import Edge, Node, Plant

# Each example simulates minutes of plant time, so shrinking a failure would take many
# minutes: a failing example is reported as found (derandomized, so it reproduces).
SETTINGS = settings(
    max_examples=25,
    deadline=None,
    derandomize=True,
    database=None,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
MAX_OCCUPANCY = 0.10  # the liveness condition's share of nodes a fleet may occupy


def undirected(plant: Plant) -> nx.Graph:
    g = nx.Graph()
    g.add_nodes_from(int(i) for i in plant.ids)
    for e in plant.edges:
        if e.routable:
            g.add_edge(e.source, e.target)
    return g


def meets_liveness_condition(plant: Plant, vehicles: int) -> bool:
    """Two-way segments forming a 2-connected graph, at most MAX_OCCUPANCY of the nodes held
    by vehicles, every function at two stations or more (docs/fleet-config.md)."""
    g = undirected(plant)
    two_way = all(e.bidirectional for e in plant.edges if e.routable)
    spread = all(len(plant.stations_for(f)) >= 2 for f in (2, 3))
    return two_way and spread and nx.is_biconnected(g) and vehicles <= MAX_OCCUPANCY * plant.n


@st.composite
def grid_plants(draw) -> Plant:
    """Grids with obstacles; stations on random free cells."""
    w, h = draw(st.integers(4, 9)), draw(st.integers(3, 7))
    blocked = draw(
        st.sets(st.tuples(st.integers(0, w - 1), st.integers(0, h - 1)), max_size=w * h // 6)
    )
    cells = [(x, y) for y in range(h) for x in range(w) if (x, y) not in blocked]
    ids = {c: k for k, c in enumerate(cells)}
    edges = []
    for (x, y), k in ids.items():
        for nb in ((x + 1, y), (x, y + 1)):
            if nb in ids:
                edges.append(Edge(k, ids[nb], 1.0))
    stations = draw(st.lists(st.sampled_from(cells), min_size=2, max_size=6, unique=True))
    func = {c: 2 + i % 2 for i, c in enumerate(stations)}
    nodes = [
        Node(
            k,
            f"c{x}_{y}",
            float(x),
            float(y),
            "station" if c in func else "transit",
            (func[c],) if c in func else (),
        )
        for c, k in ids.items()
        for x, y in [c]
    ]
    assume(len({func[c] for c in stations}) == 2)
    g = nx.Graph()
    g.add_nodes_from(ids.values())
    g.add_edges_from((e.source, e.target) for e in edges)
    assume(nx.is_connected(g))
    return Plant.build(nodes, edges, name="grid", functions={2: "a", 3: "b"})


@st.composite
def ring_plants(draw) -> Plant:
    """A two-way ring whose segments are single-lane bottlenecks, except where a passing
    loop (a parallel node) lets vehicles get round each other."""
    m = draw(st.integers(8, 20))
    loops = draw(st.sets(st.integers(0, m - 1), min_size=1, max_size=m // 2))
    nodes, edges = [], []
    for k in range(m):
        angle = 2 * 3.14159 * k / m
        nodes.append(
            Node(k, f"r{k}", 3 * __import__("math").cos(angle), 3 * __import__("math").sin(angle))
        )
        edges.append(Edge(k, (k + 1) % m, 1.0))
    for j, k in enumerate(sorted(loops)):
        loop = m + j
        a = nodes[k]
        nodes.append(Node(loop, f"p{k}", a.x * 1.3, a.y * 1.3))
        edges += [Edge(k, loop, 0.8), Edge(loop, (k + 1) % m, 0.8)]
    stations = draw(st.lists(st.integers(0, m - 1), min_size=2, max_size=6, unique=True))
    nodes = [
        Node(n.id, n.name, n.x, n.y, "station", (2 + stations.index(n.id) % 2,))
        if n.id in stations
        else n
        for n in nodes
    ]
    return Plant.build(nodes, edges, name="ring", functions={2: "a", 3: "b"})


@st.composite
def with_areas(draw, plants) -> Plant:
    """A plant in which some stations form a single-vehicle area with a neighbour (a
    transfer station and the node in front of it)."""
    plant = draw(plants)
    stations = [n.id for n in plant.nodes if n.role == "station"]
    chosen = draw(st.lists(st.sampled_from(stations), min_size=1, max_size=3, unique=True))
    area: dict[int, str] = {}
    for station in chosen:
        if station in area:
            continue
        near = sorted(
            int(plant.ids[v])
            for v, _, _ in plant.neighbors[plant.idx(station)]
            if int(plant.ids[v]) not in area
        )
        if near:
            area[station] = area[draw(st.sampled_from(near))] = f"at{station}"
    nodes = [replace(n, area=area.get(n.id)) for n in plant.nodes]
    return Plant.build(nodes, list(plant.edges), name=plant.name, functions=plant.functions)


def one_per_area(plant: Plant, starts: list[int]) -> bool:
    """No two vehicles start in one single-vehicle area (a configuration refuses that)."""
    areas = [plant.node(s).area for s in starts if plant.node(s).area]
    return len(areas) == len(set(areas))


@st.composite
def fleets(draw, plants, traffic: str = "reactive"):
    plant = draw(plants)
    max_vehicles = max(1, int(MAX_OCCUPANCY * plant.n))
    count = draw(st.integers(1, min(max_vehicles, 6)))
    starts = draw(
        st.lists(
            st.sampled_from([int(i) for i in plant.ids]),
            min_size=count,
            max_size=count,
            unique=True,
        )
    )
    assume(one_per_area(plant, starts))
    # consecutive steps need different functions, also from one round to the next (the
    # liveness condition: a vehicle never has a reason to stay at a station for ever)
    recipes = {"ab": [2, 3], "ba": [3, 2], "abab": [2, 3, 2, 3]}
    own = {v + 1: [draw(st.sampled_from(sorted(recipes)))] for v in range(count)}
    blockades = []
    if draw(st.booleans()):
        e = draw(st.sampled_from([e for e in plant.edges if e.routable]))
        at = draw(st.floats(5, 60))
        blockades.append(Blockade(e.source, e.target, at, at + draw(st.floats(5, 30))))
    clusters = {f: [n.id for n in plant.nodes if f in n.functions] for f in (2, 3)}
    strategy = draw(
        st.sampled_from(["random", "round_robin", "least_utilised", "nearest", "occupancy_aware"])
    )
    cfg = make_config(
        plant,
        {v + 1: s for v, s in enumerate(starts)},
        recipes,
        clusters,
        vehicle_recipes=own,
        strategy=strategy,
        processing_s=1.0,
        cycle_time=0.05,
        astar_budget=draw(st.integers(1, 4)),
        blockades=blockades,
        seed=draw(st.integers(0, 1000)),
        traffic=traffic,
    )
    return cfg


def simulate(cfg, seconds: float) -> FleetProgram:
    p = FleetProgram(cfg)
    try:
        run(p, seconds)  # asserts zero conflicts and the A* budget after every cycle
    finally:
        p.close()
    return p


@SETTINGS
@given(fleets(st.one_of(grid_plants(), ring_plants())))
def test_no_conflicts_and_budget_on_any_plant(cfg):
    """Safety holds whether or not the plant meets the liveness condition."""
    simulate(cfg, 90)


@SETTINGS
@given(fleets(st.one_of(grid_plants(), ring_plants())))
def test_every_vehicle_keeps_completing_recipes_when_the_condition_holds(cfg):
    assume(meets_liveness_condition(cfg.plant, len(cfg.starts)))
    # the bound: every vehicle two recipes within 120 s plus 60 s per vehicle (they share
    # the stations: with one station for a function, each visit waits for the others)
    p = simulate(cfg, 120 + 60 * len(cfg.starts))
    for v in cfg.starts:
        done = [r for r in p.completed if r.vehicle == v]
        assert len(done) >= 2, (
            v,
            p.resolver.events[-5:],
            {u: c.state for u, c in p.controls.items()},
        )
    assert p.resolver.unresolved == 0


# The time-window mode: the same safety on any plant, and on plants that meet the liveness
# condition every vehicle keeps completing recipes, with no waits-for cycle ever formed
# (execution by order: the plans' order leaves none to resolve, and nobody is pushed).
@SETTINGS
@given(fleets(st.one_of(grid_plants(), ring_plants()), traffic="time_windows"))
def test_time_windows_no_conflicts_on_any_plant(cfg):
    simulate(cfg, 90)


@SETTINGS
@given(fleets(with_areas(st.one_of(grid_plants(), ring_plants())), traffic="time_windows"))
def test_time_windows_no_conflicts_on_any_plant_with_single_vehicle_areas(cfg):
    simulate(cfg, 90)


@SETTINGS
@given(fleets(st.one_of(grid_plants(), ring_plants()), traffic="time_windows"))
def test_time_windows_every_vehicle_keeps_completing_recipes(cfg):
    assume(meets_liveness_condition(cfg.plant, len(cfg.starts)))
    p = simulate(cfg, 120 + 60 * len(cfg.starts))
    for v in cfg.starts:
        done = [r for r in p.completed if r.vehicle == v]
        assert len(done) >= 2, (v, {u: (c.state, c.current, c.goal) for u, c in p.controls.items()})
    assert p.resolver.detected == 0, p.resolver.events[:3]
    assert p.resolver.pushes == 0
    assert p.traffic.rounds > 0
