"""SafeIntervalSearch against a brute-force time-expanded search on small grids.

The model of these tests: 1 m cells, 1 m/s, turns of 1 s (90 degrees) and 2 s (U-turn), a
gap of 1 s, so every time is a whole second and a search over (cell, heading, second) with
waits of one second finds the earliest arrival by exhaustion. Its conflict rules are written
here from their definitions, not taken from the table, so the two are checked against each
other: the search must find exactly the brute force's earliest arrival, and its plan must be
a drivable path that breaks no rule against any other vehicle's windows.
"""

import math
import random

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from plan_monitor import PlanMonitor

from blocks.routing.heuristic import distances_to
from blocks.traffic.sipp import SafeIntervalSearch, TimedPlan, TurnTimes, plan_path
from blocks.traffic.time_windows import TimeWindowTable, WindowConflict
from topology import Edge, Node, Plant
from topology.grid import grid_plant

GAP = 1.0
TURNS = TurnTimes(1.0, 2.0)
HORIZON = 80


def grid(passable) -> object:
    return grid_plant(np.asarray(passable, dtype=bool))


def direction(plant, a, b):
    na, nb = plant.node(a), plant.node(b)
    return (nb.x - na.x, nb.y - na.y)


def turn(before, after) -> float:
    """90-degree grid turns by their definition: straight 0, a quarter turn 1, back 2."""
    if before is None:
        return 0.0
    dot = before[0] * after[0] + before[1] * after[1]
    return 0.0 if dot > 0 else (2.0 if dot < 0 else 1.0)


def brute_force(
    plant, others: PlanMonitor, start, goal, t0, heading=None, claim="departure"
) -> float | None:
    """Earliest arrival at ``goal`` with a stay for good, by breadth-first search over
    (cell, heading, second, seconds waited so far capped at 2). ``claim``: the window on a
    cell opens when the vehicle sets off towards it, or when it arrives."""
    frontier = {(start, heading, 0)} if others.node_free(start, t0, t0) else set()
    t = t0
    seen = set()
    while frontier and t <= t0 + HORIZON:
        nxt = set()
        for node, head, waited in frontier:
            if node == goal and others.node_free(goal, t, math.inf):
                return t
            if (node, head, waited, t) in seen:
                continue
            seen.add((node, head, waited, t))
            if others.node_free(node, t, t + 1):
                nxt.add((node, head, min(waited + 1, 2)))
            for v in plant.neighbors[plant.idx(node)]:
                to = int(plant.ids[v[0]])
                d = direction(plant, node, to)
                if waited < turn(head, d):
                    continue
                opens = t if claim == "departure" else t + 1
                if others.segment_free(node, to, t, t + 1) and others.node_free(to, opens, t + 1):
                    nxt.add((to, d, 0))
        frontier = nxt
        t += 1
    return None


def brute_force_cost(plant, others: PlanMonitor, start, goal, t0, weights) -> float | None:
    """The least cost of reaching ``goal`` to stay for good, cost being the time taken plus
    ``weights[arc] - 1`` per second driven on each arc (every move here takes 1 s): a
    dynamic programme over the seconds, keeping per (cell, heading, seconds waited) the
    least extra paid so far, until no later arrival can be cheaper."""
    layer = {(start, None, 0): 0.0} if others.node_free(start, t0, t0) else {}
    best = None
    t = t0
    while layer and t <= t0 + HORIZON and (best is None or t - t0 < best):
        nxt: dict = {}
        for (node, head, waited), extra in layer.items():
            if node == goal and all(e + GAP <= t for _, e, _ in others.nodes.get(goal, ())):
                best = min(best, t - t0 + extra) if best is not None else t - t0 + extra
            steps = []
            if others.node_free(node, t, t + 1):
                steps.append(((node, head, min(waited + 1, 2)), extra))
            for v, arc, _ in plant.neighbors[plant.idx(node)]:
                to = int(plant.ids[v])
                d = direction(plant, node, to)
                if waited < turn(head, d):
                    continue
                if others.segment_free(node, to, t, t + 1) and others.node_free(to, t, t + 1):
                    steps.append(((to, d, 0), extra + weights[arc] - 1.0))
            for key, cost in steps:
                if cost < nxt.get(key, math.inf):
                    nxt[key] = cost
        layer = nxt
        t += 1
    return best


def check_drivable(plant, plan: TimedPlan, start, goal, t0, heading=None):
    assert plan.nodes[0] == start and plan.nodes[-1] == goal
    assert plan.arrive[0] == t0
    head = heading
    for i in range(len(plan.nodes) - 1):
        a, b = plan.nodes[i], plan.nodes[i + 1]
        assert plant.arcs_between(a, b, both_ways=False)
        d = direction(plant, a, b)
        assert plan.depart[i] >= plan.arrive[i] + turn(head, d) - 1e-9
        assert plan.arrive[i + 1] == pytest.approx(plan.depart[i] + 1.0)
        head = d
    assert plan.depart[-1] == math.inf


