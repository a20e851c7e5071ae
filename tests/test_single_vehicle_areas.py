"""Single-vehicle areas (plant key ``area``) are kept by the traffic layer for every vehicle:
recipe vehicles, vehicles pushed aside or backed off by the deadlock resolver, whatever sent
them. The proof is the independent monitor (vehicles/monitor.py), which counts two vehicles
in one area from the simulated vehicles' true positions only, never the controller's holds.

Small hand-built plants show each rule: a vehicle bound for an occupied station waits
outside its area and the occupant, leaving, pushes it aside; a standing vehicle is never
pushed into an occupied area, and where the only room to back off is inside one, the
deadlock is reported instead; a corridor area is passed from both ends in turn. A property
runs random fleets with recipes over spur stations on a grid plant of over 300 nodes, over
links that drop, corrupt and spoof frames.
"""

from __future__ import annotations

import math
import random

import pytest
from fleet_scenarios import make_config
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

from blocks.traffic.deadlock import MAX_BACK_OFFS
from blocks.traffic.reservation import ReservationMatrix
from fleet.program import FleetProgram
from fleet.report import summary
from topology import Edge, Node, Plant
from vehicles.agv import AgvParams
from vehicles.fleet import Faults


def build(nodes: list[Node], pairs: list[tuple[int, int]], name: str) -> Plant:
    """Two-way segments as long as the distance between their nodes."""
    at = {n.id: (n.x, n.y) for n in nodes}
    edges = [Edge(a, b, math.dist(at[a], at[b])) for a, b in pairs]
    functions = {f: f"f{f}" for n in nodes for f in n.functions}
    return Plant.build(nodes, edges, name=name, functions=functions)


def area_nodes(p: FleetProgram, name: str) -> set[int]:
    return set(p.cfg.plant.areas[name])


def occupant(p: FleetProgram, name: str) -> set[int]:
    """Who occupies the area in the controller's view (the reservations)."""
    res = p.reservation
    return res.occupants[res.area_names.index(name)]


def in_area(p: FleetProgram, vehicle: int, area: set[int]) -> bool:
    """Where the simulated vehicle truly is: at its node, and while driving at both ends of
    its segment."""
    agv = p.fleet.vehicles[vehicle]
    return bool({agv.node, agv.target} & area)


def step(p: FleetProgram, seconds: float, each=None) -> None:
    """Step ``seconds`` on the virtual clock; after every cycle no conflict of any kind."""
    if p.rt.state != "RUN":
        p.rt.start()
    for _ in range(round(seconds / p.cfg.cycle_time)):
        p.rt.step()
        assert p.rt.state == "RUN", p.rt.fault_reason
        m = p.monitor
        assert m.head_on == 0 and m.node == 0 and m.area == 0, m.events[:3]
        if each is not None:
            each()


# ----- the rule in the reservations ---------------------------------------------------------
def spur_ring() -> Plant:
    """A two-way ring of eight lane nodes (3 m apart); off node 2 a spur north to the drill
    station 21, whose single-vehicle area is the station and its approach 20; the press
    station 6 on the ring."""
    corners = [(0, 0), (3, 0), (6, 0), (6, 3), (6, 6), (3, 6), (0, 6), (0, 3)]
    nodes = [Node(k, f"lane{k}", float(x), float(y)) for k, (x, y) in enumerate(corners, 1)]
    nodes[5] = Node(6, "press", 3.0, 6.0, "station", (3,))
    nodes += [
        Node(20, "drill-approach", 3.0, -3.0, area="drill"),
        Node(21, "drill", 3.0, -6.0, "station", (2,), area="drill"),
    ]
    pairs = [(k, k % 8 + 1) for k in range(1, 9)] + [(2, 20), (20, 21)]
    return build(nodes, pairs, "spur-ring")


