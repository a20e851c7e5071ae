"""The thesis' open case (5.3.1): the only remaining path is occupied by an oncoming vehicle.
With somewhere to give way the deadlock is detected and resolved; without, it is reported,
never a silent hang."""

from __future__ import annotations

import pytest
from fleet_scenarios import make_config, run

from fleet.config import FleetConfig
from fleet.program import FleetProgram
from fleet.report import summary
from topology import Edge, Node, Plant


def corridor(siding: bool) -> Plant:
    nodes = [Node(1, "west", 0.0, 0.0, "station", (2,))]
    nodes += [Node(i, f"c{i}", float(i - 1), 0.0) for i in (2, 3, 4)]
    nodes.append(Node(5, "east", 4.0, 0.0, "station", (3,)))
    edges = [Edge(i, i + 1, 1.0) for i in range(1, 5)]
    if siding:
        nodes.append(Node(6, "siding", 2.0, 1.0))
        edges.append(Edge(3, 6, 1.0))
    return Plant.build(nodes, edges, name="corridor", functions={2: "west", 3: "east"})


def head_on_config(siding: bool) -> FleetConfig:
    """Two vehicles at the corridor's ends, each sent to the other's end once."""
    return make_config(
        corridor(siding),
        {1: 1, 2: 5},
        {"to-east": [3], "to-west": [2]},
        {2: [1], 3: [5]},
        vehicle_recipes={1: ["to-east"], 2: ["to-west"]},
        rounds=1,
    )


@pytest.fixture
def head_on():
    made = []

    def build(siding: bool) -> FleetProgram:
        p = FleetProgram(head_on_config(siding))
        made.append(p)
        return p

    yield build
    for p in made:
        p.close()


def test_a_head_on_deadlock_is_resolved_by_pushing_and_backing_off_into_the_siding(head_on):
    p = head_on(siding=True)
    run(p, 90)
    assert p.resolver.detected >= 1 and p.resolver.resolved >= 1
    events = p.resolver.events
    assert all(set(e.vehicles) == {1, 2} for e in events)
    # vehicle 1 is the more urgent (same step age, lower id): it first pushes vehicle 2 back
    # to the east end, where pushing can go no further; the cycle that remains is broken by
    # a back-off, and the one that can step off both routes, into the siding, is vehicle 1
    assert (events[0].backed_off, events[0].to_node) == (2, 5)
    assert (events[-1].backed_off, events[-1].to_node) == (1, 6)
    assert p.resolver.pushes >= 1
    assert sorted(r.vehicle for r in p.completed) == [1, 2]
    assert p.resolver.unresolved == 0


def test_without_a_way_out_the_deadlock_is_reported_not_hidden(head_on):
    p = head_on(siding=False)
    run(p, 90)
    assert p.completed == []
    assert p.resolver.unresolved >= 1
    assert p.resolver.stranded() == [1, 2]
    assert p.rt.state == "RUN"  # the scan goes on; the cell is reported, not faulted
    result = summary(p, wall_s=1.0)
    assert result["deadlocks_unresolved"] >= 1 and result["stranded_vehicles"] == [1, 2]
    assert result["head_on_conflicts"] == 0 and result["node_conflicts"] == 0


def test_a_scan_asks_each_vehicle_for_its_priority_at_most_once(head_on):
    """At scale the resolver sorts hundreds of standing vehicles and checks every remembered
    cycle for progress each scan: one priority look-up per vehicle is enough, as priorities
    do not change within its scan."""
    p = head_on(siding=True)
    asked: list[int] = []
    priority = p.resolver.priority

    def counted(vehicle: int) -> tuple[int, int]:
        asked.append(vehicle)
        return priority(vehicle)

    p.resolver.priority = counted
    scans_asking = 0
    for _ in range(round(90 / p.cfg.cycle_time)):
        asked.clear()
        run(p, p.cfg.cycle_time)
        assert len(asked) == len(set(asked))
        scans_asking += bool(asked)
    assert scans_asking > 0
    assert p.resolver.detected >= 1 and p.resolver.pushes >= 1


def test_a_push_avoids_the_route_the_asking_vehicle_plans_now(head_on):
    """The nodes of a vehicle's route are kept between scans (routes are long, and only
    pushes need them): after every scan they are those of its current plan."""
    p = head_on(siding=True)
    index = p.cfg.plant.index
    plans = {v: set() for v in p.controls}
    for _ in range(round(90 / p.cfg.cycle_time)):
        run(p, p.cfg.cycle_time)
        for v, control in p.controls.items():
            assert p.resolver._route_nodes(v) == {index[n] for n in control.planned}
            plans[v].add(control.planned)
    assert all(len(seen) > 2 for seen in plans.values())  # routes changed on the way
    assert p.resolver.pushes >= 1