def check_no_conflict(others: PlanMonitor, plan: TimedPlan):
    assert others.conflicts(plan) == []


def random_others(
    plant, rng: random.Random, count: int, table: TimeWindowTable, others: PlanMonitor
):
    """Other vehicles on random walks with random waits, booked where the table takes them
    (a walk that conflicts with an earlier one is left out)."""
    ids = [int(i) for i in plant.ids]
    for vehicle in range(100, 100 + count):
        node, t = rng.choice(ids), float(rng.randrange(0, 6))
        nodes, arrive, depart = [node], [t], []
        for _ in range(rng.randrange(1, 12)):
            out = plant.neighbors[plant.idx(node)]
            if not out:
                break
            t += rng.choice((0, 0, 1, 2))
            depart.append(t)
            node = int(plant.ids[rng.choice(out)[0]])
            t += 1.0
            nodes.append(node)
            arrive.append(t)
        depart.append(math.inf if rng.random() < 0.3 else t + rng.randrange(0, 4))
        plan = TimedPlan(vehicle, tuple(nodes), tuple(arrive), tuple(depart), 0.0)
        try:
            plan.book(table)
        except WindowConflict:
            continue
        others.add(plan)


def search(plant, table, start, goal, t0, heading=None):
    return plan_path(plant, table, 1, start, goal, t0, speed=1.0, turns=TURNS, heading=heading)


def test_an_empty_grid_gives_the_shortest_path_with_one_turn():
    plant = grid(np.ones((4, 4)))
    plan = search(plant, TimeWindowTable(GAP), 0, 15, 0.0)
    assert len(plan.nodes) == 7
    assert plan.arrival == 7.0  # six cells and one quarter turn
    check_drivable(plant, plan, 0, 15, 0.0)


def test_the_turn_cache_is_left_out_of_the_garbage_collectors_scans():
    """A search asks for the same turns again and again, so they are cached per plant: on a
    large plant tens of thousands of pairs, which a full collection must not traverse."""
    import gc

    from blocks.traffic.sipp import ArcGeometry

    plant = grid(np.ones((4, 4)))
    geometry = ArcGeometry(plant)
    arcs = len(geometry.direction)
    seconds = [geometry.turn(TURNS, a, b) for a in range(arcs) for b in range(arcs)]
    assert set(seconds) <= {0.0, TURNS.turn_90, TURNS.turn_180}
    assert geometry.turn(TURNS, 0, 0) == 0.0  # straight on: the same arc twice
    gc.collect()
    assert not gc.is_tracked(geometry._turns[TURNS])


def test_the_start_heading_costs_a_turn_or_a_u_turn():
    plant = grid(np.ones((1, 5)))
    east, west = (1.0, 0.0), (-1.0, 0.0)
    assert search(plant, TimeWindowTable(GAP), 0, 4, 0.0, heading=east).arrival == 4.0
    assert search(plant, TimeWindowTable(GAP), 0, 4, 0.0, heading=west).arrival == 6.0


def test_in_a_corridor_it_steps_into_a_bay_to_let_an_oncoming_vehicle_pass():
    """A 1 x 6 corridor: vehicle 2 drives 5 -> 0 and stays. Vehicle 1, at 0 and bound for 5,
    has no way past it; with a bay below cell 1 it steps in, lets vehicle 2 pass, and
    goes on."""
    corridor = grid(np.ones((1, 6)))
    table = TimeWindowTable(GAP)
    plan_path(corridor, table, 2, 5, 0, 0.0, speed=1.0, turns=TURNS).book(table)
    search_ = SafeIntervalSearch(corridor, table, 1, 0, 5, 0.0, speed=1.0, turns=TURNS)
    search_.step(None)
    assert search_.plan is None and "no conflict-free path" in search_.reason
    bay = grid([[1, 1, 1, 1, 1, 1], [0, 1, 0, 0, 0, 0]])
    table, others = TimeWindowTable(GAP), PlanMonitor(GAP)
    oncoming = plan_path(bay, table, 2, 5, 0, 0.0, speed=1.0, turns=TURNS)
    oncoming.book(table)
    others.add(oncoming)
    plan = search(bay, table, 0, 5, 0.0)
    assert plan.nodes[:3] == (0, 1, 7) and 7 not in plan.nodes[3:]
    check_drivable(bay, plan, 0, 5, 0.0)
    check_no_conflict(others, plan)
    assert plan.arrival == brute_force(bay, others, 0, 5, 0.0)


def test_a_start_node_booked_by_another_vehicle_is_reported():
    plant = grid(np.ones((2, 2)))
    table = TimeWindowTable(GAP)
    table.book(7, [(0, 0.0, 10.0)], [])
    s = SafeIntervalSearch(plant, table, 1, 0, 3, 5.0, speed=1.0)
    assert s.done and s.plan is None and "booked by another vehicle" in s.reason