def test_an_area_is_taken_only_by_its_occupant_or_when_nobody_occupies_it():
    """Vehicle 1 drives into the drill's area and out again; vehicle 2 wants in from the
    junction. The occupant is the one waited for; it may go on inside the area; the area is
    free only once vehicle 1 has reported a node beyond it (clear of the approach is not
    enough: it still drives the segment out)."""
    plant = spur_ring()
    idx = plant.index
    res = ReservationMatrix(plant, [1, 2])
    assert res.report(1, idx[20]) and res.report(2, idx[3])  # start positions
    assert res.blocker(2, idx[2]) is None  # the junction is in no area
    assert res.may_enter(2, idx[21]) == (False, 1)  # free node, occupied area
    assert res.may_enter(1, idx[21]) == (True, None)  # its own area: no self-blocking
    res.claim(1, idx[21])
    assert res.report(1, idx[21])
    with pytest.raises(RuntimeError, match="area 'drill' is occupied by vehicle 1"):
        res.claim(2, idx[20])
    res.claim(1, idx[20])
    res.claim(1, idx[2])
    assert res.report(1, idx[20]) and res.report(1, idx[20], clear=True)
    assert res.holder_of(idx[20]) is None and res.held_by(1) == [idx[2]]
    assert res.blocker(2, idx[20]) == 1  # cleared the approach, still on the segment out
    assert res.report(1, idx[2])  # reached the junction: out of the area
    assert res.may_enter(2, idx[20]) == (True, None)
    # an awaited area: a driving vehicle does not take another node of it either
    res.set_awaited({idx[21]: 2})
    assert res.awaited_by(1, idx[20]) == 2 and res.awaited_by(2, idx[20]) is None
    # an operator puts vehicle 2 where it really is, in the area beside vehicle 1: both may
    # move on inside it, nobody else comes in
    res3 = ReservationMatrix(plant, [1, 2, 3])
    assert res3.report(1, idx[21]) and res3.report(3, idx[2])
    assert res3.relocate(2, idx[20]) is None
    assert res3.blocker(1, idx[20]) == 2  # held
    assert res3.area_blocker(2, idx[21]) is None and res3.blocker(3, idx[20]) == 2


# ----- a station on a spur: the second vehicle waits outside its area ---------------------------
def test_a_vehicle_bound_for_an_occupied_station_waits_outside_its_area():
    """Both vehicles' recipes start at the drill. Vehicle 1, next to it, gets there first;
    vehicle 2 stops at the junction, outside the area, waiting for vehicle 1, and enters
    only when vehicle 1 has left all of it. Vehicle 2's step is the older one, so it is the
    more urgent, yet vehicle 1 on its way out pushes it aside (it could not leave
    otherwise), and vehicle 1 never gives way."""
    cfg = make_config(
        spur_ring(),
        {1: 1, 2: 4},
        {"drill-press": [2, 3]},
        {2: [21], 3: [6]},
        rounds=1,
        processing_s=5.0,
        cycle_time=0.05,
        agv=AgvParams(max_speed=1.0),
    )
    p = FleetProgram(cfg)
    drill = area_nodes(p, "drill")
    seen = {"waited_outside": False, "left": None, "entered": None}

    def watch() -> None:
        one, two = in_area(p, 1, drill), in_area(p, 2, drill)
        c2 = p.controls[2]
        if c2.state == "waiting" and c2.waiting_for == 1 and c2.wait_node in drill:
            # (vehicle 1 may have left already: its report of that is on its way)
            assert not two and occupant(p, "drill") == {1}
            assert c2.current == 2  # the junction: the last node before the area
            seen["waited_outside"] = seen["waited_outside"] or one
        if seen["waited_outside"] and not one and seen["left"] is None:
            seen["left"] = p.fleet.time
        if two and seen["entered"] is None:
            seen["entered"] = p.fleet.time

    try:
        step(p, 120, watch)
        assert sorted(r.vehicle for r in p.completed) == [1, 2]
        assert seen["waited_outside"]
        assert seen["left"] is not None and seen["entered"] > seen["left"]
        assert p.resolver.pushes >= 1 and p.resolver.unresolved == 0
        assert all(e.backed_off in (None, 2) for e in p.resolver.events)
        assert summary(p, wall_s=1.0)["area_conflicts"] == 0
    finally:
        p.close()