def test_a_queue_of_standing_vehicles_is_pushed_aside_by_priority_inheritance():
    """Vehicle 1's shortest route runs through two standing vehicles, one behind the other:
    the first can only move onto the second's node, so the second must make room first (a
    chain of pushes, each off vehicle 1's route where it can), and vehicle 1 drives through."""
    nodes = [Node(i, f"n{i}", float(i - 1), 0.0) for i in (1, 2, 3, 4)]
    nodes.append(Node(5, "east", 4.0, 0.0, "station", (2,)))
    nodes += [Node(6, "loop-w", 1.0, 1.0), Node(7, "loop-e", 3.0, 1.0)]
    nodes[2] = Node(3, "park-a", 2.0, 0.0, "station", (3,))
    nodes[3] = Node(4, "park-b", 3.0, 0.0, "station", (4,))
    edges = [Edge(i, i + 1, 1.0) for i in range(1, 5)]
    edges += [Edge(2, 6, 1.0), Edge(6, 7, 2.0), Edge(7, 4, 1.0)]
    plant = Plant.build(nodes, edges, name="queue", functions={2: "e", 3: "a", 4: "b"})
    cfg = make_config(
        plant,
        {1: 1, 2: 3, 3: 4},
        {"east": [2], "park-a": [3], "park-b": [4]},
        {2: [5], 3: [3], 4: [4]},
        vehicle_recipes={1: ["east"], 2: ["park-a"], 3: ["park-b"]},
        rounds=1,
    )
    p = FleetProgram(cfg)
    try:
        run(p, 60)
        assert [r.vehicle for r in p.completed if r.vehicle == 1] == [1]
        assert p.resolver.pushes >= 3  # vehicle 3 twice (to make room), vehicle 2 once or more
        driven = p.recorder.driven
        assert driven[1][:5] == [1, 2, 3, 4, 5]  # straight through, no detour
        assert {6, 7} & set(driven[3])  # the one behind stepped off the route into the loop
        assert p.resolver.unresolved == 0
    finally:
        p.close()


def spur_on_a_ring(side_branch: bool, branch_busy: bool = True, **settings) -> FleetProgram:
    """A one-way ring 1 -> 2 -> 3 -> 4 -> 5 -> 6 -> 1 with stations 3 and 5 on it and a
    dead-end spur 2 - 7 (a station, like a queue place at the end of a spur). Vehicle 1
    stands at the spur's mouth heading for it, vehicle 2 in the spur heading for 5, vehicle
    3 works at 3 and then drives to 5. With ``side_branch``, a two-way branch 1 - 8 - 9 off
    the ring: vehicle 4 stands at 1, queued behind vehicle 1 on its way to 3, and (if
    ``branch_busy``) vehicle 5 works at 8 and then parks at 9."""
    ring = [(1, 0.0, 0.0), (2, 4.0, 0.0), (3, 8.0, 0.0), (4, 12.0, 0.0), (5, 12.0, 4.0)]
    ring += [(6, 0.0, 4.0)]
    nodes = [Node(i, f"lane{i}", x, y) for i, x, y in ring]
    nodes[2] = Node(3, "work", 8.0, 0.0, "station", (3,))
    nodes[4] = Node(5, "goal", 12.0, 4.0, "station", (5,))
    nodes.append(Node(7, "spur", 4.0, -4.0, "station", (7,)))
    edges = [Edge(a, b, 4.0, bidirectional=False) for a, b in [(1, 2), (2, 3), (3, 4), (4, 5)]]
    edges += [Edge(5, 6, 12.0, bidirectional=False), Edge(6, 1, 4.0, bidirectional=False)]
    edges.append(Edge(2, 7, 4.0))
    functions = {3: "work", 5: "goal", 7: "spur"}
    starts = {1: 2, 2: 7, 3: 3}
    recipes = {"to-spur": [7], "out": [5], "work": [3, 5]}
    jobs = {1: ["to-spur"], 2: ["out"], 3: ["work"]}
    if side_branch:
        nodes += [Node(8, "side", -4.0, 0.0, "station", (8,))]
        nodes += [Node(9, "park", -8.0, 0.0, "station", (9,))]
        edges += [Edge(1, 8, 4.0), Edge(8, 9, 4.0)]
        functions.update({8: "side", 9: "park"})
        starts[4], recipes["to-work"], jobs[4] = 1, [3], ["to-work"]
        if branch_busy:
            starts[5], recipes["park"], jobs[5] = 8, [8, 9], ["park"]
    plant = Plant.build(nodes, edges, name="spur-on-a-ring", functions=functions)
    clusters = {f: [f] for f in functions}  # each function's one station has its id
    cfg = make_config(plant, starts, recipes, clusters, vehicle_recipes=jobs, rounds=1, **settings)
    return FleetProgram(cfg)