def test_the_search_runs_in_bounded_steps_and_publishes_only_a_complete_plan():
    plant = grid(np.ones((10, 10)))
    s = SafeIntervalSearch(plant, TimeWindowTable(GAP), 1, 0, 99, 0.0, speed=1.0, turns=TURNS)
    steps = 0
    while not s.step(budget=3):
        steps += 1
        assert s.plan is None
        assert s.expansions <= 3 * steps
    assert s.plan.arrival == 19.0  # 18 cells, one turn
    assert steps >= 5


def test_path_heat_weights_steer_off_a_hot_row_at_a_time_cost():
    plant = grid(np.ones((3, 6)))
    hot = [1.0] * plant.n_arcs
    src, dst, _ = plant.arcs
    for arc, (u, v) in enumerate(zip(src.tolist(), dst.tolist(), strict=True)):
        if u // 6 == 0 and v // 6 == 0:
            hot[arc] = 5.0  # the top row is congested
    cold = plan_path(plant, TimeWindowTable(GAP), 1, 0, 5, 0.0, speed=1.0, turns=TURNS)
    warm = plan_path(plant, TimeWindowTable(GAP), 1, 0, 5, 0.0, speed=1.0, turns=TURNS, weights=hot)
    assert cold.nodes == (0, 1, 2, 3, 4, 5)
    assert all(n >= 6 for n in warm.nodes[1:-1])  # round through the row below
    assert warm.arrival > cold.arrival and warm.cost < 5 * 5.0


def random_areas(plant, rng: random.Random, count: int) -> dict[int, str]:
    """Up to ``count`` single-vehicle areas of two or three neighbouring cells each."""
    areas: dict[int, str] = {}
    ids = [int(i) for i in plant.ids]
    for k in range(count):
        node = rng.choice(ids)
        if node in areas:
            continue
        area = [node]
        for _ in range(rng.randrange(1, 3)):
            out = [
                int(plant.ids[v])
                for v, _, _ in plant.neighbors[plant.idx(area[-1])]
                if int(plant.ids[v]) not in areas and int(plant.ids[v]) not in area
            ]
            if out:
                area.append(rng.choice(out))
        if len(area) > 1:
            areas.update({n: f"area{k}" for n in area})
    return areas


def random_case(seed, width, height, others_count, blocked, weighted=False, areas=0):
    """A random small grid with up to ``areas`` single-vehicle areas, other vehicles' plans
    booked, arc weights of 1-3 (or None), and a random start and goal: (plant, table,
    others, weights, start, goal)."""
    rng = random.Random(seed)
    passable = np.array([[rng.random() >= blocked for _ in range(width)] for _ in range(height)])
    passable[0, 0] = True
    if passable.sum() < 2:
        passable[:] = True
    plant = grid(passable)
    shared = random_areas(plant, rng, areas)
    table, others = TimeWindowTable(GAP, shared), PlanMonitor(GAP, shared)
    random_others(plant, rng, others_count, table, others)
    weights = None
    if weighted:
        weights = [rng.choice((1.0, 1.0, 2.0, 3.0)) for _ in range(plant.n_arcs)]
    ids = [int(i) for i in plant.ids]
    return plant, table, others, weights, rng.choice(ids), rng.choice(ids)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10**6),
    width=st.integers(2, 6),
    height=st.integers(1, 5),
    others_count=st.integers(0, 8),
    blocked=st.floats(0.0, 0.3),
    t0=st.sampled_from([0.0, 1.0, 3.0]),
    heading=st.sampled_from([None, (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0)]),
    claim=st.sampled_from(["departure", "arrival"]),
    areas=st.sampled_from([0, 0, 2, 4]),
)
def test_sipp_finds_the_brute_force_earliest_arrival(
    seed, width, height, others_count, blocked, t0, heading, claim, areas
):
    """Also with single-vehicle areas, which the brute force keeps by the rule's definition:
    in every second a vehicle is on a node of an area, nobody else is on any of them."""
    plant, table, others, _, start, goal = random_case(
        seed, width, height, others_count, blocked, areas=areas
    )
    expected = brute_force(plant, others, start, goal, t0, heading, claim)
    s = SafeIntervalSearch(
        plant, table, 1, start, goal, t0, speed=1.0, turns=TURNS, heading=heading, claim=claim
    )
    s.step(None)
    if expected is None:
        # nothing within the horizon: the search may still find a later arrival
        assert s.plan is None or s.plan.arrival > t0 + HORIZON
        return
    assert s.plan is not None, s.reason
    assert s.plan.arrival == pytest.approx(expected)
    check_drivable(plant, s.plan, start, goal, t0, heading)
    check_no_conflict(others, s.plan)
    # without weights the cheapest label is the earliest: the same search
    one = plan_path(
        plant,
        table,
        1,
        start,
        goal,
        t0,
        speed=1.0,
        turns=TURNS,
        heading=heading,
        claim=claim,
        labels="cheapest",
    )
    assert one is not None and one.arrival == pytest.approx(expected)
    s.plan.book(table)  # and the table takes it


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10**6),
    width=st.integers(2, 6),
    height=st.integers(1, 5),
    others_count=st.integers(0, 8),
    blocked=st.floats(0.0, 0.3),
    t0=st.sampled_from([0.0, 1.0, 3.0]),
)
def test_with_arc_weights_sipp_finds_the_brute_force_least_cost(
    seed, width, height, others_count, blocked, t0
):
    """Weights make a later arrival the cheaper one (highways, path heat): the search must
    still find the least cost, also where the cheap way misses a free interval the dear one
    catches, and never give up while a path exists."""
    plant, table, others, weights, start, goal = random_case(
        seed, width, height, others_count, blocked, weighted=True
    )
    expected = brute_force_cost(plant, others, start, goal, t0, weights)
    s = SafeIntervalSearch(
        plant, table, 1, start, goal, t0, speed=1.0, turns=TURNS, weights=weights
    )
    s.step(None)
    if expected is None:
        assert s.plan is None or s.plan.arrival > t0 + HORIZON
        return
    assert s.plan is not None, s.reason
    assert s.plan.cost == pytest.approx(expected)
    check_drivable(plant, s.plan, start, goal, t0)
    check_no_conflict(others, s.plan)
    # the cheapest label alone: no cheaper than the least, and whatever it finds is valid
    one = SafeIntervalSearch(
        plant,
        table,
        1,
        start,
        goal,
        t0,
        speed=1.0,
        turns=TURNS,
        weights=weights,
        labels="cheapest",
    )
    one.step(None)
    if one.plan is not None:
        assert one.plan.cost >= expected - 1e-9
        check_drivable(plant, one.plan, start, goal, t0)
        check_no_conflict(others, one.plan)