# ----- pushes and back-offs never move a vehicle into an occupied area ------------------------
def spur_line(room_beyond: bool) -> Plant:
    """A line 1 - 2 - 3 (- 4 - 5), 2 m apart, with the area's spur off node 3: approach 6,
    station 7 (area "cell"). Station 3 is the junction itself, station 4 (or 1) the end."""
    xs = [1, 2, 3, 4, 5] if room_beyond else [1, 2, 3]
    nodes = [Node(k, f"n{k}", 2.0 * k, 0.0) for k in xs]
    nodes[2] = Node(3, "junction", 6.0, 0.0, "station", (4,))
    if room_beyond:
        nodes[3] = Node(4, "end", 8.0, 0.0, "station", (3,))
    else:
        nodes[0] = Node(1, "west", 2.0, 0.0, "station", (3,))
    nodes += [
        Node(6, "cell-approach", 6.0, 2.0, area="cell"),
        Node(7, "cell", 6.0, 4.0, "station", (2,), area="cell"),
    ]
    pairs = [(a, a + 1) for a in xs[:-1]] + [(3, 6), (6, 7)]
    return build(nodes, pairs, "spur-line")


def spur_program(room_beyond: bool, starts, functions, stations, recipes) -> FleetProgram:
    """One round of each vehicle's recipe on the spur line, 1 s at every station."""
    cfg = make_config(
        spur_line(room_beyond=room_beyond),
        starts,
        functions,
        stations,
        vehicle_recipes=recipes,
        rounds=1,
        processing_s=1.0,
        cycle_time=0.05,
    )
    return FleetProgram(cfg)


def test_a_standing_vehicle_is_pushed_along_the_route_not_into_an_occupied_area():
    """Vehicle 1 works at the cell and stays there. Vehicle 2 stops at the junction, its
    station; vehicle 3 needs the junction to reach station 4. Off vehicle 3's route, the
    free approach of the cell would be the best place to push vehicle 2 to, but the cell's
    area is vehicle 1's: vehicle 2 is pushed ahead along the lane instead."""
    p = spur_program(
        True,
        {1: 5, 2: 2, 3: 1},
        {"cell": [2], "junction": [4], "end": [3]},
        {2: [7], 3: [4], 4: [3]},
        {1: ["cell"], 2: ["junction"], 3: ["end"]},
    )
    try:
        step(p, 60)
        assert sorted(r.vehicle for r in p.completed) == [1, 2, 3]
        driven = p.recorder.driven
        assert driven[1][-1] == 7  # vehicle 1 stayed in the cell all along
        assert not {6, 7} & set(driven[2]) and driven[2][-2:] == [4, 5]
        assert p.resolver.pushes >= 2 and p.resolver.unresolved == 0
    finally:
        p.close()


def test_where_the_only_room_is_an_occupied_area_the_deadlock_is_reported():
    """Vehicles 2 and 3 meet head-on on a line of three nodes; the only node either could
    give way to is the approach of the cell, where vehicle 1 stays. Nobody is backed off
    into it. They give way back and forth along the line (each time nobody can, the
    deadlock is reported and tried again as the other moves) until that counts as a
    livelock, 8 back-offs without progress; then the deadlock is reported for good, both
    are stranded, and nothing collides."""
    p = spur_program(
        False,
        {1: 7, 2: 1, 3: 3},
        {"cell": [2], "west": [3], "junction": [4]},
        {2: [7], 3: [1], 4: [3]},
        {1: ["cell"], 2: ["junction"], 3: ["west"]},
    )
    try:
        step(p, 150)
        assert [r.vehicle for r in p.completed] == [1]
        assert p.resolver.resolved == MAX_BACK_OFFS
        assert p.resolver.unresolved >= 1 and p.resolver.stranded() == [2, 3]
        assert p.resolver.events[-1].backed_off is None
        assert all(6 not in p.recorder.driven[v] for v in (2, 3))
        result = summary(p, wall_s=1.0)
        assert result["stranded_vehicles"] == [2, 3] and result["area_conflicts"] == 0
    finally:
        p.close()


# ----- a corridor area passed from both ends ----------------------------------------------------
def corridor_between_loops() -> Plant:
    """A west and an east loop of four nodes each (stations 13 and 33 on them), joined by a
    corridor 20 - 21 - 22 that is one single-vehicle area."""
    nodes = [
        Node(10, "west-end", 0.0, 0.0),
        Node(11, "w1", -2.0, -2.0),
        Node(13, "west", -4.0, 0.0, "station", (2,)),
        Node(12, "w2", -2.0, 2.0),
        Node(30, "east-end", 8.0, 0.0),
        Node(31, "e1", 10.0, -2.0),
        Node(33, "east", 12.0, 0.0, "station", (3,)),
        Node(32, "e2", 10.0, 2.0),
    ]
    nodes += [Node(20 + k, f"corridor{k}", 2.0 * (k + 1), 0.0, area="corridor") for k in range(3)]
    pairs = [(10, 11), (11, 13), (13, 12), (12, 10), (30, 31), (31, 33), (33, 32), (32, 30)]
    pairs += [(10, 20), (20, 21), (21, 22), (22, 30)]
    return build(nodes, pairs, "corridor")


