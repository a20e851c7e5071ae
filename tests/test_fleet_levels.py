"""One scenario per stage of the thesis (section 2.3), on its model plant, vehicles over the
virtual CAN bus, every cycle checked by the independent conflict monitor."""

from __future__ import annotations

import networkx as nx
import pytest
from fleet_scenarios import make_config, run, visited_functions

from fleet.config import load_config
from fleet.program import FleetProgram
from topology import model_plant
from topology.model import route_cost

MIDDLE_ROW = {(0, 6), (6, 7), (7, 8), (8, 9)}


def graph(plant):
    g = nx.DiGraph()
    src, dst, length = plant.arcs
    ids = plant.ids
    for a, b, w in zip(src, dst, length, strict=True):
        g.add_edge(int(ids[a]), int(ids[b]), weight=float(w))
    return g


@pytest.fixture
def program():
    made = []

    def build(cfg):
        cfg.watchdog = 5.0  # behaviour, not wall time: a busy machine must not fault a scan
        p = FleetProgram(cfg)
        made.append(p)
        return p

    yield build
    for p in made:
        p.close()


def test_base_level_a_vehicle_drives_the_shortest_route(program):
    plant = model_plant()
    p = program(make_config(plant, {1: 0}, {"r": [5]}, {5: [18]}, rounds=1))
    run(p, 40)
    assert [f for _, f in visited_functions(p, 1)] == [[5]]
    driven = p.recorder.driven[1]
    assert driven[0] == 0 and driven[-1] == 18
    best = nx.shortest_path_length(graph(plant), 0, 18, weight="weight")
    assert route_cost(plant, driven) == pytest.approx(best)
    assert p.controls[1].replans == 0 and p.controls[1].waits == 0


def test_level_1_vehicles_queue_on_the_same_route(program):
    """One station per function: every vehicle drives the same sub-routes, one behind the
    other, and nobody overtakes (arrival order at every station is the same)."""
    plant = model_plant()
    cfg = make_config(
        plant, {1: 0, 2: 10, 3: 11}, {"r": [3, 5, 1]}, {3: [16], 5: [19], 1: [24]}, rounds=1
    )
    p = program(cfg)
    run(p, 150)
    assert len(p.completed) == 3
    order = {}
    for r in p.completed:
        for s in r.sections:
            order.setdefault(s.station, []).append((s.arrived_s, r.vehicle))
    arrival = {station: [v for _, v in sorted(x)] for station, x in order.items()}
    assert arrival[16] == arrival[19] == arrival[24]
    # the same sub-route 16 -> 19 for everyone
    legs = set()
    for v in (1, 2, 3):
        path = p.recorder.driven[v]
        legs.add(tuple(path[path.index(16) : path.index(19) + 1]))
    assert len(legs) == 1
    assert sum(c.waits for c in p.controls.values()) > 0  # they did queue


def test_level_2_vehicles_take_different_stations_and_overtake(program):
    plant = model_plant()
    cfg = make_config(
        plant,
        {1: 0, 2: 10, 3: 11, 4: 1},
        {"r": [2, 5, 1]},
        {2: [15, 22], 5: [18, 19], 1: [24]},
        strategy="round_robin",
        rounds=2,
    )
    p = program(cfg)
    trace = run(p, 300)
    assert len(p.completed) == 8
    stations_for_2 = {s.station for r in p.completed for s in r.sections if s.function == 2}
    assert stations_for_2 == {15, 22}
    # overtaking: some vehicle reached its first station after another one but finished first
    runs = [r for r in p.completed if r.round == 1]
    overtakes = [
        (a.vehicle, b.vehicle)
        for a in runs
        for b in runs
        if a.sections[0].arrived_s > b.sections[0].arrived_s and a.finished_s < b.finished_s
    ]
    assert overtakes
    assert set(trace.segments()) & MIDDLE_ROW  # the inner (overtaking) lanes are used