def test_a_cheaper_later_way_does_not_hide_an_earlier_one_that_catches_an_interval():
    """A highway 2 -> 0 makes the direct step 0 -> 2 cost 3; the detour 0 -> 1 -> 2 costs
    2 but reaches 2 a second later, after its free interval has closed. The direct step is
    the only way on (cost 6 in all), and the search must not lose it to the detour."""
    from topology import Edge, Node, Plant

    nodes = [Node(0, "S", 0, 0), Node(1, "Q", 0, 1), Node(2, "P", 1, 0)]
    nodes += [Node(3, "M", 2, 0), Node(4, "X", 3, 0), Node(5, "G", 4, 0)]
    edges = [Edge(2, 0, 1.0, highway=True), Edge(0, 1, 1.0), Edge(1, 2, 1.0)]
    edges += [Edge(3, 4, 1.0), Edge(2, 3, 1.0), Edge(4, 5, 1.0)]
    plant = Plant.build(nodes, edges)
    table = TimeWindowTable(0.5)
    for vehicle, node, start, end in [(9, 4, 3.6, 10), (8, 3, 4, 20), (7, 2, 5, 30)]:
        table.book(vehicle, [(node, start, end)], [])
    table.book(6, [(1, 2.5, 40.0)], [])
    table.book(5, [(0, 3.0, 50.0)], [])
    weights = np.where(plant.against_highway, 3.0, 1.0).tolist()
    kw = {"speed": 1.0, "turns": TurnTimes(0, 0), "weights": weights}
    plan = plan_path(plant, table, 1, 0, 5, 0.0, **kw)
    assert plan is not None and plan.nodes == (0, 2, 3, 4, 5)
    assert plan.cost == pytest.approx(6.0) and plan.arrival == pytest.approx(4.0)
    # one label per state, the cheapest, loses it: the bounded search the fleet uses
    assert plan_path(plant, table, 1, 0, 5, 0.0, labels="cheapest", **kw) is None
    with pytest.raises(ValueError, match="labels"):
        plan_path(plant, table, 1, 0, 5, 0.0, labels="all", **kw)


def test_a_windowed_search_plans_past_a_vehicle_that_stays_on_its_goal():
    """Vehicle 2 stays on cell 3 of a corridor for good. Without a cut-off there is no
    path to it (the whole corridor is searched in vain); with conflicts resolved only
    up to 10 s, the plan waits and arrives after the cut-off, when nobody is in the way."""
    corridor = grid(np.ones((1, 4)))
    table = TimeWindowTable(GAP)
    table.book(2, [(3, 0.0, math.inf)], [])
    plain = SafeIntervalSearch(corridor, table, 1, 0, 3, 0.0, speed=1.0, turns=TURNS)
    plain.step(None)
    assert plain.plan is None
    windowed = SafeIntervalSearch(corridor, table, 1, 0, 3, 0.0, speed=1.0, turns=TURNS, until=10.0)
    windowed.step(None)
    assert windowed.plan is not None and windowed.plan.nodes == (0, 1, 2, 3)
    assert windowed.plan.claims[-1] >= 10.0  # it claims the cell only after the cut-off