def test_a_corridor_area_is_passed_from_both_ends_in_turn():
    """Vehicles shuttle between the loops in opposite directions, two rounds each: one
    drives through the corridor while the other waits at its end, outside it, and makes
    room there when the one in the corridor comes out."""
    cfg = make_config(
        corridor_between_loops(),
        {1: 11, 2: 31},
        {"east-west": [3, 2], "west-east": [2, 3]},
        {2: [13], 3: [33]},
        vehicle_recipes={1: ["east-west"], 2: ["west-east"]},
        rounds=2,
        processing_s=1.0,
        cycle_time=0.05,
        agv=AgvParams(max_speed=1.0),
    )
    p = FleetProgram(cfg)
    corridor = area_nodes(p, "corridor")
    waited: set[int] = set()

    def watch() -> None:
        for v, other in ((1, 2), (2, 1)):
            c = p.controls[v]
            if c.state == "waiting" and c.waiting_for == other and c.wait_node in corridor:
                assert not in_area(p, v, corridor) and occupant(p, "corridor") == {other}
                assert c.current in (10, 30)  # at the corridor's end
                waited.add(v)

    try:
        step(p, 180, watch)
        assert sorted(r.vehicle for r in p.completed) == [1, 1, 2, 2]
        assert waited
        assert p.resolver.unresolved == 0
    finally:
        p.close()


# ----- the property: a grid plant of over 300 nodes, spur stations, faulty links ---------------
COLS, ROWS, GAP = 17, 17, 2.0  # 289 lane nodes
FUNCTIONS = (2, 3, 4, 5)
SPEED = 1.0  # m/s
CYCLE_S = 0.05
PROCESSING_S = 2.0


def spur_sites() -> list[tuple[int, int, float, float]]:
    """(column, row, direction of the spur) of the stations: three per function, round the
    grid's border, spurs pointing out of the grid."""
    last = COLS - 1
    sites = [(c, 0, 0.0, -1.0) for c in (2, 8, 14)]
    sites += [(last, r, 1.0, 0.0) for r in (2, 8, 14)]
    sites += [(c, last, 0.0, 1.0) for c in (14, 8, 2)]
    sites += [(0, r, -1.0, 0.0) for r in (14, 8, 2)]
    return sites


def lane(c: int, r: int) -> int:
    return r * COLS + c


def spur_grid() -> Plant:
    """A two-way grid of COLS x ROWS lane nodes, and twelve stations each at the end of a
    two-way spur junction -> approach -> station; station and approach are the station's
    single-vehicle area. 313 nodes."""
    nodes = [
        Node(lane(c, r), f"l{c}-{r}", GAP * c, GAP * r) for r in range(ROWS) for c in range(COLS)
    ]
    pairs = [(lane(c, r), lane(c + 1, r)) for r in range(ROWS) for c in range(COLS - 1)]
    pairs += [(lane(c, r), lane(c, r + 1)) for r in range(ROWS - 1) for c in range(COLS)]
    for k, (c, r, ux, uy) in enumerate(spur_sites()):
        function, station, approach = FUNCTIONS[k % len(FUNCTIONS)], 1000 + k, 2000 + k
        x, y, name = GAP * c, GAP * r, f"s{k}"
        nodes.append(Node(approach, f"{name}-approach", x + GAP * ux, y + GAP * uy, area=name))
        nodes.append(
            Node(
                station, name, x + 2 * GAP * ux, y + 2 * GAP * uy, "station", (function,), area=name
            )
        )
        pairs += [(lane(c, r), approach), (approach, station)]
    return build(nodes, pairs, "spur-grid")


SPUR_GRID = spur_grid()
LANES = [lane(c, r) for r in range(ROWS) for c in range(COLS)]
RECIPES = {f"{a}-{b}": [a, b] for a in FUNCTIONS for b in FUNCTIONS if a != b}
STRATEGIES = ["random", "round_robin", "least_utilised", "nearest", "occupancy_aware"]