def test_level_3_routes_avoid_a_blockade_and_come_back_after_it_clears(program):
    from fleet.config import Blockade

    plant = model_plant()
    cfg = make_config(
        plant,
        {1: 0, 2: 10},
        {"out": [1]},
        {1: [24]},
        blockades=[Blockade(7, 8, 60.0, 200.0)],
    )
    p = program(cfg)
    trace = run(p, 320)
    blocked = {(7, 8), (8, 7)}
    before = [t for t, _v, a, b in trace.entered if (a, b) in blocked and t < 60]
    during = [t for t, _v, a, b in trace.entered if (a, b) in blocked and 62 <= t < 200]
    after = [t for t, _v, a, b in trace.entered if (a, b) in blocked and t >= 200]
    assert before and after and not during
    assert list(p.events.segment_changes) == [(60.0, "closed", 7, 8), (200.0, "reopened", 7, 8)]
    detour = [t for t, _v, a, b in trace.entered if (a, b) == (3, 17) and 62 <= t < 200]
    assert detour  # the way round over the top lane
    assert len(p.completed) >= 10


def test_a_segment_stays_closed_while_anyone_keeps_it_closed():
    """Two overlapping entries of the schedule, and an operator: the segment opens only
    when the last of them reopens it; the operator's reopening opens it whoever closed it."""
    from blocks.routing.constraints import RoutingConstraints

    c = RoutingConstraints(model_plant())
    c.block(7, 8, by=("schedule", 0))
    c.block(8, 7, by=("schedule", 1))
    epoch = c.epoch
    c.unblock(8, 7, by=("schedule", 1))
    assert c.blocked_segments() == [(7, 8), (8, 7)] and c.epoch == epoch  # nothing changed
    assert c.closed_by(7, 8) == {("schedule", 0)}
    c.block(7, 8)  # the operator
    c.unblock(7, 8, by=("schedule", 0))
    assert c.blocked_segments() == [(7, 8), (8, 7)] and c.closed_by(8, 7) == {"operator"}
    c.unblock(7, 8, by="operator")
    assert c.blocked_segments() == [] and c.epoch == epoch + 1
    c.block(8, 7, by=("schedule", 0))
    assert c.closed_by(7, 8) == c.closed_by(8, 7) == {("schedule", 0)}  # either way
    c.block(7, 8)
    c.unblock(7, 8)  # the operator's override
    assert c.blocked_segments() == [] and c.closed_by(7, 8) == set()


def test_the_schedule_reopens_only_what_it_closed(program):
    """A scheduled blockade 7-8 from 10 to 50 s and one 8-7 from 20 to 30 s: closed from
    10 to 50 s (the second entry's end reopened it before). An operator's closure of 3-17
    at 5 s outlasts a scheduled one of the same segment from 8 to 40 s."""
    from fleet.config import Blockade

    plant = model_plant()
    cfg = make_config(
        plant,
        {1: 0, 2: 10},
        {"out": [1]},
        {1: [24]},
        blockades=[
            Blockade(7, 8, 10.0, 50.0),
            Blockade(8, 7, 20.0, 30.0),
            Blockade(3, 17, 8.0, 40.0),
        ],
    )
    p = program(cfg)
    closed = {}
    rt = p.rt
    rt.start()
    while rt.clock.now() < 60.0:
        if abs(rt.clock.now() - 5.0) < 1e-9:
            p.blockades.block(3, 17)
        rt.step()
        closed[round(rt.clock.now(), 2)] = set(p.blockades.blocked_segments())
    assert (7, 8) in closed[35.0] and (7, 8) in closed[45.0] and (7, 8) not in closed[50.05]
    assert (3, 17) in closed[45.0] and (3, 17) in closed[59.95]
    assert [e for e in p.events.segment_changes if e[2:] == (7, 8)] == [
        (10.0, "closed", 7, 8),
        (50.0, "reopened", 7, 8),
    ]


def test_level_4_the_default_job_runs_every_vehicles_own_recipes(program):
    p = program(load_config())
    run(p, 320)
    cfg = p.cfg
    assert cfg.level == "4"
    recipes_seen = set()
    for v in p.vehicles:
        done = visited_functions(p, v)
        assert len(done) >= 2, f"vehicle {v} completed {done}"
        own = cfg.vehicle_recipes[v]
        for k, (name, functions) in enumerate(done):
            assert name == own[k % len(own)]
            assert functions == list(cfg.recipes[name].functions)
        recipes_seen.add(done[0][0])
    assert len(recipes_seen) == len(p.vehicles)  # different recipes per vehicle
    assert [e for _t, e, *_ in p.events.segment_changes] == ["closed", "reopened"]