@pytest.mark.parametrize(("claim", "arrival"), [("departure", 11.5), ("arrival", 10.5)])
def test_a_single_vehicle_area_is_entered_only_when_all_of_it_is_free(claim, arrival):
    """Nodes 1 and 2 of the line 0 - 1 - 2 (1 m, then 4 m) form one area, and another
    vehicle is on node 2 from 5 to 6 s. Node 1 is free all the while, but the vehicle may
    not be in the area while the other one is: it waits on node 0 until that one has left
    (6 s and the gap), although driving straight on would reach node 2 before 5 s.
    When a node's window begins on arrival, a move inside the area must not wait for a
    later free interval on the 4 m segment between its nodes either (it would arrive at
    6.5 s, on the segment inside the area while the other vehicle is on node 2)."""
    line = Plant.build(
        [
            Node(0, "a", 0.0, 0.0),
            Node(1, "b", 1.0, 0.0, area="s"),
            Node(2, "c", 5.0, 0.0, area="s"),
        ],
        [Edge(0, 1, 1.0), Edge(1, 2, 4.0)],
        name="line",
    )
    table = TimeWindowTable(0.5, {1: "s", 2: "s"})
    table.book(9, [(2, 5.0, 6.0)], [])
    plan = plan_path(line, table, 1, 0, 2, 0.0, speed=1.0, turns=TURNS, claim=claim)
    assert plan is not None and plan.nodes == (0, 1, 2)
    assert plan.arrival == pytest.approx(arrival)
    assert plan.claims[1] >= 6.5 - 1e-9  # nobody else in the area from its claim on
    plan.book(table)  # the table takes it


def windows_before(plan: TimedPlan, until: float):
    """The plan's node and segment windows that start before ``until``."""
    nodes = [(n, a, d) for n, a, d in plan.node_windows() if a < until]
    segments = [(u, v, s, e) for u, v, s, e in plan.segment_windows() if s < until]
    return nodes, segments


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10**6),
    width=st.integers(2, 6),
    height=st.integers(1, 5),
    others_count=st.integers(0, 8),
    until=st.sampled_from([0.0, 2.0, 5.0, 9.0, math.inf]),
)
# a plan first costed past the cut-off with a turn on its way on loses to one without
@example(seed=0, width=2, height=3, others_count=2, until=5.0)
def test_a_windowed_plan_keeps_every_rule_before_its_cut_off(
    seed, width, height, others_count, until
):
    """Every window of a windowed plan that starts before the cut-off keeps the rules
    against every other vehicle's window that starts before it (checked by the
    independent monitor); the plan arrives no later than the plan without a cut-off would
    if it went on down the distances from its first node past the cut-off (the windowed
    model: that is a plan of it too), and is that plan when the cut-off is inf."""
    rng = random.Random(seed)
    plant = grid(np.ones((height, width)))
    table, others = TimeWindowTable(GAP), PlanMonitor(GAP)
    random_others(plant, rng, others_count, table, others)
    before = PlanMonitor(GAP)
    for n, windows in others.nodes.items():
        before.nodes[n] = [w for w in windows if w[0] < until]
    for key, windows in others.segments.items():
        before.segments[key] = [w for w in windows if w[0] < until]
    lasting = PlanMonitor(GAP)  # the vehicles that stand for good from before the cut-off
    for n, windows in others.nodes.items():
        lasting.nodes[n] = [w for w in windows if w[0] < until and w[1] == math.inf]
    ids = [int(i) for i in plant.ids]
    start, goal = rng.choice(ids), rng.choice(ids)
    if not others.node_free(start, 0.0, 0.0):
        return
    kw = {"speed": 1.0, "turns": TURNS}
    plain = SafeIntervalSearch(plant, table, 1, start, goal, 0.0, **kw)
    plain.step(None)
    windowed = SafeIntervalSearch(plant, table, 1, start, goal, 0.0, until=until, **kw)
    windowed.step(None)
    if until == math.inf:
        assert (windowed.plan is None) == (plain.plan is None)
        if plain.plan is not None:
            assert windowed.plan.nodes == plain.plan.nodes
            assert windowed.plan.arrival == plain.plan.arrival
        return
    plan = windowed.plan
    if plain.plan is not None:
        assert plan is not None, windowed.reason  # fewer rules: never fewer plans
    if plan is None:
        return  # boxed in before the cut-off
    check_drivable(plant, plan, start, goal, 0.0)
    nodes, segments = windows_before(plan, until)
    for n, a, d in nodes:
        assert before.node_free(n, a, d, 1), (n, a, d)
    # past the cut-off too, it keeps off the nodes where a vehicle stands for good from
    # before it, but for its goal
    for n, a, d in plan.node_windows():
        assert n == goal or lasting.node_free(n, a, d, 1), (n, a, d)
    for u, v, s, e in segments:
        assert before.segment_free(u, v, s, e, 1), (u, v, s, e)
    if plain.plan is not None:
        assert plan.arrival <= as_windowed(plant, windowed, plain.plan, until) + 1e-9