# The bound on a recipe (two steps), in simulated seconds. A trip is at most the plant's
# longest route, 72 m (32 lane segments and two 4 m spurs), driven at 1 m/s with a stop and
# a turn at every node (about 2.5 s each): TRIP_S. At a station a vehicle waits at most for
# every other vehicle's visit, one at a time: in and out of the spur with two stops and a
# half turn, and the processing time: VISIT_S each. A vehicle made suspect by a spoofed
# frame stands still for at least RECOVER_S (2 s), a few times per run at these rates:
# FAULTS_S. Observed so far: at most 40 % of the bound (275 s of 690 s, 14 vehicles).
TRIP_S, VISIT_S, FAULTS_S = 150.0, 15.0, 60.0


def recipe_bound_s(vehicles: int) -> float:
    return 2 * TRIP_S + 2 * (vehicles - 1) * VISIT_S + FAULTS_S


def spur_grid_config(vehicles: int, layout: int, strategy: str, rates: tuple[float, ...]):
    """``vehicles`` on distinct lane nodes with one random recipe each (``layout`` seeds
    both), every vehicle's link faulty at ``rates`` (dropped, corrupted, spoofed)."""
    rnd = random.Random(layout)
    starts = rnd.sample(LANES, vehicles)
    faults = Faults(drop_rate=rates[0], corrupt_rate=rates[1], spoof_rate=rates[2])
    clusters = {f: [n.id for n in SPUR_GRID.nodes if f in n.functions] for f in FUNCTIONS}
    return make_config(
        SPUR_GRID,
        {v + 1: s for v, s in enumerate(starts)},
        RECIPES,
        clusters,
        vehicle_recipes={v + 1: [rnd.choice(sorted(RECIPES))] for v in range(vehicles)},
        strategy=strategy,
        processing_s=PROCESSING_S,
        cycle_time=CYCLE_S,
        seed=layout,
        faults={v + 1: faults for v in range(vehicles)},
        agv=AgvParams(max_speed=SPEED, length=0.5),
    )


def test_the_spur_grid_is_large_and_every_station_has_its_own_area():
    plant = SPUR_GRID
    assert plant.n >= 300
    stations = plant.with_role("station")
    assert len(stations) == 12 and len(plant.areas) == 12
    for members in plant.areas.values():
        # the station and its approach, a dead-end spur
        assert len(members) == 2 and len(set(members) & set(stations)) == 1
    assert all(len(plant.stations_for(f)) == 3 for f in FUNCTIONS)


@settings(
    max_examples=4,
    deadline=None,
    derandomize=True,
    database=None,
    # an example simulates minutes of plant time: a failure is reported as found
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.too_slow],
)
@example(vehicles=14, layout=1, strategy="random", rates=(0.05, 0.03, 0.01))
@given(
    vehicles=st.integers(4, 14),
    layout=st.integers(0, 2**32 - 1),
    strategy=st.sampled_from(STRATEGIES),
    rates=st.tuples(
        st.sampled_from([0.0, 0.02, 0.05]),
        st.sampled_from([0.0, 0.03]),
        st.sampled_from([0.0, 0.005, 0.01]),
    ),
)
def test_no_conflict_and_nobody_stranded_with_spur_stations_on_faulty_links(
    vehicles, layout, strategy, rates
):
    """Safety every cycle (no head-on, node or area conflict from the monitor), and every
    vehicle completes its recipe within the bound, with the links faulty all along."""
    cfg = spur_grid_config(vehicles, layout, strategy, rates)
    p = FleetProgram(cfg)
    bound = recipe_bound_s(vehicles)
    try:
        done: set[int] = set()
        p.rt.start()
        while len(done) < vehicles and p.fleet.time < bound:
            step(p, 5.0)
            done.update(r.vehicle for r in p.completed)
        stuck = {
            v: (c.state, c.current, c.waiting_for, p.jobs[v].target)
            for v, c in p.controls.items()
            if v not in done
        }
        assert not stuck, (stuck, bound, [e.line() for e in p.events.recent(8)])
        assert p.resolver.stranded() == []
        if any(rates):
            injected = [p.fleet.counters[k] for k in ("dropped", "corrupted", "spoofed")]
            assert sum(injected) > 0  # the faults really were there
    finally:
        p.close()