def test_a_deadlock_nobody_can_leave_yet_is_retried_and_broken_once_there_is_room():
    """Seen on the distribution centre: a vehicle stands in a dead-end spur (a queue place),
    the vehicle heading for that spur stands at its mouth on a one-way ring lane, and each
    waits for the other. Neither can step aside: the only free-looking node is the lane
    ahead, and a third vehicle is working there. When that one has driven on, the waiting
    one must be backed off onto it after all (it then drives a lap round the ring back to
    the spur), not left standing for ever because the deadlock was reported once."""
    p = spur_on_a_ring(side_branch=False)
    try:
        run(p, 120)
        assert p.resolver.unresolved >= 1  # nobody could move when it formed
        assert p.resolver.resolved >= 1 and p.resolver.stranded() == []
        assert sorted(r.vehicle for r in p.completed) == [1, 2, 3]
        assert p.recorder.driven[1][:2] == [2, 3]  # backed off onto the lane ahead
    finally:
        p.close()


@pytest.mark.parametrize("branch_busy", [False, True])
def test_a_back_off_of_a_vehicle_queued_behind_a_deadlock_does_not_end_its_retries(
    branch_busy,
):
    """As above, with vehicle 4 queued behind vehicle 1 and a side branch it can give way
    into: at once, or (``branch_busy``) once vehicle 5 has left it. Backing vehicle 4 off
    makes room but breaks nothing: the deadlock of vehicles 1 and 2 must still be tried
    again (and then broken), not counted as resolved and forgotten. Replanning after a
    long wait, which might free them by chance, is switched off."""
    p = spur_on_a_ring(side_branch=True, branch_busy=branch_busy, wait_replan_s=1000.0)
    try:
        run(p, 200)
        backed_off = [e.backed_off for e in p.resolver.events if e.backed_off is not None]
        assert backed_off[:2] == [4, 1]  # the one behind first, then one of the two
        assert sorted(r.vehicle for r in p.completed) == (
            [1, 2, 3, 4, 5] if branch_busy else [1, 2, 3, 4]
        )
        assert p.resolver.stranded() == []
    finally:
        p.close()


def test_a_deadlock_a_push_was_decided_for_is_watched_until_the_push_happens():
    """Vehicle 1 in the spur and vehicle 2 at its mouth wait for each other. When they
    meet, the only node to push vehicle 2 to is the ring lane ahead, and vehicle 3 is
    driving there: the push is decided, to follow it. But vehicle 3 stops there and works
    for a minute, so the push never happens. The deadlock must then be reported (both
    stranded) and, once vehicle 3 has driven on, broken, not taken as resolved when the
    push was decided and never looked at again."""
    nodes = [Node(1, "one", 0.0, 0.0, "station", (1,)), Node(2, "mouth", 4.0, 0.0)]
    nodes += [Node(3, "work", 8.0, 0.0, "station", (3,)), Node(4, "lane4", 12.0, 0.0)]
    nodes += [Node(5, "goal", 12.0, 4.0, "station", (5,)), Node(6, "lane6", 0.0, 4.0)]
    nodes += [
        Node(7, "spur", 4.0, -4.0, "station", (7,)),
        Node(8, "far", 8.0, -16.0, "station", (8,)),
    ]
    one_way = [(1, 2, 4.0), (2, 3, 4.0), (3, 4, 4.0), (4, 5, 4.0), (5, 6, 12.0), (6, 1, 4.0)]
    edges = [Edge(a, b, length, bidirectional=False) for a, b, length in one_way]
    edges += [Edge(2, 7, 4.0), Edge(8, 3, 16.0, bidirectional=False)]
    functions = {1: "one", 3: "work", 5: "goal", 7: "spur", 8: "far"}
    plant = Plant.build(nodes, edges, name="pushed-to-a-busy-node", functions=functions)
    cfg = make_config(
        plant,
        {1: 7, 2: 1, 3: 8},
        {"out": [7, 5], "in": [1, 7], "work": [3]},
        {f: [f] for f in functions},
        vehicle_recipes={1: ["out"], 2: ["in"], 3: ["work"]},
        rounds=1,
        wait_replan_s=1000.0,
    )
    p = FleetProgram(cfg)
    # (working times per function, which the configuration has no key for; each function's
    # one station has the function's id)
    p.jobs[1].processing_s = {7: 10.0, 5: 1.0}
    p.jobs[2].processing_s = {1: 1.0, 7: 1.0}
    p.jobs[3].processing_s = {3: 60.0}
    try:
        run(p, 50)  # vehicle 3 reaches 3 at about 33 s and works there until about 93 s
        events = p.resolver.events
        assert (events[0].backed_off, events[0].to_node) == (2, 3)  # the push, decided
        assert events[1].backed_off is None  # reported once vehicle 3 stood on node 3
        assert p.resolver.unresolved >= 1 and p.resolver.stranded() == [1, 2]
        run(p, 250)
        assert sorted(r.vehicle for r in p.completed) == [1, 2, 3]
        assert p.resolver.stranded() == []
    finally:
        p.close()