def as_windowed(plant, search: SafeIntervalSearch, plan: TimedPlan, until: float) -> float:
    """When ``plan`` arrives if, from its first node reached at or past ``until`` from
    which a way down the distances is open (round the vehicles that stand for good), it
    goes on down them instead (its own arrival if it arrives before, or no such way is
    open from any of its nodes)."""
    past = next((i for i, a in enumerate(plan.arrive) if a >= until), None)
    if past is None:
        return plan.arrival
    for i in range(past, len(plan.nodes)):
        node, arc = plant.idx(plan.nodes[i]), -1  # -1: it starts there (past the cut-off)
        if i > 0:
            before = plant.idx(plan.nodes[i - 1])
            arc = next(a for v, a, _ in plant.neighbors[before] if v == node)
        tail = search.descent(node, arc, plan.arrive[i])
        if tail is not None:
            return tail.arrive[-1]
    return plan.arrival


def test_a_windowed_search_ends_at_its_cut_off_and_goes_on_down_the_distances():
    """Across an empty 12 x 12 grid, many ways are equally short and turns cost time: the
    search without a cut-off explores them turn by turn. With a cut-off at 3 s it stops
    at the first states past it and goes on down the distances, straight on until it must
    turn: the same arrival, a fraction of the expansions."""
    plant = grid(np.ones((12, 12)))
    table = TimeWindowTable(GAP)
    kw = {"speed": 1.0, "turns": TURNS, "heading": (1.0, 0.0)}
    plain = SafeIntervalSearch(plant, table, 1, 0, 143, 0.0, **kw)
    plain.step(None)
    windowed = SafeIntervalSearch(plant, table, 1, 0, 143, 0.0, until=3.0, **kw)
    windowed.step(None)
    assert plain.plan is not None and windowed.plan is not None
    assert windowed.plan.arrival == plain.plan.arrival == 22 + TURNS.turn_90
    assert windowed.descended > 0 and windowed.expansions * 4 < plain.expansions
    check_drivable(plant, windowed.plan, 0, 143, 0.0)
    # past the cut-off (3 s: node 3) it drives straight to the row's end, then down
    assert windowed.plan.nodes[3:12] == tuple(range(3, 12))
    assert windowed.plan.nodes[12:] == tuple(range(23, 144, 12))


def test_past_its_cut_off_a_search_keeps_off_arcs_the_distances_do_not_know_are_closed():
    """On a 2 x 4 grid the distances from node 0 to node 3 run along the top row, but the
    arc 1 -> 2 is closed (a blockade after the distances were computed). No way down the
    distances is open from the top row, so the search goes on past its cut-off and finds
    the way along the bottom row."""
    plant = grid(np.ones((2, 4)))
    allowed = [True] * plant.n_arcs
    for arc in plant.arc_index[(1, 2)]:
        allowed[arc] = False
    table = TimeWindowTable(GAP)
    search = SafeIntervalSearch(
        plant, table, 1, 0, 3, 0.0, speed=1.0, turns=TURNS, until=0.0, allowed=allowed
    )
    assert search.descent(plant.idx(0), -1, 0.0) is None
    search.step(None)
    assert search.plan is not None and search.plan.nodes == (0, 4, 5, 6, 7, 3)
    check_drivable(plant, search.plan, 0, 3, 0.0)


def test_a_way_down_the_distances_that_is_closed_is_walked_once_not_from_every_state():
    """The goal of a 10 x 10 hall is joined to its corner node 0 only, and that arc is
    closed by a blockade the distances do not know, so every way down them ends at node
    0. A search past its cut-off from the far corner pops every state of the hall, and
    each would walk down to node 0 again; the nodes of a walk that ended nowhere are
    remembered, so all walks together take at most one step per node. From a node with
    no way to the goal at all (a one-way arc into a pocket) no walk starts."""
    hall = grid(np.ones((10, 10)))
    goal = 1000
    plant = Plant.build(
        [*hall.nodes, Node(goal, "", -1.0, 0.0)],
        [*hall.edges, Edge(0, goal, 1.0)],
        name="hall",
    )
    allowed = [True] * plant.n_arcs
    for key in ((0, goal), (goal, 0)):
        for arc in plant.arc_index[key]:
            allowed[arc] = False
    search = SafeIntervalSearch(
        plant,
        TimeWindowTable(GAP),
        1,
        99,
        goal,
        0.0,
        speed=1.0,
        turns=TURNS,
        until=0.0,
        allowed=allowed,
    )
    search.step(None)
    assert search.plan is None and search.expansions >= 100
    assert 0 < search.descended <= plant.n
    pocket = Plant.build(
        [
            Node(0, "", 0.0, 0.0),
            Node(1, "", 1.0, 0.0),
            Node(2, "", 2.0, 0.0),
            Node(9, "", -1.0, 0.0),
        ],
        [
            Edge(9, 0, 1.0, bidirectional=False),
            Edge(0, 1, 1.0, bidirectional=False),
            Edge(1, 2, 1.0),
        ],
        name="pocket",
    )
    trapped = SafeIntervalSearch(
        pocket, TimeWindowTable(GAP), 1, 0, 9, 0.0, speed=1.0, turns=TURNS, until=0.0
    )
    assert trapped.descent(pocket.idx(1), -1, 0.0) is None and trapped.descended == 0


def test_the_way_down_the_distances_is_a_shortest_way_far_from_the_goal_and_across_one_spot():
    """From every node of a 10 x 10 hall whose corner leads by a 2.5 km corridor to the
    goal, the way down the distances is a shortest way (its length is the node's
    distance): no step leads away from the goal however far it is. Two nodes at one spot
    (a zero-length arc, a shortest way in both directions) are crossed once, not back and
    forth."""
    hall = grid(np.ones((10, 10)))
    far = Plant.build(
        [*hall.nodes, Node(1000, "", 2509.0, 9.0)],
        [*hall.edges, Edge(99, 1000, 2500.0)],
        name="far",
    )
    row = distances_to(far, [1000])[0]
    no_turns = TurnTimes(0.0, 0.0)  # so that arriving takes as many seconds as metres
    search = SafeIntervalSearch(
        far, TimeWindowTable(GAP), 1, 0, 1000, 0.0, speed=1.0, turns=no_turns, until=0.0
    )
    for n in range(100):
        tail = search.descent(n, -1, 0.0)
        assert tail is not None and tail.nodes[-1] == far.idx(1000)
        assert tail.arrive[-1] == pytest.approx(row[n], rel=1e-6)
    spot = Plant.build(
        [
            Node(0, "", 0.0, 0.0),
            Node(1, "", 1.0, 0.0),
            Node(2, "", 1.0, 0.0),
            Node(3, "", 2.0, 0.0),
        ],
        [Edge(1, 2, 0.0), Edge(0, 1, 1.0), Edge(2, 3, 1.0)],
        name="spot",
    )
    across = SafeIntervalSearch(spot, TimeWindowTable(GAP), 1, 0, 3, 0.0, speed=1.0, until=0.0)
    tail = across.descent(spot.idx(0), -1, 0.0)
    assert tail is not None and [spot.ids[n] for n in tail.nodes] == [1, 2, 3]


def test_a_plan_past_its_cut_off_pays_its_speed_limits_and_weights():
    """On the line 0 - 1 - 2 - 3 - 4 (1 m apart) the segment 2 - 3 is limited to 0.5 m/s
    and the arc 3 -> 4 weighs 3. Past a cut-off of 0.5 s (from node 1 on) the plan goes on
    down the distances: it arrives at 5 s (1 + 1 + 2 + 1) and costs 7 (2 s of weight on top
    of the 1 s on 3 -> 4), as the search without a cut-off plans it."""
    line = Plant.build(
        [Node(i, "", float(i), 0.0) for i in range(5)],
        [Edge(0, 1, 1.0), Edge(1, 2, 1.0), Edge(2, 3, 1.0, max_speed=0.5), Edge(3, 4, 1.0)],
        name="line",
    )
    weights = [3.0 if key == (3, 4) else 1.0 for key in arc_keys(line)]
    kw = {"speed": 1.0, "turns": TURNS, "heading": (1.0, 0.0), "weights": weights}
    for until in (0.5, 0.0, math.inf):
        plan = plan_path(line, TimeWindowTable(GAP), 1, 0, 4, 0.0, until=until, **kw)
        assert plan is not None and plan.nodes == (0, 1, 2, 3, 4), until
        assert plan.arrive == (0.0, 1.0, 2.0, 4.0, 5.0) and plan.cost == 7.0, until
        assert plan.depart[:-1] == (0.0, 1.0, 2.0, 4.0) and plan.depart[-1] == math.inf


def arc_keys(plant: Plant) -> list[tuple[int, int]]:
    """(from, to) node ids of each arc, in arc order."""
    keys = [(0, 0)] * plant.n_arcs
    for key, arcs in plant.arc_index.items():
        for arc in arcs:
            keys[arc] = key
    return keys


def test_a_budget_counts_the_walks_down_the_distances():
    """Across a 40 x 40 grid, corner to corner, with a cut-off at 10 s: many states past
    the cut-off tie on their lower bound, and each is costed by a walk down the distances
    (up to 78 steps) before the cheapest wins. A step of 20 works to 20 and stops: its
    expansions and walks (four steps to an expansion) overrun that by at most one walk
    and one expansion, not a walk for each of 20 states."""
    plant = grid(np.ones((40, 40)))
    search = SafeIntervalSearch(
        plant,
        TimeWindowTable(GAP),
        1,
        0,
        1599,
        0.0,
        speed=1.0,
        turns=TURNS,
        heading=(1.0, 0.0),
        until=10.0,
    )
    steps = 0
    while True:
        work = search.work
        done = search.step(20)
        assert search.work - work <= 20 + 78 // 4 + 2
        steps += 1
        if done:
            break
    assert search.plan is not None and search.plan.nodes[-1] == 1599
    assert search.descended > 5 * 78 and steps > 5  # several walks, over several steps


def ring(m: int) -> Plant:
    """A two-way ring of ``m`` nodes 1 m apart."""
    r = m / (2 * math.pi)
    nodes = [
        Node(k, "", r * math.cos(2 * math.pi * k / m), r * math.sin(2 * math.pi * k / m))
        for k in range(m)
    ]
    return Plant.build(nodes, [Edge(k, (k + 1) % m, 1.0) for k in range(m)], name="ring")


def test_past_its_cut_off_a_search_goes_round_a_vehicle_that_stands_for_good():
    """On a ring of 40, vehicle 2 stands on node 2 for good; the way from node 0 to node 5
    round the other side takes 35 s, longer than the 10 s window. Past the cut-off a
    vehicle that stands for good is still in the way (like a blockade), so the plan goes
    the long way round at once, as without a cut-off, instead of waiting on node 0 for the
    cut-off and then driving through node 2. A vehicle that will only arrive after the
    cut-off to stay for good is ignored as every window from then on."""
    plant = ring(40)
    kw = {"speed": 1.0, "turns": TurnTimes(0.0, 0.0)}
    table = TimeWindowTable(GAP)
    table.book(2, [(2, -1.0, math.inf)], [])  # it has stood there since before now
    for until in (10.0, 0.0, math.inf):
        search = SafeIntervalSearch(plant, table, 1, 0, 5, 0.0, until=until, **kw)
        search.step(None)
        plan = search.plan
        assert plan is not None, until
        assert plan.nodes == (0, *range(39, 4, -1)) and plan.arrival == 35.0, until
        assert plan.claims[1] == 0.0  # it sets off now
    assert search.descent(plant.idx(1), -1, 20.0) is None  # every shortest way is closed
    later = TimeWindowTable(GAP)
    later.book(2, [(2, 12.0, math.inf)], [])
    plan = plan_path(plant, later, 1, 0, 5, 0.0, until=10.0, **kw)
    assert plan is not None and plan.nodes == (0, 1, 2, 3, 4, 5)


def test_past_its_cut_off_the_way_down_the_distances_turns_off_round_one_that_stands():
    """Across an empty 6 x 6 grid the way down the distances from corner 0 to corner 35
    goes straight along the top row first; with vehicles standing for good on nodes 3 and
    8 it takes another shortest way (same length, down earlier), turning back from node 2
    whose every shortest way on is closed, which it remembers."""
    plant = grid(np.ones((6, 6)))
    table = TimeWindowTable(GAP)
    table.book(2, [(3, -1.0, math.inf)], [])
    table.book(3, [(8, -1.0, math.inf)], [])
    search = SafeIntervalSearch(
        plant, table, 1, 0, 35, 0.0, speed=1.0, turns=TURNS, heading=(1.0, 0.0), until=0.0
    )
    tail = search.descent(plant.idx(0), -1, 0.0)
    assert tail is not None and len(tail.nodes) == 10  # a shortest way
    assert tail.nodes[:2] == [plant.idx(1), plant.idx(7)] and plant.idx(2) in search._stuck
    search.step(None)
    assert search.plan is not None and not {3, 8} & set(search.plan.nodes)
    check_drivable(plant, search.plan, 0, 35, 0.0, (1.0, 0.0))


def test_a_goal_behind_a_vehicle_that_stands_for_good_has_no_plan_and_the_search_ends():
    """In a corridor of 6 cells vehicle 2 stands for good on cell 3, between vehicle 1
    (cell 0) and its goal (cell 5): past the cut-off it is still in the way, so there is
    no plan, found after a search of the few cells on this side (not a plan through it).
    On the goal itself, or anywhere in the goal's area, a vehicle that stands for good is
    no obstacle past the cut-off: the plan waits for the cut-off and drives in."""
    corridor = grid(np.ones((1, 6)))
    kw = {"speed": 1.0, "turns": TURNS, "until": 10.0}
    table = TimeWindowTable(GAP)
    table.book(2, [(3, 0.0, math.inf)], [])
    search = SafeIntervalSearch(corridor, table, 1, 0, 5, 0.0, **kw)
    assert search.step(None) and search.plan is None and search.expansions < 20
    assert "no conflict-free path" in search.reason
    on_goal = TimeWindowTable(GAP)
    on_goal.book(2, [(5, 0.0, math.inf)], [])
    plan = plan_path(corridor, on_goal, 1, 0, 5, 0.0, **kw)
    assert plan is not None and plan.nodes == tuple(range(6)) and plan.claims[-1] >= 10.0
    in_area = TimeWindowTable(GAP, {4: "s", 5: "s"})
    in_area.book(2, [(4, 0.0, math.inf)], [])
    plan = plan_path(corridor, in_area, 1, 0, 5, 0.0, **kw)
    assert plan is not None and plan.nodes == tuple(range(6)) and plan.claims[-2] >= 10.0
